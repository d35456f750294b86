"""Warm replans with limits that bind: every Newton step solves its inequality QP exactly
(``hoc_cli.goals.qp_step``, ``hoc_cli.goals.replan_qp``).

References: the QP's answer is certified by its KKT conditions (a convex QP: stationarity, feasibility,
μ ≥ 0 and complementarity make a point optimal) and compared with scipy's SLSQP; the limit rows' values
and Jacobians against the augmented Lagrangian's own row evaluation; the replan against a cold solve of
the moved task by the augmented Lagrangian (J to 1e-8, within limits by the exact extrema check).
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize

from hoc_cli.constraints.bounds import KINEMATIC, JointLimits
from hoc_cli.constraints.check import check_limits
from hoc_cli.constraints.penalty import LimitRows
from hoc_cli.dynamics import link_poses
from hoc_cli.elements import HermiteMesh
from hoc_cli.goals import FrameResidual, Goals, inverse_kinematics, plan_goals
from hoc_cli.goals.active_limits import ActiveRows, all_rows, from_multipliers
from hoc_cli.goals.free_time_sqp import COARSE_N, COLD_STEPS
from hoc_cli.goals.qp_step import bordered_factor, solve_qp, upper_factor
from hoc_cli.goals.replan import TimeRange, replan
from hoc_cli.model import load_robot
from hoc_cli.problem import Layout
from hoc_cli.system import RobotSystem
from tests._robots import ROBOTS, ROOT, steps_on_mesh

MODEL = load_robot(ROBOTS / "two_link.urdf")
SYSTEM = RobotSystem(MODEL)
Q0, Z = np.array([0.0, 0.0]), np.zeros(2)
QG = np.array([1.0, -0.5])
# the shoulder's velocity limit binds on the unmoved task (its unconstrained peak is ~1.6 rad/s)
LIMITS = JointLimits.from_arrays(MODEL.joint_names, velocity=[1.3, 10.0])


def goals_at(dx: float) -> Goals:
    p = link_poses(MODEL, QG)["tool"][:3, 3] + np.array([dx, 0.0, 0.0])
    res = FrameResidual(MODEL, "tool", p)
    return Goals(final=res, q1_guess=inverse_kinematics(res, QG, 1.0))


def random_qp(rng, P=12, r=2, k=30, dependent=True):
    M = rng.standard_normal((P, P))
    H = M @ M.T + 0.1 * np.eye(P)
    g = rng.standard_normal(P)
    E = rng.standard_normal((r, P))
    e = rng.standard_normal(r) * 0.1
    A = rng.standard_normal((k, P))
    if dependent:  # repeated and combined rows, as the Bernstein rows of a saturated element
        A[k // 2:] = A[: k - k // 2] * 2.0
    b = rng.uniform(0.0, 0.5, k) * (A @ np.zeros(P) + 1.0)
    return H, g, E, e, A, b


@pytest.mark.parametrize("seed", range(6))
def test_qp_step_meets_its_kkt_conditions_and_slsqp(seed):
    rng = np.random.default_rng(seed)
    H, g, E, e, A, b = random_qp(rng, dependent=seed % 2 == 0)
    s = solve_qp(upper_factor(H), g, E, e, A, b)
    d = s.d
    scale = 1.0 + np.abs(g).max()
    assert np.max(np.abs(E @ d - e)) <= 1e-10 * scale
    assert np.max(A @ d - b) <= 1e-10 * scale
    assert np.all(s.mu >= 0)
    assert np.max(np.abs(s.mu * (A @ d - b))) <= 1e-9 * scale  # complementarity
    stationarity = H @ d + g + E.T @ s.nu + A.T @ s.mu
    assert np.max(np.abs(stationarity)) <= 1e-9 * scale
    ref = minimize(lambda x: g @ x + 0.5 * x @ H @ x, np.zeros(g.size), jac=lambda x: g + H @ x, method="SLSQP",
                   constraints=[{"type": "eq", "fun": lambda x: E @ x - e, "jac": lambda x: E},
                                {"type": "ineq", "fun": lambda x: b - A @ x, "jac": lambda x: -A}],
                   options={"ftol": 1e-14, "maxiter": 500})
    assert ref.success
    assert g @ d + 0.5 * d @ H @ d <= ref.fun + 1e-9 * scale
    assert np.max(np.abs(d - ref.x)) <= 1e-5 * scale


def test_qp_step_without_rows_is_the_newton_step():
    rng = np.random.default_rng(7)
    H, g, *_ = random_qp(rng)
    s = solve_qp(upper_factor(H), g, np.zeros((0, g.size)), np.zeros(0), np.zeros((0, g.size)), np.zeros(0))
    assert np.allclose(s.d, -np.linalg.solve(H, g), rtol=1e-10, atol=1e-12)
    assert s.decrease == pytest.approx(0.5 * g @ np.linalg.solve(H, g), rel=1e-10)


def test_bordered_factor_is_the_cholesky_factor_of_the_bordered_matrix():
    rng = np.random.default_rng(5)
    H, *_ = random_qp(rng)
    b = rng.standard_normal(H.shape[0])
    h = float(b @ np.linalg.solve(H, b)) + 0.3
    U = bordered_factor(upper_factor(H), b, h)
    assert np.allclose(U.T @ U, np.block([[H, b[:, None]], [b[None, :], np.array([[h]])]]), rtol=1e-12, atol=1e-10)
    with pytest.raises(Exception):
        bordered_factor(upper_factor(H), b, h - 0.4)


@pytest.mark.parametrize("uniform", [True, False])
def test_active_rows_values_and_jacobian_match_the_penalty_rows(uniform):
    """g = A_full·C + offsets reproduces every kinematic row's g of the augmented Lagrangian's evaluation,
    and A is its derivative (a linear map: one random direction, exact)."""
    rng = np.random.default_rng(3)
    mesh = HermiteMesh("quintic", 1.0, 4) if uniform else HermiteMesh.from_nodes("quintic", [0.0, 0.2, 0.5, 0.6, 1.0])
    n = 2
    limits = JointLimits.from_arrays(MODEL.joint_names, lower=[-1.0, -2.0], upper=[1.5, 2.0], velocity=[1.0, 2.0],
                                     acceleration=[5.0, 6.0])
    layout = Layout.build(mesh, n)
    rows = LimitRows.build(mesh, layout.free, n)
    C = rng.standard_normal((mesh.N + 1, mesh.m, n))
    pv = all_rows(SYSTEM, limits, rows, C)
    sel = ActiveRows.where(tuple(np.isfinite(g) for g in pv.g_lo[:KINEMATIC]), tuple(np.isfinite(g) for g in pv.g_hi[:KINEMATIC]))
    A, A_full = sel.jacobian(rows, limits, layout.free)
    values = A_full @ C.ravel() + sel.offsets(limits)
    assert np.allclose(values, sel.gather(pv.g_lo, pv.g_hi), rtol=1e-12, atol=1e-12)
    dC = rng.standard_normal(C.shape)
    moved = all_rows(SYSTEM, limits, rows, C + dC)
    assert np.allclose(sel.gather(moved.g_lo, moved.g_hi) - values, A_full @ dC.ravel(), rtol=1e-10, atol=1e-10)


@pytest.fixture(scope="module")
def previous():
    plan = plan_goals(SYSTEM, HermiteMesh("quintic", 1.0, 8), Q0, Z, goals_at(0.0), limits=LIMITS)
    assert plan.converged
    active = from_multipliers(plan.limits.penalty)
    assert active is not None and active.size > 0  # the velocity limit binds
    return plan


def test_the_goal_rows_and_the_limits_are_two_terms_of_one_augmented_lagrangian_loop(monkeypatch, previous):
    """Each level's loop has both terms, one inner solve per outer iteration (the goal rows have no loop of their
    own inside each of the limits' iterations, which took 47 inner solves here); the same plan to 1e-9."""
    from hoc_cli.constraints import auglag

    runs, minimize = [], auglag.minimize

    def recorded(base, terms, *args, **kwargs):
        out = minimize(base, terms, *args, **kwargs)
        runs.append(([type(t).__name__ for t in terms], out.outer))
        return out

    monkeypatch.setattr(auglag, "minimize", recorded)
    plan = plan_goals(SYSTEM, HermiteMesh("quintic", 1.0, 8), Q0, Z, goals_at(0.0), limits=LIMITS)
    assert plan.converged and runs and all(names == ["GoalTerm", "LimitTerm"] for names, _ in runs)
    assert plan.outer_iterations == sum(outer for _, outer in runs) <= 25
    assert plan.J == pytest.approx(previous.J, rel=1e-9)  # unchanged by the recording


@pytest.mark.parametrize("dx", [0.002, 0.01, 0.03])
def test_replan_with_binding_limits_meets_the_cold_optimum(previous, dx):
    warm = replan(SYSTEM, previous, goals_at(dx), limits=LIMITS, fallback=False)
    cold = plan_goals(SYSTEM, previous.mesh, Q0, Z, goals_at(dx), limits=LIMITS)
    assert warm.converged and not warm.fallback and 0 < warm.steps <= 8
    assert warm.plan.J == pytest.approx(cold.J, rel=1e-8)
    assert check_limits(SYSTEM, LIMITS, warm.plan.mesh, warm.plan.coeffs).feasible
    p = link_poses(MODEL, warm.plan.coeffs[-1, 0])["tool"][:3, 3]
    assert np.max(np.abs(p - goals_at(dx).final.position)) <= 1e-9
    # the limit still binds, and the plan's multipliers say where
    assert warm.plan.limits.penalty is not None
    assert any(np.any(m > 0) for m in warm.plan.limits.penalty.mu_hi[:KINEMATIC] + warm.plan.limits.penalty.mu_lo[:KINEMATIC])


def test_free_time_replan_with_binding_limits_is_a_free_time_optimum(previous):
    """weight 1: after a 1 cm move the replan's T makes dJ*/dT = −weight (|.| to 1e-6 relative), and fixed-T
    plans with the limits at T ± 1 % cost no less (J + weight·T)."""
    span = TimeRange(0.6, 1.6, weight=1.0)
    first = replan(SYSTEM, previous, goals_at(0.0), free=span, limits=LIMITS, fallback=False)
    assert first.converged
    warm = replan(SYSTEM, first, goals_at(0.01), free=span, limits=LIMITS, fallback=False)
    assert warm.converged and not warm.fallback and warm.steps <= 8
    assert check_limits(SYSTEM, LIMITS, warm.plan.mesh, warm.plan.coeffs).feasible
    T = warm.T
    for factor in (0.99, 1.01):
        other = plan_goals(SYSTEM, HermiteMesh("quintic", T * factor, 8), Q0, Z, goals_at(0.01), limits=LIMITS)
        assert other.converged
        assert other.J + span.weight * T * factor >= warm.plan.J + span.weight * T - 1e-9 * warm.plan.J


@pytest.mark.parametrize("cold_steps", [0, COLD_STEPS])
@pytest.mark.parametrize("limits, fractions", [(None, None), (LIMITS, None),
                                               (LIMITS, [0.0, 0.1, 0.3, 0.45, 0.5, 0.6, 0.75, 0.9, 1.0])])
def test_free_time_by_sqp_steps_meets_the_search(limits, fractions, cold_steps):
    """``minimize_time_sqp`` against the search over fixed-T solves (``minimize_time``): the same T (1e-6
    relative) and J + weight·T (1e-9 relative), on N equal elements and on a non-uniform mesh that scales
    with T; the plan at the guess both ways: with limits, by Newton steps at fixed T from the initial
    trajectory (on the non-uniform mesh G then grows to the converged quadrature; on the equal elements by way of the
    coarse stage), and, without limits or with ``cold_steps=0``, by one fixed-T solve (``plan_goals``)."""
    from hoc_cli.free_time import minimize_time
    from hoc_cli.goals.free_time_sqp import minimize_time_sqp
    from hoc_cli.goals.time_solver import goal_solver

    goals = goals_at(0.01)
    fractions = None if fractions is None else np.array(fractions)
    solver = goal_solver(SYSTEM, "quintic", 8, Q0, Z, goals, limits=limits, fractions=fractions)
    search = minimize_time(solver, 0.6, 1.6, guess=0.95, weight=1.0)
    sqp = minimize_time_sqp(solver, SYSTEM, goals, 0.6, 1.6, guess=0.95, weight=1.0, limits=limits,
                            cold_steps=cold_steps)
    # the plan at the guess and the Newton steps' plan; with limits on 8 equal elements one plan on the mesh: the coarse
    # optimum's steps (the guess breaks a velocity limit: the restoration runs on the coarse stage's 4 elements)
    coarse_path = bool(cold_steps and limits is not None and fractions is None)
    assert sqp.converged and len(sqp.history) == (1 if coarse_path else 2)
    by_steps = sqp.history[0].result.optimizer.message.startswith("warm replan")
    assert by_steps == bool(cold_steps and limits is not None)
    assert sqp.bound is None and search.bound is None
    assert sqp.T == pytest.approx(search.T, rel=1e-6)
    assert sqp.objective == pytest.approx(search.objective, rel=1e-9)
    assert abs(sqp.dJ_dT + 1.0) <= 1e-6 * (sqp.J / sqp.T + 1.0)
    if limits is not None:
        assert check_limits(SYSTEM, limits, sqp.result.mesh, sqp.result.coeffs).feasible
    assert sqp.result.mesh.uniform == (fractions is None)


def test_free_time_first_on_a_coarse_mesh_meets_the_steps_on_the_mesh(monkeypatch):
    """From a guess whose initial trajectory keeps the limits (T = 1.5 s; at 0.95 s it breaks the velocity limit and
    the restoration runs instead), ``minimize_time_sqp`` finds T on ``COARSE_N`` elements first and then needs a few
    steps in x and T on the mesh: the same optimum as the steps on the mesh alone (``coarse=0``: T to 1e-8,
    J + weight·T to 1e-12 relative), stationary in T, within the limits by the exact check."""
    from hoc_cli.goals.free_time_sqp import minimize_time_sqp
    from hoc_cli.goals.time_solver import goal_solver

    goals = goals_at(0.01)
    solver = goal_solver(SYSTEM, "quintic", 8, Q0, Z, goals, limits=LIMITS)
    fine = minimize_time_sqp(solver, SYSTEM, goals, 0.6, 1.6, guess=1.5, weight=1.0, limits=LIMITS, coarse=0)
    on_mesh = steps_on_mesh(monkeypatch, 8)
    coarse = minimize_time_sqp(solver, SYSTEM, goals, 0.6, 1.6, guess=1.5, weight=1.0, limits=LIMITS, coarse=COARSE_N)
    assert fine.converged and coarse.converged and coarse.bound is None
    assert len(fine.history) == 2 and len(coarse.history) == 1  # one plan on the mesh: the coarse optimum's steps
    assert sum(on_mesh) <= 6 < fine.result.optimizer.iterations
    assert coarse.result.optimizer.iterations > sum(on_mesh)  # the plan reports the coarse stage's steps too
    assert coarse.T == pytest.approx(fine.T, rel=1e-8)
    assert coarse.objective == pytest.approx(fine.objective, rel=1e-12)
    assert abs(coarse.dJ_dT + 1.0) <= 1e-6 * (coarse.J / coarse.T + 1.0)
    assert check_limits(SYSTEM, LIMITS, coarse.result.mesh, coarse.result.coeffs).feasible


def test_replan_with_a_binding_effort_limit_keeps_the_penalty_steps():
    """An effort limit (90 % of the shoulder's unconstrained peak torque) binds: the limits are not linear
    rows, so the replan keeps them as augmented-Lagrangian terms; after 2 mm and 1 cm moves it meets the
    cold solve of the moved task (J to 1e-9) within the limits."""
    mesh = HermiteMesh("quintic", 1.0, 8)
    free = plan_goals(SYSTEM, mesh, Q0, Z, goals_at(0.0))
    t = np.linspace(0.0, 1.0, 200)
    u = SYSTEM.inverse_dynamics(*(mesh.evaluate(free.coeffs, t, d) for d in range(3)))
    peak = np.abs(u).max(axis=0)
    limits = JointLimits.from_arrays(MODEL.joint_names, effort=[0.9 * peak[0], 10.0 * peak[1]])
    base = plan_goals(SYSTEM, mesh, Q0, Z, goals_at(0.0), limits=limits)
    assert base.converged and from_multipliers(base.limits.penalty) is None  # effort multipliers: penalty steps
    for dx in (0.002, 0.01):
        warm = replan(SYSTEM, base, goals_at(dx), limits=limits, fallback=False)
        cold = plan_goals(SYSTEM, mesh, Q0, Z, goals_at(dx), limits=limits)
        assert warm.converged and not warm.fallback
        assert warm.plan.J == pytest.approx(cold.J, rel=1e-9)
        assert check_limits(SYSTEM, limits, warm.plan.mesh, warm.plan.coeffs).feasible


def _task(path, text: str):
    """(system, goals, limits, x0 states) of a task file written at ``path``."""
    from hoc_cli.io.robot import load_model
    from hoc_cli.io.task import load_task, resolve
    from hoc_cli.io.task.problem import task_goals, task_limits

    path.write_text(text)
    task = load_task(path, purpose="plan")
    model = load_model(task)
    states = resolve(task, model.joint_names)
    return RobotSystem(model), task_goals(task, model, states), task_limits(model, states.limits), states


def _from_initial(system, goals, limits, states, mesh, merit: bool):
    from hoc_cli.goals.free_time_sqp import COLD_FLOOR, COLD_STEPS
    from hoc_cli.goals.warm import initial_plan

    start = initial_plan(system, mesh, states.q0, states.dq0, goals)
    return replan(system, start, goals, limits=limits, fallback=False, max_steps=COLD_STEPS,
                  violation_floor=COLD_FLOOR, merit=merit)


def test_steps_from_the_initial_trajectory_need_the_merit_test(tmp_path):
    """The plan at a free T's guess by Newton steps from the initial trajectory (``minimize_time_sqp``'s first
    phase): on a two-link link goal with gravity and URDF limits, the steps whose length is chosen by the ℓ1
    merit function converge in a few steps to ``plan_goals``' optimum (J to 1e-10); steps damped by the goal
    rows' violation alone run J up to 10⁴ and back and take over 20 (or do not converge within ``COLD_STEPS``)."""
    import shutil

    shutil.copy(ROBOTS / "two_link.urdf", tmp_path / "arm.urdf")
    system, goals, limits, states = _task(tmp_path / "t.yaml", "robot: arm.urdf\ngravity: [0.0, 0.0, -9.81]\n"
                                          "x0: {q: [0.0, 0.0]}\nx1: {link: tool, position: [0.91, 0.0, 1.3], dq: zero}\n"
                                          "T: 1.0\nN: 8\norder: quintic\n")
    mesh = HermiteMesh("quintic", 1.0, 8)
    cold = plan_goals(system, mesh, states.q0, states.dq0, goals, limits=limits)
    r = _from_initial(system, goals, limits, states, mesh, True)
    assert r.converged
    assert r.plan.J == pytest.approx(cold.J, rel=1e-10)
    assert check_limits(system, limits, r.plan.mesh, r.plan.coeffs).feasible
    assert r.steps <= 8
    r = _from_initial(system, goals, limits, states, mesh, False)
    assert not r.converged or r.steps > 20


def test_steps_from_the_initial_trajectory_on_the_lbr7_converge_with_the_levenberg_marquardt_shift(tmp_path):
    """The lbr7's flange to a point at rest (T = 1 s, URDF limits): the programme's full steps are far too long in
    the wrist's flat directions (the merit test cut them to 1/32 for 50 steps); with the Levenberg-Marquardt
    shift that grows while steps are cut and vanishes once full steps pass, the steps converge within
    ``COLD_STEPS`` to ``plan_goals``' optimum (J to 1e-8: the two stopping tests differ), within the limits."""
    catch = (ROOT / "configs" / "catch_ball.yaml").read_text()
    text = "\n".join(line for line in catch.splitlines() if line.startswith(("x0:", "N:", "order:")))
    text = (f"robot: {ROOT / 'robots' / 'lbr7.urdf'}\n{text}\n"
            "x1: {link: lbr_flange, position: [0.5, 0.2, 0.6]}\nT: 1.0\n")
    system, goals, limits, states = _task(tmp_path / "t.yaml", text)
    mesh = HermiteMesh("quintic", 1.0, 8)
    r = _from_initial(system, goals, limits, states, mesh, True)
    assert r.converged
    cold = plan_goals(system, mesh, states.q0, states.dq0, goals, limits=limits)
    assert r.plan.J == pytest.approx(cold.J, rel=1e-8)
    assert check_limits(system, limits, r.plan.mesh, r.plan.coeffs).feasible
