"""``hoc plan --init PLAN.mcap`` on a free-T task: a warm replan (``hoc_cli.goals.replan``) from the plan's T
and coefficients, with the goal multipliers estimated by least squares (``hoc_cli.goals.warm``). After the
target moves 1 cm it converges in a few Newton steps to the cold plan's T and J, and J equals a cold
fixed-T plan at its T; with vias off the uniform mesh the replan's mesh keeps their nodes."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from typer.testing import CliRunner

from hoc_cli.cli import app
from hoc_cli.dynamics import link_poses
from hoc_cli.elements import HermiteMesh
from hoc_cli.goals import FrameResidual, Goals, inverse_kinematics, plan_goals
from hoc_cli.goals.replan import TimeRange, replan
from hoc_cli.goals.warm import _limit_columns, estimate_state, previous_plan
from hoc_cli.model import load_robot
from hoc_cli.system import RobotSystem
from tests._robots import ROBOTS

MODEL = load_robot(ROBOTS / "two_link.urdf")
SYSTEM = RobotSystem(MODEL)
Z = np.zeros(2)
TASK = """\
robot: arm.urdf
gravity: [0.0, 0.0, -9.81]
x0: {{q: [0.0, 0.0], dq: [0.0, 0.0]}}
x1: {{link: tool, position: [{x}, 0.0, 1.3], dq: zero}}
T: {{free: true, min: 0.5, max: 2.0, weight: 1.0}}
N: 8
order: quintic
{extra}"""


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    shutil.copy(ROBOTS / "two_link.urdf", tmp_path / "arm.urdf")
    monkeypatch.chdir(tmp_path)
    return tmp_path


def hoc_plan(d, name: str, text: str, *extra: str) -> dict:
    (d / name).write_text(text)
    r = CliRunner().invoke(app, ["plan", name, "--json", "-q", *extra])
    assert r.exit_code == 0, r.output
    return json.loads(r.stdout)


def test_init_on_a_free_time_task_is_a_warm_replan_to_the_cold_optimum(workdir):
    """The tool's goal moves 1 cm: the replan from the first plan's MCAP takes ≤ 4 Newton steps (no
    fallback), its T and J are the cold plan's of the moved task (T to the cold search's own tolerance,
    1e-7), it is a stationary point in T (|dJ/dT + weight| ≤ 1e-7 (|J|/T + weight)), and a cold plan with T
    fixed at its T has its J to 1e-8."""
    first = hoc_plan(workdir, "first.yaml", TASK.format(x=0.9, extra=""), "-o", "first.mcap")
    assert first["converged"] and "warm_start" not in first
    moved = TASK.format(x=0.91, extra="")
    cold = hoc_plan(workdir, "moved.yaml", moved, "-o", "cold.csv")
    warm = hoc_plan(workdir, "moved.yaml", moved, "--init", "first.mcap", "-o", "warm.csv")
    assert warm["converged"] and warm["warm_start"] == "replan" and not warm["replan_fallback"]
    assert 1 <= warm["replan_steps"] <= 4 and warm["iterations"] == warm["replan_steps"]
    assert warm["T"] == pytest.approx(cold["T"], rel=1e-7) and warm["T"] != first["T"]
    assert warm["cost"] == pytest.approx(cold["cost"], rel=1e-8)
    assert abs(warm["dJ_dT"] + 1.0) <= 1e-7 * (warm["cost"] / warm["T"] + 1.0)
    assert warm["T_bound"] is None and warm["T_converged"]
    fixed = hoc_plan(workdir, "moved.yaml", moved, "-T", repr(warm["T"]), "-o", "fixed.csv")
    assert fixed["cost"] == pytest.approx(warm["cost"], rel=1e-8)
    again = hoc_plan(workdir, "first.yaml", TASK.format(x=0.9, extra=""), "--init", "first.mcap", "-o", "same.csv")
    assert again["replan_steps"] == 0 and again["cost"] == first["cost"] and again["T"] == first["T"]


def test_init_from_another_mesh_order_and_T_resamples_and_converges(workdir):
    """A cubic plan on 12 elements at T = 1 s starts the quintic N = 8 free-T task: the replan reaches the
    cold optimum (J to 1e-8)."""
    text = TASK.format(x=0.9, extra="")
    hoc_plan(workdir, "task.yaml", text, "-T", "1.0", "-N", "12", "--order", "cubic", "-o", "cubic.mcap")
    cold = hoc_plan(workdir, "task.yaml", text, "-o", "cold.csv")
    warm = hoc_plan(workdir, "task.yaml", text, "--init", "cubic.mcap", "-o", "warm.csv")
    assert warm["converged"] and warm["warm_start"] == "replan" and warm["N"] == 8 and warm["order"] == "quintic"
    assert warm["cost"] == pytest.approx(cold["cost"], rel=1e-8)


def test_init_with_vias_off_the_uniform_mesh_is_a_warm_replan_on_that_mesh(workdir):
    """A joint via at s = 0.4 (the mesh is non-uniform; its nodes scale with T): the replan from the plan of the
    task itself converges in at most one step to the cold plan's J (1e-8), the via still met to 1e-12."""
    text = TASK.format(x=0.9, extra="via: [{s: 0.4, q: [0.2, 0.6]}]\n")
    cold = hoc_plan(workdir, "task.yaml", text, "-o", "cold.mcap")
    warm = hoc_plan(workdir, "task.yaml", text, "--init", "cold.mcap", "-o", "warm.csv")
    assert cold["mesh"] == warm["mesh"] == "nonuniform" and warm["warm_start"] == "replan"
    assert warm["converged"] and not warm["replan_fallback"] and warm["replan_steps"] <= 1
    assert warm["cost"] == pytest.approx(cold["cost"], rel=1e-8)
    assert warm["vias"][0]["error"] <= 1e-12


def moving(dx: float) -> Goals:
    """The two-link catch of a target moving at 0.2 m/s along x (position and velocity matched at T)."""
    qg = np.array([1.0, -0.5])
    p = link_poses(MODEL, qg)["tool"][:3, 3] - [0.1 - dx, 0.0, 0.0]
    res = FrameResidual(MODEL, "tool", p, velocity=np.array([0.2, 0.0, 0.0]), acceleration=np.zeros(3),
                        match_velocity=True)
    return Goals(final=res, q1_guess=inverse_kinematics(res, qg, 0.5), dq1_guess=Z)


def test_least_squares_multipliers_are_the_solvers_and_save_the_first_step():
    """At an optimum the least-squares λ of ∇ₓJ + Dᵀλ = 0 equal the augmented Lagrangian's converged
    multipliers (1e-6); started from them an unchanged goal needs no Newton step, from zeros one (after
    the target moved 1 cm both take the same steps to the same optimum: measured 20)."""
    base = plan_goals(SYSTEM, HermiteMesh("quintic", 0.6, 8), Z, Z, moving(0.0))
    assert base.converged
    prev = previous_plan(SYSTEM, base.mesh, base.coeffs, Z, Z, moving(0.0), G=base.G)
    lam, ref = np.concatenate(prev.terms.lam), np.concatenate(base.terms.lam)
    assert np.max(np.abs(lam - ref)) <= 1e-6 * np.max(np.abs(ref))
    x = prev.problem.layout.pack(prev.coeffs)
    assert np.array_equal(np.concatenate(estimate_state(SYSTEM, prev.problem, prev.coeffs,
                                                        prev.problem.evaluate(x).grad)[0]), lam)
    assert prev.limits is None
    zeros = previous_plan(SYSTEM, base.mesh, base.coeffs, Z, Z, moving(0.0), G=base.G, multipliers="zeros")
    assert replan(SYSTEM, prev, moving(0.0), fallback=False).steps == 0
    assert replan(SYSTEM, zeros, moving(0.0), fallback=False).steps >= 1
    span = TimeRange(0.3, 1.5, 1.0)
    a, b = (replan(SYSTEM, p, moving(0.01), free=span, fallback=False, max_steps=60) for p in (prev, zeros))
    assert a.converged and b.converged and abs(a.steps - b.steps) <= 1
    assert a.T == pytest.approx(b.T, rel=1e-7) and a.plan.J == pytest.approx(b.plan.J, rel=1e-9)


def test_the_limits_state_is_estimated_with_the_goal_multipliers():
    """A link goal at T = 0.8 s with velocity limits at 80 % of the free plan's peaks (both joints bind): from
    the limited optimum's coefficients alone, λ equals the augmented Lagrangian's (1e-6), the working set
    is the limits loop's, every μ ≥ 0, and ∇ₓJ + Dᵀλ + Σ μ ∂g/∂x vanishes to 1e-6 of ‖∇ₓJ‖ (47/62 of it
    without the limits' term: they matter); a replan of the same goals takes at most one step (its QP's
    exact rows) to the same J (1e-9)."""
    from hoc_cli.constraints.bounds import JointLimits
    from hoc_cli.constraints.penalty import LimitRows
    from hoc_cli.goals.terms import GoalTerms

    res = FrameResidual(MODEL, "tool", np.array([0.9, 0.0, 1.3]))
    goals = Goals(final=res, q1_guess=inverse_kinematics(res, Z, 1.0))
    mesh = HermiteMesh("quintic", 0.8, 8)
    free = plan_goals(SYSTEM, mesh, Z, Z, goals)
    peak = np.abs(mesh.evaluate(free.coeffs, np.linspace(0.0, 0.8, 200), 1)).max(axis=0)
    limits = JointLimits.from_arrays(MODEL.joint_names, velocity=0.8 * peak)
    base = plan_goals(SYSTEM, mesh, Z, Z, goals, limits=limits)
    assert base.converged and base.limits.working[1].all()
    prev = previous_plan(SYSTEM, mesh, base.coeffs, Z, Z, goals, G=base.G, limits=limits)
    lam, ref = np.concatenate(prev.terms.lam), np.concatenate(base.terms.lam)
    assert np.max(np.abs(lam - ref)) <= 1e-6 * np.max(np.abs(ref))
    assert np.array_equal(prev.limits.working, base.limits.working)
    problem, C = prev.problem, prev.coeffs
    g = problem.evaluate(problem.layout.pack(C)).grad
    rows = LimitRows.build(mesh, problem.layout.free, 2)
    candidates, A = _limit_columns(SYSTEM, limits, rows, C, problem.layout.free, 1e-3)
    pen = prev.limits.penalty
    mu = np.array([(pen.mu_hi if side > 0 else pen.mu_lo)[k][idx] for k, side, idx in candidates])
    assert len(candidates) > 2 and np.all(mu >= 0) and mu.max() > 0
    c, dc = GoalTerms.start(mesh, problem.points).jacobian(C)
    D = dc.reshape(len(c), -1)[:, problem.layout.free]
    assert np.linalg.norm(g + D.T @ lam + A @ mu) <= 1e-6 * np.linalg.norm(g)
    assert np.linalg.norm(g + D.T @ lam) >= 0.5 * np.linalg.norm(g)
    # a replan of the same goals polishes the augmented Lagrangian's rows in at most one exact QP step
    same = replan(SYSTEM, prev, goals, limits=limits, fallback=False)
    assert same.converged and same.steps <= 1 and same.plan.J == pytest.approx(base.J, rel=1e-9)


def test_init_on_the_lbr7_catch_with_binding_velocity_limits(tmp_path, monkeypatch):
    """configs/catch_ball.yaml (free T, moving target, velocity limits binding): --init from its own plan is
    accepted with no Newton step (exit 0); after the ball's start moves 3 mm the replan converges, without
    the fallback, to the cold plan of the moved task (J to 1e-9, T to 1e-7), within the limits."""
    from pathlib import Path

    monkeypatch.chdir(tmp_path)
    root = Path(__file__).resolve().parents[1]
    text = (root / "configs" / "catch_ball.yaml").read_text().replace("../robots/", f"{root}/robots/")
    first = hoc_plan(tmp_path, "catch.yaml", text, "-o", "first.mcap")
    assert first["converged"] and first["active_limits"]
    same = hoc_plan(tmp_path, "catch.yaml", text, "--init", "first.mcap", "-o", "same.csv")
    assert same["converged"] and same["replan_steps"] == 0 and same["cost"] == pytest.approx(first["cost"], rel=1e-12)
    moved = text.replace("position: [0.6725, -0.0375, 0.1246]", "position: [0.6755, -0.0375, 0.1246]")
    assert moved != text
    warm = hoc_plan(tmp_path, "moved.yaml", moved, "--init", "first.mcap", "-o", "warm.csv")
    cold = hoc_plan(tmp_path, "moved.yaml", moved, "-o", "cold.csv")
    assert warm["converged"] and not warm["replan_fallback"] and warm["replan_steps"] <= 10
    assert warm["cost"] == pytest.approx(cold["cost"], rel=1e-9) and warm["T"] == pytest.approx(cold["T"], rel=1e-7)
    assert warm["limit_violations"] == [] and warm["reached"]["position_error"] <= 1e-9
