"""Issue 13 items 2, 3, 7: `-o none`, `simulate --integrator` (and the deprecated `--method`), `--tol` and
`--max-iter` honoured, and a Hermite integrator that subdivides an element whose Newton iteration fails.

Reference: a plan's torque is u = ID(q_h, q̇_h, q̈_h) of its own Hermite trajectory q_h, so q_h solves the
forward dynamics exactly and a replay must land on the plan's final state (`--check 1e-8` against x1).
"""
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from hoc_cli.cli import app
from hoc_cli.elements import HermiteMesh
from hoc_cli.errors import NumericalError
from hoc_cli.io.mcap import read_plan
from hoc_cli.model import load_robot
from hoc_cli.simulate import MAX_SPLIT_DEPTH, simulate_hermite
from hoc_cli.system import RobotSystem
from hoc_cli.torque import PlannedTorque
from tests._robots import task_configs

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = task_configs()  # the hoc catch scenario is not a task


def hoc(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    shutil.copytree(ROOT / "configs", tmp_path / "configs", ignore=shutil.ignore_patterns("*.png"))
    shutil.copytree(ROOT / "robots", tmp_path / "robots")
    monkeypatch.chdir(tmp_path)
    return tmp_path


# --------------------------------------------------------------------------- -o none
@pytest.mark.parametrize("command", ["plan", "simulate"])
def test_o_none_writes_no_file_and_prints_the_json_summary(workdir, command):
    before = sorted(p.name for p in workdir.iterdir())
    if command == "simulate":
        assert hoc("plan", "configs/pendulum_swing.yaml", "-o", "p.mcap", "-q").exit_code == 0
        before = sorted(p.name for p in workdir.iterdir())
        r = hoc("simulate", "p.mcap", "-o", "none", "--json")
    else:
        r = hoc("plan", "configs/pendulum_swing.yaml", "-o", "none", "--json")
    assert r.exit_code == 0, r.output
    summary = json.loads(r.stdout)
    assert summary["outputs"] == []
    assert sorted(p.name for p in workdir.iterdir()) == before


def test_o_none_with_another_output_is_refused_with_exit_2(workdir):
    r = hoc("plan", "configs/pendulum_swing.yaml", "-o", "none", "-o", "a.csv")
    assert r.exit_code == 2
    assert r.stderr.count("\n") == 1 and "'-o none' writes no file" in r.stderr
    assert not (workdir / "a.csv").exists()


# --------------------------------------------------------------------------- --integrator, --method
@pytest.fixture
def pendulum_plan(workdir):
    assert hoc("plan", "configs/pendulum_swing.yaml", "-o", "p.mcap", "-q").exit_code == 0
    return workdir / "p.mcap"


@pytest.mark.parametrize("integrator", ["hermite", "rk"])
def test_integrator_option_picks_the_integrator_and_the_summary_names_it(pendulum_plan, integrator):
    r = hoc("simulate", pendulum_plan, "--integrator", integrator, "--json", "-o", "none")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["integrator"] == s["method"] == integrator
    assert (s["N"] is None) == (integrator == "rk")
    assert r.stderr == ""


def test_the_deprecated_method_option_still_works_with_a_note_on_stderr(pendulum_plan):
    new = json.loads(hoc("simulate", pendulum_plan, "--integrator", "rk", "--json", "-o", "none").stdout)
    r = hoc("simulate", pendulum_plan, "--method", "rk", "--json", "-o", "none")
    assert r.exit_code == 0
    old = json.loads(r.stdout)
    assert old["integrator"] == "rk" and old["final_state"] == new["final_state"]
    assert r.stderr.count("\n") == 1 and "deprecated" in r.stderr and "--integrator rk" in r.stderr
    quiet = hoc("simulate", pendulum_plan, "--method", "rk", "-o", "none", "-q")
    assert quiet.exit_code == 0 and quiet.stderr == ""


@pytest.mark.parametrize("args, needle", [
    (["--integrator", "euler"], "--integrator: expected one of hermite, rk"),
    (["--integrator", "rk", "--method", "hermite"], "disagree"),
    (["--tol", "0"], "--tol: expected a tolerance > 0"),
    (["--max-iter", "0"], "--max-iter: expected an integer >= 1"),
    (["--integrator", "rk", "--max-iter", "5"], "rk has none"),
])
def test_bad_integrator_options_are_one_line_and_exit_2(pendulum_plan, args, needle):
    r = hoc("simulate", pendulum_plan, *args, "-o", "none")
    assert r.exit_code == 2
    assert needle in r.stderr and r.stderr.strip().count("\n") <= 1  # at most the deprecation note before it


def test_tol_is_honoured_by_both_integrators(pendulum_plan):
    def run(*args):
        r = hoc("simulate", pendulum_plan, *args, "--json", "-o", "none")
        assert r.exit_code == 0, r.output
        return json.loads(r.stdout)

    tight, loose = run(), run("--tol", "1e-3")
    assert loose["iterations"] < tight["iterations"]
    assert tight["final_error"] < 1e-12 < loose["final_error"]
    rk_tight, rk_loose = run("--integrator", "rk"), run("--integrator", "rk", "--tol", "1e-5")
    assert rk_loose["evaluations"] < rk_tight["evaluations"]
    assert rk_tight["final_error"] < 1e-9 < rk_loose["final_error"] < 1e-3


def test_max_iter_is_honoured_an_element_that_needs_more_newton_steps_is_subdivided(pendulum_plan):
    s = json.loads(hoc("simulate", pendulum_plan, "--max-iter", "1", "--json", "-o", "none").stdout)
    assert s["subdivided"] and s["final_error"] < 1e-8
    assert "solved as" in s["message"]


# --------------------------------------------------------------------------- subdivision (maths)
def reach_plan(tmp_path):
    """The shipped reach, planned: its system and trajectory."""
    assert hoc("plan", ROOT / "configs" / "lbr7_reach.yaml", "-o", tmp_path / "r.mcap", "-q").exit_code == 0
    plan = read_plan(tmp_path / "r.mcap")
    system = RobotSystem(load_robot(ROOT / "robots" / "lbr7.urdf"))
    return system, plan.trajectory


def test_a_subdivided_simulation_lands_where_the_reference_integrator_does(tmp_path):
    system, tr = reach_plan(tmp_path)
    torque = PlannedTorque(system, tr.mesh, np.asarray(tr.coeffs))
    q0, dq0 = tr.q[0], tr.dq[0]
    exact = np.concatenate([tr.q[-1], tr.dq[-1]])  # u = ID(q_h, q̇_h, q̈_h): the plan's q_h solves the ODE exactly
    plain = simulate_hermite(system, q0, dq0, torque, tr.mesh)
    split = simulate_hermite(system, q0, dq0, torque, tr.mesh, max_iter=2)  # forces sub-elements (measured: element 0 as 4)
    assert plain.subdivided == () and split.subdivided
    assert all(e in range(tr.mesh.N) and k in (2, 4, 8, 16, 32) for e, k in split.subdivided)
    for sim in (plain, split):
        assert np.max(np.abs(np.concatenate(sim.final_state()) - exact)) < 1e-11
    # nodes before the first subdivided element are untouched
    first = split.subdivided[0][0]
    np.testing.assert_array_equal(split.coeffs[: first + 1], plain.coeffs[: first + 1])


def test_an_element_that_fails_at_every_depth_names_the_element_and_the_depth(tmp_path):
    system, tr = reach_plan(tmp_path)
    torque = PlannedTorque(system, tr.mesh, np.asarray(tr.coeffs))
    with pytest.raises(NumericalError, match=rf"element 0 \(t = 0 … .*even as {2 ** MAX_SPLIT_DEPTH} sub-elements"):
        simulate_hermite(system, tr.q[0], tr.dq[0], torque, HermiteMesh("quintic", tr.mesh.T, 1), max_iter=1)


# --------------------------------------------------------------------------- the shipped plans replay
@pytest.mark.parametrize("config", CONFIGS, ids=[c.stem for c in CONFIGS])
def test_every_shipped_plan_replays_to_1e_8_by_default(workdir, config):
    assert hoc("plan", f"configs/{config.name}", "-o", "p.mcap", "-q").exit_code == 0
    r = hoc("simulate", "p.mcap", "--check", "1e-8", "--json", "-o", "none")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["check"]["passed"] is True


def test_the_dual_arm_plan_without_limits_at_n_8_replays_by_subdividing(workdir):
    """The issue's report: this replay failed with "Newton step rejected down to λ = 0.00024"."""
    assert hoc("plan", "configs/dual_arm.yaml", "-N", "8", "--limits", "report", "-o", "d.mcap", "-q").exit_code == 0
    r = hoc("simulate", "d.mcap", "-N", "8", "--check", "1e-8", "--json", "-o", "none", "-q")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["subdivided"] and s["check"]["passed"]
    assert {"element", "t", "sub_elements"} == set(s["subdivided"][0])


def test_dual_arm_ships_with_a_mesh_fine_enough_for_its_cost():
    """J at the shipped N is within 0.5 % of J at 2N (at N = 8 it was 1 % off)."""
    costs = []
    for N in ("16", "32"):
        r = hoc("plan", ROOT / "configs" / "dual_arm.yaml", "-N", N, "-o", "none", "--json", "-q")
        costs.append(json.loads(r.stdout)["cost"])
    text = (ROOT / "configs" / "dual_arm.yaml").read_text()
    assert "\nN: 16\n" in text
    assert abs(costs[0] - costs[1]) < 5e-3 * costs[1]
