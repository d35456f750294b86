"""`hoc simulate` through the CLI: torque sources, outputs read back, --json, --check, exit codes."""
import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.special import ellipk
from typer.testing import CliRunner

from hoc_cli.cli import app
from hoc_cli.elements import HermiteMesh
from hoc_cli.io.csv import read_csv, write_csv
from hoc_cli.model import load_robot
from hoc_cli.simulate import simulate_hermite
from hoc_cli.system import RobotSystem
from hoc_cli.torque import ConstantTorque, PlannedTorque
from hoc_cli.trajectory import Trajectory, sample_times

ROBOTS = Path(__file__).resolve().parent.parent / "robots"
PENDULUM = ROBOTS / "pendulum.urdf"
Q0 = math.pi / 12



def invoke(*args):
    return CliRunner().invoke(app, ["simulate", *map(str, args)])


def pendulum_period() -> float:
    """τ = (4/ω) K(sin(q0/2)) with ω = √(g/l) of robots/pendulum.urdf (its l = 1.0195 m)."""
    system = RobotSystem(load_robot(PENDULUM))
    _, du_dq, _, M = system.id_derivatives(np.zeros((1, 1)), np.zeros((1, 1)), np.zeros((1, 1)))
    return 4.0 / math.sqrt(du_dq[0, 0, 0] / M[0, 0, 0]) * ellipk(math.sin(Q0 / 2) ** 2)


def write_task(path: Path, **keys) -> Path:
    doc = {"robot": str(PENDULUM), "x0": {"q": [Q0], "dq": [0.0]}, "T": 1.0, "N": 20, "order": "quintic"}
    doc.update(keys)
    path.write_text(json.dumps(doc))  # JSON is YAML
    return path


def test_one_free_period_of_the_pendulum_returns_to_x0_in_the_json_summary(tmp_path):
    tau = pendulum_period()
    task = write_task(tmp_path / "pend.yaml", T=tau, N=60, torque="zero", x1={"q": [Q0], "dq": [0.0]})
    r = invoke(task, "--json", "-o", tmp_path / "out.csv")
    assert r.exit_code == 0, r.output
    doc = json.loads(r.stdout)
    assert doc["final_error"] < 1e-9
    assert doc["final_state"]["q"][0] == pytest.approx(Q0, abs=1e-9)
    assert doc["method"] == "hermite" and doc["N"] == 60 and doc["order"] == "quintic" and doc["converged"] is True
    assert doc["joints"] == ["pivot"] and doc["outputs"] == [str(tmp_path / "out.csv")]


def test_check_exits_0_within_the_tolerance_and_1_beyond_it(tmp_path):
    task = write_task(tmp_path / "pend.yaml", T=pendulum_period(), N=60, torque="zero", x1={"q": [Q0]})
    out = tmp_path / "out.csv"
    assert invoke(task, "--check", "1e-8", "-o", out).exit_code == 0
    r = invoke(task, "--check", "1e-14", "-o", out, "-q")
    assert r.exit_code == 1 and "check failed" in r.stderr


def test_rk_and_hermite_reach_the_same_final_state_under_a_constant_torque(tmp_path):
    task = write_task(tmp_path / "pend.yaml", torque=[0.8], T=1.5, N=40)
    docs = [json.loads(invoke(task, "--json", "--integrator", m, "-o", tmp_path / "o.csv").stdout) for m in ("hermite", "rk")]
    for key in ("q", "dq"):
        np.testing.assert_allclose(docs[0]["final_state"][key], docs[1]["final_state"][key], atol=1e-9)
    assert docs[1]["method"] == "rk" and docs[0]["final_error"] is None


def test_csv_and_mcap_outputs_read_back_with_the_applied_torque_and_the_hermite_coefficients(tmp_path):
    from hoc_cli.io.mcap import read_plan

    task = write_task(tmp_path / "pend.yaml", torque=[0.5], output={"rate": 40})
    csv, mcap = tmp_path / "sim.csv", tmp_path / "sim.mcap"
    r = invoke(task, "-o", csv, "-o", mcap, "--json")
    assert r.exit_code == 0, r.output
    traj = read_csv(csv)
    np.testing.assert_array_equal(traj.t, sample_times(1.0, 40))
    np.testing.assert_array_equal(traj.u, np.full((41, 1), 0.5))
    system = RobotSystem(load_robot(PENDULUM))
    direct = simulate_hermite(system, [Q0], [0.0], ConstantTorque([0.5]), HermiteMesh("quintic", 1.0, 20))
    np.testing.assert_allclose(traj.q[-1], direct.coeffs[-1, 0], rtol=1e-15)
    plan = read_plan(mcap)
    np.testing.assert_array_equal(plan.trajectory.coeffs, direct.coeffs)
    assert json.loads(plan.metadata["simulation"])["torque"] == "constant"


def test_default_outputs_are_named_after_the_task_with_a_sim_suffix(tmp_path, monkeypatch):
    # never <stem>.csv/.mcap: those are the plan's names, and may be the --torque input (issue 12, item 1)
    monkeypatch.chdir(tmp_path)
    task = write_task(tmp_path / "swing.yaml", torque="zero")
    assert invoke(task).exit_code == 0
    assert (tmp_path / "swing-sim.csv").exists() and (tmp_path / "swing-sim.mcap").exists()
    assert not (tmp_path / "swing.csv").exists() and not (tmp_path / "swing.mcap").exists()


def test_dash_output_writes_csv_to_stdout(tmp_path):
    task = write_task(tmp_path / "pend.yaml", torque="zero", output={"rate": 10})
    r = invoke(task, "-o", "-")
    assert r.exit_code == 0 and r.stdout.splitlines()[0] == "t,q.pivot,dq.pivot,ddq.pivot,u.pivot"
    assert len(r.stdout.splitlines()) == 12


# --------------------------------------------------------------------------- replaying a plan
@pytest.fixture
def plan_files(tmp_path):
    """A 'plan' of the pendulum (a smooth swing, as hoc plan would write it): MCAP with the exact
    Hermite coefficients, CSV samples at 100 Hz, and its task with x1 = the plan's end state."""
    from hoc_cli import dynamics
    from hoc_cli.io.mcap import write_mcap

    model = load_robot(PENDULUM)
    system = RobotSystem(model)
    T, N = 1.2, 12
    mesh = HermiteMesh("quintic", T, N)
    w = 2 * np.pi / T
    C = mesh.interpolate(lambda t: Q0 * np.cos(w * t) + 0.3 * np.sin(w * t) ** 2,
                         lambda t: -Q0 * w * np.sin(w * t) + 0.3 * w * np.sin(2 * w * t),
                         lambda t: -Q0 * w * w * np.cos(w * t) + 0.6 * w * w * np.cos(2 * w * t))
    t = sample_times(T, 100)
    q, dq, ddq = mesh.evaluate_all(C, t)
    traj = Trajectory(joints=("pivot",), t=t, q=q, dq=dq, ddq=ddq, u=PlannedTorque(system, mesh, C)(t), mesh=mesh, coeffs=C)
    task_doc = {"robot": str(PENDULUM), "x0": {"q": [Q0], "dq": [0.0]}, "x1": {"q": [float(C[-1, 0, 0])], "dq": [float(C[-1, 1, 0])]},
                "T": T, "N": N, "order": "quintic"}
    task = tmp_path / "plan_task.yaml"
    task.write_text(json.dumps(task_doc))
    mcap = tmp_path / "plan.mcap"
    with open(mcap, "wb") as fh:
        write_mcap(fh, traj, urdf_text=PENDULUM.read_text(), task_text=task.read_text(),
                   link_poses=lambda qq: dynamics.link_poses(model, qq))
    csv = tmp_path / "plan.csv"
    with open(csv, "wb") as fh:
        write_csv(fh, traj)
    return task, mcap, csv, traj


def test_replaying_a_plans_mcap_reaches_its_goal_to_1e_8(plan_files, tmp_path, monkeypatch):
    _, mcap, _, _ = plan_files
    monkeypatch.chdir(tmp_path)
    r = invoke(mcap, "--check", "1e-8", "--json")
    assert r.exit_code == 0, r.output
    doc = json.loads(r.stdout)
    assert doc["final_error"] < 1e-12 and doc["torque"] == "plan (exact Hermite)"
    assert doc["check"]["tol"] == 1e-8 and doc["check"]["passed"] is True and doc["check"]["miss"] == doc["final_error"]
    assert sorted(doc["outputs"]) == ["plan-sim.csv", "plan-sim.mcap"]  # never overwrites the plan


def test_replaying_a_plan_on_a_finer_mesh_still_reaches_its_goal(plan_files):
    task, mcap, _, _ = plan_files
    r = invoke(task, "--torque", mcap, "-N", "48", "--json", "-o", task.parent / "fine.csv")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["final_error"] < 1e-8


def test_a_plans_csv_torque_replays_to_1e_6_and_a_perturbed_one_fails_the_check(plan_files, tmp_path):
    task, _, csv, traj = plan_files
    out = tmp_path / "o.csv"
    r = invoke(task, "--torque", csv, "--check", "1e-6", "--json", "-o", out)
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["torque"] == "csv"
    bumped = Trajectory(joints=traj.joints, t=traj.t, q=traj.q, dq=traj.dq, ddq=traj.ddq, u=traj.u + 0.01)
    bad = tmp_path / "bumped.csv"
    with open(bad, "wb") as fh:
        write_csv(fh, bumped)
    assert invoke(task, "--torque", bad, "--check", "1e-6", "-o", out).exit_code == 1


# --------------------------------------------------------------------------- bad input: exit 2, one line
@pytest.mark.parametrize("extra, keys, needle", [
    ([], {}, "torque"),  # no torque history at all
    (["--integrator", "euler"], {"torque": "zero"}, "--integrator"),
    (["--check", "1e-6"], {"torque": "zero"}, "x1"),
    (["--check", "-1"], {"torque": "zero"}, "--check"),
    (["-o", "-", "--json"], {"torque": "zero"}, "--output"),
    (["-o", "out.txt"], {"torque": "zero"}, "--output"),
    (["-N", "0"], {"torque": "zero"}, "--elements"),
    ([], {"torque": [1.0, 2.0]}, "torque"),
])
def test_bad_input_exits_2_with_one_line_naming_what_is_wrong(tmp_path, extra, keys, needle):
    task = write_task(tmp_path / "pend.yaml", **keys)
    r = invoke(task, *extra)
    assert r.exit_code == 2, r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0] and "Traceback" not in r.stderr


def test_a_torque_file_for_other_joints_or_too_short_is_rejected_with_exit_2(plan_files, tmp_path):
    task, _, _, traj = plan_files
    other = tmp_path / "other.csv"
    with open(other, "wb") as fh:
        write_csv(fh, Trajectory(joints=("elbow",), t=traj.t, q=traj.q, dq=traj.dq, ddq=traj.ddq, u=traj.u))
    r = invoke(task, "--torque", other)
    assert r.exit_code == 2 and "elbow" in r.stderr
    short = tmp_path / "short.csv"
    k = traj.K // 2
    with open(short, "wb") as fh:
        write_csv(fh, Trajectory(joints=traj.joints, t=traj.t[:k], q=traj.q[:k], dq=traj.dq[:k], ddq=traj.ddq[:k], u=traj.u[:k]))
    r = invoke(task, "--torque", short)
    assert r.exit_code == 2 and "cover" in r.stderr
    r = invoke(task, "--torque", tmp_path / "missing.csv")
    assert r.exit_code == 2 and "missing.csv" in r.stderr


def test_a_missing_source_exits_2():
    r = invoke("does-not-exist.yaml")
    assert r.exit_code == 2 and "does-not-exist.yaml" in r.stderr


def test_a_motion_that_overflows_exits_1_with_one_line_naming_the_element(tmp_path):
    task = tmp_path / "arm.yaml"  # (PyYAML reads 1e+200 as a string: YAML 1.1 floats need a dot)
    task.write_text(f"robot: {ROBOTS / 'lbr7.urdf'}\nx0: {{q: [0.1, 0.2, 0.3, -0.4, 0.5, 0.6, 0.7]}}\n"
                    "torque: [1.0e+200, 1.0e+200, 1.0e+200, 1.0e+200, 1.0e+200, 1.0e+200, 1.0e+200]\nT: 1.0\nN: 4\n")
    r = invoke(task, "-o", tmp_path / "o.csv")
    assert r.exit_code == 1 and "element 0 (t = 0" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1  # no RuntimeWarning noise


def test_the_7dof_arm_accepts_joint_name_mappings_for_x0_and_torque(tmp_path):
    names = [f"lbr_joint_{i}" for i in range(1, 8)]
    doc = {"robot": str(ROBOTS / "lbr7.urdf"), "gravity": [0.0, 0.0, 9.81],
           "x0": {"q": {n: 0.05 * i for i, n in enumerate(names)}}, "torque": {n: 0.0 for n in names},
           "T": 0.5, "N": 40, "order": "quintic"}
    task = tmp_path / "arm.yaml"
    task.write_text(json.dumps(doc))
    docs = [json.loads(invoke(task, "--json", "--integrator", m, "-o", tmp_path / "a.csv").stdout) for m in ("hermite", "rk")]
    np.testing.assert_allclose(docs[0]["final_state"]["q"], docs[1]["final_state"]["q"], atol=1e-8)
    assert docs[0]["joints"] == names


def test_a_csv_as_the_simulation_source_points_to_the_torque_option(tmp_path):
    p = tmp_path / "plan.csv"
    p.write_text("t,q.a,dq.a,ddq.a,u.a\n0,0,0,0,0\n")
    r = invoke(p)
    assert r.exit_code == 2 and "--torque" in r.stderr and len(r.stderr.strip().splitlines()) == 1
