"""The dense SQP's steps (``hoc_cli.goals.replan_qp``): its stopping test and what keeps far steps long.

The lbr7 catch's steps from scratch at its guess T on 4 elements (``minimize_time_sqp``'s first phase on its coarse
mesh): the step re-solved with the limit rows it would break and the second-order correction of a step the merit
test or the violation floor would cut each save steps, to the same optimum.
"""
from __future__ import annotations

import numpy as np
import pytest

import hoc_cli.goals.replan_qp as replan_qp
from hoc_cli.goals.free_time_sqp import COLD_FLOOR, COLD_STEPS
from hoc_cli.goals.qp_step import QPStep
from hoc_cli.goals.replan import replan
from hoc_cli.goals.time_solver import goal_solver
from tests._robots import lbr7_catch_problem, lbr7_catch_start


@pytest.fixture(scope="module")
def catch():
    """(system, limits, goals, the initial trajectory at T = 0.35 s on 4 elements) of configs/catch_ball.yaml."""
    return lbr7_catch_start(N=4, T=0.35)


def _cold(catch, **kw):
    arm, limits, goals, start = catch
    return replan(arm, start, goals, limits=limits, fallback=False, max_steps=COLD_STEPS, violation_floor=COLD_FLOOR,
                  merit=True, **kw)


def test_rows_added_and_corrected_steps_save_steps_to_the_same_optimum(catch, monkeypatch):
    best = _cold(catch)
    assert best.converged and best.steps <= 30  # 10 measured
    for name, off in (("EXPAND_ROUNDS", 0), ("CORRECTION", False)):
        with monkeypatch.context() as m:
            m.setattr(replan_qp, name, off)
            other = _cold(catch)
        assert other.converged and other.steps > best.steps + 10, name  # 31 and 35 steps measured
        assert abs(other.plan.J - best.plan.J) <= 1e-11 * best.plan.J, name
    assert best.plan.violation <= 1e-9


def test_a_negative_model_decrease_is_not_an_optimum(catch, monkeypatch):
    """A converged plan whose programme is made to report a decrease of −1 (a step that raises the model to reach
    its rows) is not taken as converged by zero steps; with the true decrease it is."""
    arm, limits, goals, _ = catch
    done = _cold(catch)
    again = replan(arm, done, goals, limits=limits, fallback=False, max_steps=0)
    assert again.converged and again.steps == 0
    solve = replan_qp.solve_qp

    def raising(*args, **kwargs):
        s = solve(*args, **kwargs)
        return QPStep(d=s.d, nu=s.nu, mu=s.mu, decrease=-1.0)

    monkeypatch.setattr(replan_qp, "solve_qp", raising)
    assert not replan(arm, done, goals, limits=limits, fallback=False, max_steps=0).converged


def test_a_newton_matrix_costs_few_factorisations(catch, monkeypatch):
    """Where the goal rows' negative curvature makes the Newton matrix indefinite, no multiple of the cost's positive
    semi-definite part is searched for it (the matrix without the negative part follows at once), and the weights'
    search starts near the last one accepted."""
    from hoc_cli.banded import BandedSPD

    calls = []
    assemble = BandedSPD.assemble.__func__

    def counted(cls, *args, **kw):
        calls.append(1)
        return assemble(cls, *args, **kw)

    monkeypatch.setattr(BandedSPD, "assemble", classmethod(counted))
    r = _cold(catch)
    assert r.converged and len(calls) <= 2 * r.steps + 5  # 1.6 per step measured, 5.3 with searches from scratch


def test_the_weights_search_starts_where_asked():
    from hoc_cli.errors import NumericalError
    from hoc_cli.optimize.modify import gauss_newton_shift

    H, GN = -np.eye(2)[None] * 50.0, np.eye(2)[None]  # H + μ·GN factors for μ > 50; the first weight is 0.05
    tried = []

    def factor(M):
        tried.append(M[0, 0, 0])
        if M[0, 0, 0] <= 0:
            raise NumericalError("no")
        return M

    mu, _ = gauss_newton_shift(H, GN, factor)
    assert mu == pytest.approx(500.0) and len(tried) == 5  # 0.05, 0.5, 5, 50, 500
    tried.clear()
    mu, _ = gauss_newton_shift(H, GN, factor, start=10.0)
    assert mu == pytest.approx(100.0) and len(tried) == 2


def _catch_per_value(monkeypatch, name: str, values) -> tuple[list, list, tuple]:
    """The lbr7 catch at N = 8 planned by ``minimize_time_sqp`` once per value of ``free_time_sqp.<name>``: (the results,
    per run the (mesh's N, violation floor, steps) of each ``replan`` it made, (arm, limits, goals, problem))."""
    import hoc_cli.goals.free_time_sqp as fts

    problem = lbr7_catch_problem(N=8)
    arm, limits, goals = problem.system, problem.limits, problem.goals()
    solver = goal_solver(arm, "quintic", 8, problem.q0, problem.dq0, goals, limits=limits)
    calls: list = []
    run = fts.replan

    def spied(*args, **kwargs):
        r = run(*args, **kwargs)
        calls[-1].append((args[1].mesh.N, kwargs.get("violation_floor"), r.steps))
        return r

    monkeypatch.setattr(fts, "replan", spied)
    out = []
    for value in values:
        monkeypatch.setattr(fts, name, value)
        calls.append([])
        out.append(fts.minimize_time_sqp(solver, arm, goals, 0.3, 0.5, guess=0.35, limits=limits))
    return out, calls, (arm, limits, goals, problem)


def test_the_coarse_steps_at_the_guess_stop_early_for_a_free_time(monkeypatch):
    """With a free T the coarse steps at the guess (``free_time_sqp._coarse_replan``'s first stage) stop at
    ``COARSE_START_ACCURACY``: the lbr7 catch's take 7 steps there (9 to ``COARSE_ACCURACY``) and fewer steps in all,
    to the same optimum on the 8 elements (J to 1e-12, T to 1e-11 measured)."""
    import hoc_cli.goals.free_time_sqp as fts

    # the third value: a start that passes the loose test itself (its first programme's decrease is no distance to the
    # optimum; the torque catch's) gets the steps at the full accuracy from it: the same steps as with it throughout
    out, calls, _ = _catch_per_value(monkeypatch, "COARSE_START_ACCURACY",
                                     (fts.COARSE_START_ACCURACY, fts.COARSE_ACCURACY, 1e9))
    steps = [[s for *_, s in run] for run in calls]
    early, full, loose = out
    assert early.converged and full.converged
    assert steps[0][0] <= 8 < steps[1][0]  # 7 and 9 measured
    assert sum(steps[0]) < sum(steps[1])  # 18 and 20
    assert early.J == pytest.approx(full.J, rel=1e-12) and early.T == pytest.approx(full.T, rel=1e-9)
    assert steps[2][:2] == [0, steps[1][0]] and steps[2][2:] == steps[1][1:]
    assert loose.J == full.J and loose.T == full.T


def test_the_problem_and_rows_on_a_uniform_mesh_at_another_time_are_those_built_afresh():
    """``problem_on`` and ``rows_on`` rescale a uniform mesh's quadrature and limit rows to another T (a free T's
    steps evaluate each trial T) instead of building them: the same samples, cost and rows to rounding."""
    from hoc_cli.constraints.penalty import LimitRows
    from hoc_cli.elements import HermiteMesh
    from hoc_cli.goals.plan import GoalProblem
    from hoc_cli.goals.replan_point import problem_on, rows_on

    problem = lbr7_catch_problem(N=4)
    goals = problem.goals()
    built = []
    for T in (0.35, 0.41):
        mesh = HermiteMesh("quintic", T, 4)
        p = GoalProblem(problem.system, mesh, problem.q0, problem.dq0, goals, G=8)
        p.op_h = p.op
        built.append((mesh, p, LimitRows.build(mesh, p.layout.free, 7)))
    (_, p1, r1), (mesh2, p2, r2) = built
    p3, r3 = problem_on(p1, mesh2), rows_on(r1, mesh2)
    assert p3 is not None and r3 is not None and p3.mesh is mesh2 and p3.op_h is p3.op and r3.mesh is mesh2
    C = np.random.default_rng(3).normal(size=(5, 3, 7))
    for a, b in zip(p2.op.apply(C), p3.op.apply(C)):
        assert np.abs(a - b).max() <= 1e-13 * np.abs(a).max()
    assert np.allclose(p3.op.t, p2.op.t, rtol=1e-15, atol=0) and np.allclose(p3.op.w, p2.op.w, rtol=1e-15, atol=0)
    x = p2.layout.pack(C)
    assert abs(p3.value(x) - p2.value(x)) <= 1e-12 * abs(p2.value(x))
    for k in range(4):
        a, b = (r.apply(k, mesh2.local_coefficients(C)) for r in (r3, r2))
        assert np.abs(a - b).max() <= 1e-12 * np.abs(b).max()
    assert all(np.array_equal(a, b) for a, b in zip(r3.data, r2.data))
    assert problem_on(p1, HermiteMesh("quintic", 0.41, 8)) is None and rows_on(r1, HermiteMesh("quintic", 0.41, 8)) is None


def test_a_newton_matrix_reuses_the_point_s_dynamics_and_goal_curvature(catch, monkeypatch):
    """The Hessian sweep takes the torques and mass matrices of the point's evaluation (``hessian_samples(ev, samples)``),
    and the goal rows' curvature is differenced once for the blocks with and without its negative part
    (``newton_blocks(parts=…)``): the same numbers as computed afresh, with fewer dynamics and kinematics calls."""
    from hoc_cli.goals.replan_point import evaluate_point
    from hoc_cli.goals.terms import GoalTerms

    arm, limits, goals, start = catch
    p = start.problem
    lam = [np.full(g.residual.size, 3.0) for g in p.points] + [np.zeros(0)]
    pt = evaluate_point(arm, "quintic", 4, 0.35, start.coeffs, p.boundary[0], p.boundary[1], goals, p.cost, start.G, lam,
                        limits, None, 0.0, False, {})
    problem = pt.problem
    fresh = problem.hessian_samples(pt.ev)
    calls = []
    mass = arm.mass_matrix
    monkeypatch.setattr(arm, "mass_matrix", lambda q: calls.append(q.shape) or mass(q))
    kept = problem.hessian_samples(pt.ev, pt.samples)
    assert not calls and all(np.array_equal(a, b) for a, b in zip(fresh, kept))
    terms = GoalTerms(problem.mesh, problem.points, lam[:-1], 10.0, pt.where)
    batches = []
    kind = type(problem.points[0].residual)
    batch = kind.batch
    monkeypatch.setattr(kind, "batch", lambda self, *a: batches.append(1) or batch(self, *a))
    parts: list = []
    for indefinite in (True, False):
        alone = terms.newton_blocks(pt.C, indefinite=indefinite, res=pt.res)
        shared = terms.newton_blocks(pt.C, indefinite=indefinite, res=pt.res, parts=parts)
        assert np.array_equal(alone, shared)
    assert len(batches) == 3  # twice alone, once for both shared


def test_a_free_t_goal_plan_reports_every_step_that_made_it(monkeypatch):
    """The cold catch at N = 8 (coarse stage, then the mesh): the plan's iterations, evaluations and Newton matrices
    (the summary's ``iterations``, ``evaluations``, ``hessians``) are the totals of every replan it ran, not the last
    one's (which re-estimates the multipliers and takes no step)."""
    import hoc_cli
    import hoc_cli.goals.free_time_sqp as fts

    runs = []
    run = fts._run

    def spy(record, *args, **options):
        r = run(record, *args, **options)
        runs.append(r.plan.optimizer)
        return r

    monkeypatch.setattr(fts, "_run", spy)
    plan = hoc_cli.solve(lbr7_catch_problem(N=8))
    o = plan.result.optimizer
    assert plan.converged and len(runs) >= 3
    assert (o.iterations, o.n_evals, o.n_precond) == (sum(r.iterations for r in runs), sum(r.n_evals for r in runs),
                                                      sum(r.n_precond for r in runs))
    assert o.iterations > runs[-1].iterations


def test_the_coarse_steps_in_x_and_t_stop_near_the_coarse_optimum_s_distance_to_the_mesh_s(monkeypatch):
    """The coarse steps in x and T stop at ``COARSE_FREE_ACCURACY`` (1e-4, about the coarse optimum's distance to the
    mesh's): the lbr7 catch at N = 8 takes fewer steps there than to ``COARSE_ACCURACY`` (7 and 8 measured) and as many
    on the mesh, to the same optimum (J to 1e-12, T to 1e-9)."""
    import hoc_cli.goals.free_time_sqp as fts

    out, calls, _ = _catch_per_value(monkeypatch, "COARSE_FREE_ACCURACY", (fts.COARSE_FREE_ACCURACY, fts.COARSE_ACCURACY))
    steps = [[s for *_, s in run] for run in calls]
    loose, full = out
    assert loose.converged and full.converged
    assert steps[0][0] == steps[1][0] and steps[0][1] < steps[1][1]  # the steps at the guess, then those in x and T
    assert sum(steps[0]) < sum(steps[1])
    assert loose.J == pytest.approx(full.J, rel=1e-12) and loose.T == pytest.approx(full.T, rel=1e-9)


def test_a_free_t_coarse_stage_takes_its_own_violation_floor(monkeypatch):
    """The coarse stage of a free T steps with ``FREE_COLD_FLOOR`` (its steps move the target), a fixed-T goal plan's
    with ``COLD_FLOOR``; the lbr7 catch at N = 8 takes no more steps with it than with ``COLD_FLOOR`` (18 and 19
    measured), to the same optimum (J to 1e-12, T to 1e-9)."""
    import hoc_cli.goals.free_time_sqp as fts

    free_floor = fts.FREE_COLD_FLOOR
    out, floors, (arm, limits, goals, problem) = _catch_per_value(monkeypatch, "FREE_COLD_FLOOR", (free_floor, fts.COLD_FLOOR))
    own, cold = out
    assert own.converged and cold.converged
    assert [f for n, f, _ in floors[0] if n == 4] == [free_floor] * 2 and free_floor > fts.COLD_FLOOR
    assert sum(s for *_, s in floors[0]) <= sum(s for *_, s in floors[1])
    assert own.J == pytest.approx(cold.J, rel=1e-12) and own.T == pytest.approx(cold.T, rel=1e-9)
    floors.append([])
    start = goal_solver(arm, "quintic", 8, problem.q0, problem.dq0, goals, limits=limits).initial(0.42)
    assert fts.plan_fixed_time(arm, start, goals, limits) is not None
    assert floors[2][0][1] == fts.COLD_FLOOR  # its steps from the initial trajectory
