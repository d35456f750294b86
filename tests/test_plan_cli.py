"""`hoc plan` end to end through the CLI: outputs, JSON summary, exit codes, warm start."""
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from hoc_cli.cli import app
from hoc_cli.io.csv import read_csv

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture
def task(tmp_path, monkeypatch):
    shutil.copy(ROOT / "robots" / "two_link.urdf", tmp_path / "two_link.urdf")
    text = (ROOT / "configs" / "two_link.yaml").read_text().replace("../robots/two_link.urdf", "two_link.urdf")
    text = text.replace("N: 16", "N: 8")
    p = tmp_path / "arm.yaml"
    p.write_text(text)
    monkeypatch.chdir(tmp_path)
    return p


def invoke(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def test_plan_writes_csv_and_mcap_and_a_json_summary(task, tmp_path):
    r = invoke("plan", task, "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    for key in ("cost", "converged", "iterations", "grad_norm", "wall_time_s", "joints", "N", "order", "T",
                "boundary_error", "max_abs_u", "limit_violations", "outputs"):
        assert key in s
    assert s["converged"] is True and s["joints"] == ["shoulder", "elbow"] and s["N"] == 8
    assert s["boundary_error"] <= 1e-12
    assert sorted(s["outputs"]) == ["arm.csv", "arm.mcap"]
    assert (tmp_path / "arm.csv").exists() and (tmp_path / "arm.mcap").exists()


def test_csv_torque_equals_pinocchio_rnea_of_the_csv_motion_and_boundaries_are_exact(task, tmp_path):
    pin = pytest.importorskip("pinocchio")
    assert invoke("plan", task, "-o", "arm.csv", "-q").exit_code == 0
    tr = read_csv(tmp_path / "arm.csv")
    model = pin.buildModelFromUrdf(str(tmp_path / "two_link.urdf"))
    data = model.createData()
    names = [model.names[i] for i in range(1, model.njoints)]
    idx = [names.index(j) for j in tr.joints]
    for k in range(0, tr.K, 7):
        q, v, a = (np.zeros(model.nq) for _ in range(3))
        q[idx], v[idx], a[idx] = tr.q[k], tr.dq[k], tr.ddq[k]
        tau = pin.rnea(model, data, q, v, a)[idx]
        np.testing.assert_allclose(tr.u[k], tau, rtol=1e-10, atol=1e-10 * np.abs(tau).max())
    np.testing.assert_allclose(tr.q[0], [0, 0], atol=1e-12)
    np.testing.assert_allclose(tr.q[-1], [1.2, -0.6], atol=1e-12)
    np.testing.assert_allclose(tr.dq[[0, -1]], 0, atol=1e-12)
    assert tr.t[-1] == 1.5 and tr.K == 151


def test_dash_streams_csv_to_stdout_and_nothing_else(task, tmp_path):
    r = invoke("plan", task, "-o", "-", "-q")
    assert r.exit_code == 0
    lines = r.stdout.splitlines()
    assert lines[0].startswith("t,q.shoulder,q.elbow,dq.shoulder")
    assert len(lines) == 152
    assert r.stderr == ""
    assert not list(tmp_path.glob("*.csv")) and not list(tmp_path.glob("*.mcap"))


def test_quiet_prints_nothing_on_stderr(task):
    r = invoke("plan", task, "-q", "--progress")
    assert r.exit_code == 0 and r.stderr == ""


def test_hitting_max_iter_writes_the_best_iterate_marked_unconverged_and_exits_1(task, tmp_path):
    r = invoke("plan", task, "--max-iter", "1", "--json")
    assert r.exit_code == 1
    s = json.loads(r.stdout)
    assert s["converged"] is False and s["status"] == "max_iter" and s["iterations"] == 1
    assert (tmp_path / "arm.csv").exists()


def test_same_inputs_give_byte_identical_csv_and_mcap(task, tmp_path):
    assert invoke("plan", task, "-o", "a.csv", "-o", "a.mcap", "-q").exit_code == 0
    assert invoke("plan", task, "-o", "b.csv", "-o", "b.mcap", "-q").exit_code == 0
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()


def test_warm_start_from_a_converged_plan_needs_no_iterations(task, tmp_path):
    assert invoke("plan", task, "-o", "first.mcap", "-q").exit_code == 0
    r = invoke("plan", task, "--init", "first.mcap", "-o", "second.csv", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["iterations"] <= 1


def test_warm_start_resamples_a_plan_with_another_number_of_elements(task, tmp_path):
    assert invoke("plan", task, "-o", "coarse.mcap", "-q", "-N", "4").exit_code == 0
    r = invoke("plan", task, "--init", "coarse.mcap", "-o", "fine.csv", "--json")
    assert r.exit_code == 0 and json.loads(r.stdout)["converged"] is True


def test_json_and_csv_on_stdout_together_is_a_usage_error(task):
    r = invoke("plan", task, "--json", "-o", "-")
    assert r.exit_code == 2 and "--output" in r.stderr


@pytest.mark.parametrize("out,needle", [("nodir/x.csv", "does not exist"), ("x.txt", "unknown output extension")])
def test_bad_output_paths_exit_2_before_any_work(task, tmp_path, out, needle):
    r = invoke("plan", task, "-o", out)
    assert r.exit_code == 2 and needle in r.stderr
    assert not list(tmp_path.glob("*.csv"))


def test_a_plans_mcap_read_back_matches_its_csv_row_for_row(task, tmp_path):
    from hoc_cli.io.mcap import read_plan

    assert invoke("plan", task, "-o", "p.csv", "-o", "p.mcap", "-q").exit_code == 0
    csv = read_csv(tmp_path / "p.csv")
    mc = read_plan(tmp_path / "p.mcap")
    tr = mc.trajectory
    assert tr.joints == csv.joints and tr.K == csv.K
    np.testing.assert_array_equal(tr.t, csv.t)
    for name in ("q", "dq", "ddq", "u"):
        np.testing.assert_array_equal(getattr(tr, name), getattr(csv, name))
    assert "<robot" in mc.urdf_text and "x0:" in mc.task_text
    summary = json.loads(mc.metadata["summary"])
    assert summary["converged"] is True and summary["joints"] == list(csv.joints)
    q = tr.mesh.evaluate(tr.coeffs, csv.t, 0)  # the exact coefficients reproduce the samples
    np.testing.assert_allclose(q, csv.q, atol=1e-14)


def test_reported_cost_equals_pinocchios_integral_of_the_covariant_effort(task, tmp_path):
    """J recomputed independently: Pinocchio's RNEA and CRBA on 4001 points of the exact Hermite
    trajectory (from the MCAP attachment), ½ uᵀM⁻¹u integrated by Simpson's rule."""
    pin = pytest.importorskip("pinocchio")
    from scipy.integrate import simpson

    from hoc_cli.io.mcap import read_plan

    r = invoke("plan", task, "-o", "p.mcap", "--json")
    assert r.exit_code == 0
    J = json.loads(r.stdout)["cost"]
    tr = read_plan(tmp_path / "p.mcap").trajectory
    model = pin.buildModelFromUrdf(str(tmp_path / "two_link.urdf"))
    data = model.createData()
    t = np.linspace(0.0, tr.mesh.T, 4001)
    q, dq, ddq = tr.mesh.evaluate_all(tr.coeffs, t)
    L = np.empty(t.size)
    for k in range(t.size):
        u = pin.rnea(model, data, q[k], dq[k], ddq[k])
        M = pin.crba(model, data, q[k])
        M = np.triu(M) + np.triu(M, 1).T
        L[k] = 0.5 * u @ np.linalg.solve(M, u)
    assert simpson(L, x=t) == pytest.approx(J, rel=1e-9)


def test_an_unexpected_exception_is_one_line_exit_1_and_a_traceback_with_debug(task, monkeypatch):
    import hoc_cli.planner as planner

    def boom(*a, **k):
        raise ZeroDivisionError("simulated bug")

    monkeypatch.setattr(planner, "plan", boom)
    r = invoke("plan", task)
    assert r.exit_code == 1
    assert r.stderr.strip().splitlines() == [
        "hoc: error: internal error (ZeroDivisionError: simulated bug); please report it with the output of --debug"]
    r = invoke("plan", task, "--debug")
    assert isinstance(r.exception, ZeroDivisionError)


@pytest.mark.parametrize("outs", [["-", "-"], ["a.csv", "./a.csv"]])
def test_the_same_output_twice_is_a_usage_error(task, tmp_path, outs):
    args = [x for o in outs for x in ("-o", o)]
    r = invoke("plan", task, *args)
    assert r.exit_code == 2 and "is given twice" in r.stderr and r.stdout == ""
    assert not (tmp_path / "a.csv").exists()


def test_an_output_rate_that_would_write_millions_of_samples_is_refused(task, tmp_path):
    task.write_text(task.read_text() + "")
    text = task.read_text().replace("output: {rate: 100}", "output: {rate: 1.0e+9}")
    task.write_text(text)
    r = invoke("plan", task)
    assert r.exit_code == 2 and "output.rate" in r.stderr and "1000000" in r.stderr


def test_a_7dof_plans_mcap_decodes_with_the_ros2_decoder_and_tf_matches_yourdfpy(tmp_path, monkeypatch):
    """Read back with mcap's reader and mcap_ros2's decoder (not hoc's reader): one JointState per CSV
    row with equal values, the URDF on /robot_description, /tf equal to yourdfpy's forward kinematics
    (an independent oracle), the `hoc` metadata and the three attachments."""
    import yourdfpy
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from scipy.spatial.transform import Rotation

    monkeypatch.chdir(tmp_path)
    urdf = ROOT / "robots" / "lbr7.urdf"
    (tmp_path / "t.yaml").write_text(
        (ROOT / "configs" / "lbr7_reach.yaml").read_text().replace("../robots/lbr7.urdf", str(urdf))
        .replace("N: 16", "N: 4") + "output: {rate: 20}\n")
    assert invoke("plan", tmp_path / "t.yaml", "-o", "p.mcap", "-o", "p.csv", "-q").exit_code == 0
    csv = read_csv(tmp_path / "p.csv")
    by_topic: dict = {}
    with open(tmp_path / "p.mcap", "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            by_topic.setdefault(channel.topic, []).append((message.log_time, decoded))
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        attachments = {a.name for a in reader.iter_attachments()}
    js = by_topic["/joint_states"]
    assert len(js) == csv.K
    for k, (log_time, m) in enumerate(js):
        assert list(m.name) == list(csv.joints)
        assert m.header.stamp.sec * 10**9 + m.header.stamp.nanosec == log_time == round(csv.t[k] * 1e9)
        np.testing.assert_array_equal(m.position, csv.q[k])
        np.testing.assert_array_equal(m.velocity, csv.dq[k])
        np.testing.assert_array_equal(m.effort, csv.u[k])
    acc = by_topic["/joint_accelerations"]
    assert len(acc) == csv.K
    for k, (log_time, m) in enumerate(acc):
        assert list(m.joint_names) == list(csv.joints) and log_time == js[k][0]
        np.testing.assert_array_equal(m.points[0].accelerations, csv.ddq[k])
    assert by_topic["/robot_description"][0][1].data == urdf.read_text()
    assert "task" in metadata["hoc"] and "summary" in metadata["hoc"]
    assert attachments == {"robot.urdf", "task.yaml", "hermite.json"}
    oracle = yourdfpy.URDF.load(str(urdf), build_scene_graph=True, load_meshes=False,
                                build_collision_scene_graph=False, load_collision_meshes=False)
    tf = by_topic["/tf"]
    assert len(tf) == csv.K
    for k in (0, csv.K // 2, csv.K - 1):
        oracle.update_cfg(dict(zip(csv.joints, csv.q[k].tolist())))
        for ts in tf[k][1].transforms:
            r, p = ts.transform.rotation, ts.transform.translation
            A = np.eye(4)
            A[:3, :3] = Rotation.from_quat([r.x, r.y, r.z, r.w]).as_matrix()
            A[:3, 3] = [p.x, p.y, p.z]
            expected = oracle.get_transform(frame_to=ts.child_frame_id, frame_from=ts.header.frame_id)
            np.testing.assert_allclose(A, expected, atol=1e-12)


def test_an_output_that_is_a_symlink_is_written_through_the_link(task, tmp_path):
    target = tmp_path / "real.csv"
    target.write_text("old")
    (tmp_path / "link.csv").symlink_to(target)
    assert invoke("plan", task, "-o", "link.csv", "-q").exit_code == 0
    assert (tmp_path / "link.csv").is_symlink()
    assert target.read_text().startswith("t,q.shoulder")


def test_planning_a_third_party_ur5_gives_torques_equal_to_pinocchios_rnea(tmp_path, monkeypatch):
    """A real URDF from example-robot-data, through the CLI, checked against Pinocchio."""
    import sysconfig

    pin = pytest.importorskip("pinocchio")
    urdf = (Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix" / "share" / "example-robot-data" / "robots"
            / "ur_description" / "urdf" / "ur5_robot.urdf")
    assert urdf.is_file(), "the test extra installs example-robot-data"
    monkeypatch.chdir(tmp_path)
    (tmp_path / "ur5.yaml").write_text(
        f"robot: {urdf}\nx0: {{q: [0.0, -1.2, 1.2, -1.5, -1.5, 0.0]}}\n"
        "x1: {q: [1.0, -1.0, 1.0, -1.3, -1.2, 0.5]}\nT: 1.5\nN: 8\noutput: {rate: 20}\n")
    r = invoke("plan", "ur5.yaml", "-o", "ur5.csv", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["converged"] is True
    tr = read_csv(tmp_path / "ur5.csv")
    model = pin.buildModelFromUrdf(str(urdf))
    data = model.createData()
    names = [model.names[i] for i in range(1, model.njoints)]
    idx = [names.index(j) for j in tr.joints]
    for k in range(tr.K):
        q, v, a = (np.zeros(model.nq) for _ in range(3))
        q[idx], v[idx], a[idx] = tr.q[k], tr.dq[k], tr.ddq[k]
        tau = pin.rnea(model, data, q, v, a)[idx]
        np.testing.assert_allclose(tr.u[k], tau, rtol=1e-10, atol=1e-10 * np.abs(tau).max())


def test_check_gradient_passes_on_the_task_and_writes_nothing(task, tmp_path):
    r = invoke("plan", task, "--check-gradient", "--json")
    assert r.exit_code == 0, r.output
    c = json.loads(r.stdout)["gradient_check"]
    assert c["passed"] is True and c["max_rel_error"] <= c["rtol"] == 1e-6
    assert c["coordinates"] == c["of"] == (8 + 1) * 3 * 2 - 4 * 2  # every free coefficient of N = 8, quintic, n = 2
    assert not (tmp_path / "arm.csv").exists() and not (tmp_path / "arm.mcap").exists()
    assert invoke("plan", task, "--check-gradient", "-o", "x.csv").exit_code == 2
    r = invoke("plan", task, "--check-gradient", "--json", "-N", "1", "--order", "cubic")  # nothing is free
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["gradient_check"]["coordinates"] == 0


def test_check_gradient_catches_a_wrong_gradient_and_exits_1(task, monkeypatch):
    """A 0.1 % error in ∂L/∂q̈ (a plausible bug) fails the check."""
    from hoc_cli.problem import ControlProblem

    right = ControlProblem.gradient_from_samples
    monkeypatch.setattr(ControlProblem, "gradient_from_samples",
                        lambda self, gq, gdq, gddq: right(self, gq, gdq, 1.001 * gddq))
    r = invoke("plan", task, "--check-gradient", "--json")
    assert r.exit_code == 1, r.output
    c = json.loads(r.stdout)["gradient_check"]
    assert c["passed"] is False and 1e-4 < c["max_rel_error"] < 1e-2
    assert c["worst"]["joint"] in ("shoulder", "elbow") and c["worst"]["derivative"] in ("q", "dq", "ddq")


def test_tol_below_the_rounding_level_says_the_rounding_level_test_held(task):
    r = invoke("plan", task, "--tol", "1e-300", "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["status"] == "converged" and s["message"].startswith("the rounding-level test held")
    r = invoke("plan", task, "--json")
    assert json.loads(r.stdout)["message"].startswith("the stopping test held: ½ gᵀP⁻¹g <= tol·|J|")


def test_check_gradient_on_a_large_mesh_checks_a_fixed_subset(task, monkeypatch):
    from hoc_cli.commands import plan as cmd

    monkeypatch.setattr(cmd, "GRADIENT_MAX_COORDINATES", 5)
    runs = [json.loads(invoke("plan", task, "--check-gradient", "--json").stdout)["gradient_check"] for _ in range(2)]
    assert runs[0]["coordinates"] == 5 and runs[0]["of"] == 46 and runs[0]["passed"] is True
    assert runs[0] == runs[1]  # the same subset every time
