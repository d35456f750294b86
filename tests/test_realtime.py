"""The real-time parts that need no closed loop: the ballistic fit, the exact shift, the limits' guard, one update."""
from __future__ import annotations

import numpy as np
import pytest
from _robots import lbr7_catch_problem

import hoc_cli
from hoc_cli.constraints.check import check_limits
from hoc_cli.constraints.penalty import LimitRows
from hoc_cli.problem import Layout
from hoc_cli.realtime import BallisticFit, Replanner, Target
from hoc_cli.realtime.limits_guard import guard, worst_row
from hoc_cli.realtime.shift import shift_plan

G = np.array([0.0, 0.0, -9.81])
P0 = np.array([0.6725, -0.0375, 0.1246])  # configs/catch_ball.yaml's target
V0 = np.array([-0.15, 0.25, 3.13])


def ballistic(t):
    t = np.asarray(t, float)
    return P0 + np.outer(t, V0) + 0.5 * np.outer(t**2, G)


def test_the_fit_of_exact_observations_is_the_ball_itself():
    t = np.arange(0.0, 0.2, 0.01)
    fit = BallisticFit(G, 1e-3)
    fit.add_many(t, ballistic(t))
    est = fit.estimate(0.35)
    p, v = ballistic([0.35])[0], V0 + 0.35 * G
    assert np.abs(est.position - p).max() < 1e-12 and np.abs(est.velocity - v).max() < 1e-11


def test_the_fit_error_shrinks_like_one_over_root_n_and_matches_its_covariance():
    """Monte Carlo over 400 seeds at 100 Hz and σ = 5 mm: the RMS error of the position at the last observation
    falls at least like 1/√n from n = 10 to n = 40, and agrees with the fit's own covariance to 10 %.
    """
    sigma = 0.005
    rms, predicted = {}, {}
    for n in (10, 40):
        t = np.arange(n) * 0.01
        truth = ballistic(t)
        errs, pred = [], None
        for seed in range(400):
            rng = np.random.default_rng(seed)
            fit = BallisticFit(G, sigma)
            fit.add_many(t, truth + rng.normal(0.0, sigma, truth.shape))
            est = fit.estimate(t[-1])
            errs.append(np.sum((est.position - truth[-1]) ** 2))
            pred = np.trace(est.covariance[:3, :3])
        rms[n], predicted[n] = np.sqrt(np.mean(errs)), np.sqrt(pred)
        assert abs(rms[n] / predicted[n] - 1.0) < 0.1
    assert rms[40] <= rms[10] / np.sqrt(4.0) * 1.05


def test_a_prior_alone_is_the_estimate_and_it_is_not_ready_without_one():
    fit = BallisticFit(G, 0.005, prior=(np.concatenate([P0, V0]), (0.05, 0.25)))
    est = fit.estimate(0.0)
    assert np.allclose(est.position, P0) and np.allclose(est.velocity, V0)
    assert not BallisticFit(G, 0.005).ready
    with pytest.raises(ValueError):
        BallisticFit(G, 0.005).estimate()


@pytest.fixture(scope="module")
def catch():
    problem = lbr7_catch_problem()
    return problem, hoc_cli.solve(problem)


def test_the_shifted_plan_is_the_plan_in_force_and_keeps_its_bernstein_rows(catch):
    problem, plan = catch
    mesh, C = plan.mesh, plan.coeffs
    t = 0.31 * mesh.T  # inside the third element, away from its nodes
    s = shift_plan(mesh, C, 0.0, t)
    assert s.exact and s.mesh.N == mesh.N and abs(s.mesh.T - (mesh.T - t)) < 1e-15
    tau = np.linspace(0.0, s.mesh.T, 97)
    for d in range(3):
        assert np.abs(s.mesh.evaluate(s.coeffs, tau, d) - mesh.evaluate(C, t + tau, d)).max() < 1e-9 * 10**d
    rows = LimitRows.build(s.mesh, Layout.build(s.mesh, 7, True, True).free, 7)
    rows0 = LimitRows.build(mesh, Layout.build(mesh, 7, True, True).free, 7)
    assert worst_row(problem.system, problem.limits, rows, s.coeffs) <= worst_row(problem.system, problem.limits, rows0, C) + 1e-12


def test_the_guard_projects_a_plan_beyond_its_velocity_limits_back_inside(catch):
    problem, plan = catch
    mesh = plan.mesh
    C = np.array(plan.coeffs)
    C[1:, 1] *= 1.6  # the nodes' velocities (and the end's) 60 % faster: beyond the lbr7's velocity limits
    free = Layout.build(mesh, 7, True, True).free
    rows = LimitRows.build(mesh, free, 7)
    assert not check_limits(problem.system, problem.limits, mesh, C).feasible
    safe = guard(problem.system, problem.limits, rows, C, free)
    assert safe is not None and safe is not C
    assert worst_row(problem.system, problem.limits, rows, safe) <= 1e-9
    assert check_limits(problem.system, problem.limits, mesh, safe).feasible
    assert np.array_equal(safe.ravel()[~free], C.ravel()[~free])  # the start state is untouched
    # rows to keep (as the goal rows' Jacobian): the projection moves along their null space only
    rng = np.random.default_rng(3)
    E = rng.normal(size=(3, int(free.sum())))
    kept = guard(problem.system, problem.limits, rows, C, free, keep=E)
    assert kept is not None and worst_row(problem.system, problem.limits, rows, kept) <= 1e-9
    d = kept.ravel()[free] - C.ravel()[free]
    assert np.abs(E @ d).max() <= 1e-9 * np.abs(E).sum(axis=1).max() * np.abs(d).max()
    # a second projection starting from the rows a first one needed (and left in ``near``): within the limits too
    near: list = []
    first = guard(problem.system, problem.limits, rows, C, free, keep=E, near=near)
    assert np.array_equal(first, kept) and len(near) == 2 and sum(int(m.sum()) for m in near[0] + near[1]) > 0
    again = guard(problem.system, problem.limits, rows, C, free, near=near)
    assert again is not None and worst_row(problem.system, problem.limits, rows, again) <= 1e-9
    assert check_limits(problem.system, problem.limits, mesh, again).feasible
    assert np.array_equal(again.ravel()[~free], C.ravel()[~free])


def test_the_rows_of_the_steps_are_those_of_the_limits_terms_and_the_update_check_is_the_exact_one(catch):
    """``row_values`` gives ``all_rows``' kinematic numbers (uniform and shifted, non-uniform meshes); the update's
    check (``within_limits``: Bernstein rows, torques) agrees with ``check_limits`` on a plan within its limits, one
    beyond its velocity limits, one whose start velocity (rows fixed by the start, not rows of the guard) is beyond
    them, and one beyond its torque limits.
    """
    import dataclasses

    from hoc_cli.goals.active_limits import all_rows
    from hoc_cli.goals.replan_point import row_values
    from hoc_cli.realtime.limits_guard import effort_only, within_limits

    problem, plan = catch
    system, limits = problem.system, problem.limits
    s = shift_plan(plan.mesh, plan.coeffs, 0.0, 0.31 * plan.mesh.T)
    for mesh, C in ((plan.mesh, plan.coeffs), (s.mesh, s.coeffs)):
        rows = LimitRows.build(mesh, Layout.build(mesh, 7, True, True).free, 7)
        ref, got = all_rows(system, limits, rows, C), row_values(limits, rows, C)
        for a, b in zip(ref.g_lo[:4] + ref.g_hi[:4], got.g_lo + got.g_hi):
            np.testing.assert_array_equal(a, b)
    mesh = plan.mesh
    rows = LimitRows.build(mesh, Layout.build(mesh, 7, True, True).free, 7)
    fast = np.array(plan.coeffs)
    fast[1:, 1] *= 1.6
    start = np.array(plan.coeffs)
    start[0, 1] = 1.01 * limits.velocity  # the start state beyond the velocity limit: rows of data alone
    weak = dataclasses.replace(limits, effort=0.2 * limits.effort)
    for lim, C, ok in ((limits, plan.coeffs, True), (limits, fast, False), (limits, start, False), (weak, plan.coeffs, False)):
        assert check_limits(system, lim, mesh, C).feasible is ok
        assert within_limits(system, lim, rows, C, effort_only(lim)) is ok
        if C is not fast:  # the rows not fixed by the start hold (as after ``guard``): those fixed by it decide
            assert within_limits(system, lim, rows, C, effort_only(lim), rows_hold=True) is ok


def test_the_problem_and_rows_at_another_catch_time_are_those_built_afresh(catch):
    """A step evaluates its problem at T, T + δ and the trial T on the same node fractions: ``problem_on`` and
    ``rows_on`` rescale the first one's quadrature and limit rows instead of building them, to rounding.
    """
    from hoc_cli.goals.mesh import mesh_fractions, scaled_mesh
    from hoc_cli.goals.plan import GoalProblem
    from hoc_cli.goals.replan_point import limit_rows, problem_on, rows_on

    problem, plan = catch
    s = shift_plan(plan.mesh, plan.coeffs, 0.0, 0.31 * plan.mesh.T)
    q0, dq0 = s.coeffs[0, 0], s.coeffs[0, 1]
    built = []
    for T in (s.mesh.T, 1.07 * s.mesh.T):
        mesh = scaled_mesh(s.mesh.order, T, s.mesh.N, mesh_fractions(s.mesh))
        p = GoalProblem(problem.system, mesh, q0, dq0, problem.goals(), G=8)
        p.op_h = p.op
        built.append((mesh, p, LimitRows.build(mesh, p.layout.free, 7)))
    (_, p1, r1), (mesh2, p2, r2) = built
    p3, r3 = problem_on(p1, mesh2), rows_on(r1, mesh2)
    assert p3.mesh is mesh2 and p3.op_h is p3.op and r3.mesh is mesh2
    C = s.coeffs
    for a, b in zip(p2.op.apply(C), p3.op.apply(C)):
        assert np.abs(a - b).max() <= 1e-13 * np.abs(a).max()
    x = p2.layout.pack(C)
    assert abs(p3.value(x) - p2.value(x)) <= 1e-12 * abs(p2.value(x))
    for k in range(4):
        a, b = (r.apply(k, mesh2.local_coefficients(C)) for r in (r3, r2))
        assert np.abs(a - b).max() <= 1e-12 * np.abs(b).max()
    assert problem_on(p1, plan.mesh) is None and rows_on(r1, plan.mesh) is None  # other fractions: built afresh
    kept = limit_rows(mesh2, p2.layout.free, 7)  # another cycle's mesh: the h = 1 rows kept, its own scales
    for name in ("rows", "part", "data", "scale"):
        assert all(np.array_equal(a, b) for a, b in zip(getattr(kept, name), getattr(r2, name)))
    # the rows of the same s-domain trajectory at T' = 1.07 T from those at T (``row_values``' ratio)
    from hoc_cli.free_time import rescale
    from hoc_cli.goals.replan_point import row_values

    T1, T2 = r1.mesh.T, mesh2.T
    C1 = p1.coefficients(p1.layout.pack(C))
    ref, got = row_values(problem.limits, r2, rescale(C1, T1, T2)), row_values(problem.limits, r1, C1, T1 / T2)
    for a, b in zip(ref.g_lo + ref.g_hi, got.g_lo + got.g_hi):
        fin = np.isfinite(a)
        assert np.array_equal(fin, np.isfinite(b))
        assert np.abs(a[fin] - b[fin]).max(initial=0.0) <= 1e-12 * np.abs(a[fin]).max(initial=0.0)
    assert max(float(np.max(np.abs(a[np.isfinite(a)] - b[np.isfinite(a)]), initial=0.0)) for a, b in zip(
        ref.g_hi, row_values(problem.limits, r1, C1).g_hi)) > 1e-3  # (the rows at T differ)


def test_the_updates_torque_check_is_check_limits_at_its_tolerance(catch):
    """``torques_hold`` (the update's torque check) decides as ``check_limits`` with the effort limits alone: limits at
    the plan's own largest torques, moved by 0.5e-9 (within the check's 1e-9 tolerance: held) or 3e-9 (broken) on one
    joint, on the cold plan and a shifted one.
    """
    import dataclasses

    from hoc_cli.constraints.points import PointSet
    from hoc_cli.realtime.limits_guard import effort_only, torques_hold

    problem, plan = catch
    system, limits = problem.system, problem.limits
    s = shift_plan(plan.mesh, plan.coeffs, 0.0, 0.31 * plan.mesh.T)
    for mesh, C in ((plan.mesh, plan.coeffs), (s.mesh, s.coeffs)):
        N = mesh.N
        pts = PointSet.build(mesh, np.repeat(np.arange(N), 33), np.tile(np.linspace(0.0, 1.0, 33), N), np.ones(N * 33))
        X = pts.apply(C)
        top = np.abs(system.inverse_dynamics(X[0], X[1], X[2])).max(axis=0)
        for j, factor, ok in ((0, 1.0 - 0.5e-9, True), (3, 1.0 - 3e-9, False), (6, 1.0 - 3e-9, False), (6, 1.2, True)):
            effort = np.array(top)
            effort[j] *= factor
            effort[np.arange(7) != j] *= 1.01
            lim = effort_only(dataclasses.replace(limits, effort=effort))
            assert check_limits(system, lim, mesh, C).feasible is ok
            assert torques_hold(system, lim, mesh, C) is ok


def test_a_damped_step_evaluates_only_the_point_it_keeps_when_the_goal_rows_alone_say_no():
    """``damped_trial`` with ``violation_at`` (the goal rows' violation without the dynamics) returns what it returns
    without it, and evaluates the point only where the rows pass (or at the last halving).
    """
    from types import SimpleNamespace

    from hoc_cli.goals.replan_point import damped_trial

    def rows(alpha):  # the violation of the step scaled by alpha: too large above alpha = 0.25
        return 4e-3 * alpha

    for limit, kept in ((1e-3, 0.25), (1e-9, 0.5**5)):
        calls = []

        def trial_at(alpha):
            calls.append(alpha)
            return 1.0 + alpha, SimpleNamespace(c=np.array([rows(alpha), 0.0]))

        full = damped_trial(trial_at, 1, limit, floor=limit)
        assert full[2] == kept and len(calls) == 1 + round(np.log2(1.0 / kept))
        calls.clear()
        quick = damped_trial(trial_at, 1, limit, floor=limit, violation_at=rows)
        assert calls == [kept] and quick[1:] == full[1:] and quick[0].c[0] == full[0].c[0]


def test_an_update_takes_one_step_towards_a_moved_target_within_the_limits(catch):
    problem, plan = catch
    rp = Replanner(problem, plan, max_steps=1)
    t = 0.05
    x = (rp.current.state(t)[0], rp.current.state(t, 1)[0])
    p1, v1 = P0 + [0.01, -0.005, 0.0], V0 + [0.02, 0.0, -0.03]
    viol0 = None
    for k in range(4):  # the same moved target: the violation of the goal rows falls step by step
        tk = t + 0.01 * k
        cur = rp.current
        x = (cur.state(tk)[0], cur.state(tk, 1)[0])
        up = rp.update(tk, x, Target(p1 + v1 * tk + 0.5 * G * tk**2, v1 + G * tk, G), budget_s=10.0)
        assert up.steps == 1 and up.t0 == tk
        assert np.allclose(up.coeffs[0, 0], x[0]) and np.allclose(up.coeffs[0, 1], x[1])
        assert check_limits(problem.system, problem.limits, up.mesh, up.coeffs).feasible
        if k == 0:
            viol0 = up.violation
    assert up.violation < 0.1 * viol0


def test_a_steps_first_programme_starts_from_the_rows_its_free_step_breaks_and_is_the_full_programmes_step(catch,
                                                                                                         monkeypatch):
    """The real-time step's first programme (``qp_steps(..., quick=True)``) is ``solve_qp_within`` from no row: over the
    rows the step without inequality rows breaks, then with any row its step breaks. Its step is the minimiser over
    every candidate row (``solve_qp`` of the same programme, SciPy's NNLS from no active row: the reference) and it meets
    every candidate row.
    """
    from hoc_cli.goals import qp_step, replan_qp

    problem, plan = catch
    seen = []
    within = replan_qp.solve_qp_within

    def spy(U, g, E, e, A, b, rows, programme=None, keys=None):
        step = within(U, g, E, e, A, b, rows, programme=programme, keys=keys)
        if not np.any(rows):  # the first programme of a step
            ref = qp_step.solve_qp(U, g, E, e, A, b, programme=qp_step.Programme(U, g, E, keyed=True), keys=keys)
            seen.append((A.shape[0], step, ref, float(np.max(A @ step.d - b))))
        return step

    monkeypatch.setattr(replan_qp, "solve_qp_within", spy)
    rp = Replanner(problem, plan, max_steps=1)
    for t, dp in ((0.05, [0.01, -0.005, 0.0]), (0.07, [0.012, -0.004, 0.002])):
        x = (rp.current.state(t)[0], rp.current.state(t, 1)[0])
        rp.update(t, x, Target(P0 + dp + V0 * t + 0.5 * G * t**2, V0 + G * t, G), budget_s=10.0)
    assert len(seen) >= 2
    for k, step, ref, worst in seen:
        scale = max(float(np.max(np.abs(ref.d))), 1e-12)
        assert np.max(np.abs(step.d - ref.d)) <= 1e-9 * scale
        assert abs(step.decrease - ref.decrease) <= 1e-9 * max(abs(ref.decrease), 1.0)
        assert worst <= 1e-9


def test_the_point_after_the_last_step_is_evaluated_without_derivatives_and_the_plan_is_the_same(catch, monkeypatch):
    """The point after an update's last allowed step (``max_steps``): no step starts there, so ℒ's derivatives are
    not evaluated (``evaluate_point(..., derivatives=False)``), nor its cost (``value=False``: no dynamics); the plan,
    its J, goal rows and stationarity (evaluated when read) are those of the same update with them.
    """
    import hoc_cli.goals.replan_qp as replan_qp
    from hoc_cli.goals.plan import GoalProblem

    problem, plan = catch
    evaluate, calls = replan_qp.evaluate_point, []
    values, costs = GoalProblem.evaluate, []
    monkeypatch.setattr(GoalProblem, "evaluate", lambda self, x, grad=True: costs.append(grad) or values(self, x, grad))
    rows_alone, violations = replan_qp.goal_violation, []
    monkeypatch.setattr(replan_qp, "goal_violation", lambda *a, **k: violations.append(1) or rows_alone(*a, **k))

    def spy(*a, derivatives=True, **k):
        calls.append(derivatives)
        return evaluate(*a, derivatives=derivatives, **k)

    t = 0.03
    v = V0 + [0.06, 0.02, 0.03]  # an estimate off by centimetres: the step's full length is cut, its correction taken
    target = Target(P0 + [0.037, 0.024, -0.001] + v * t + 0.5 * G * t**2, v + G * t, G)
    rp = Replanner(problem, plan, max_steps=1)
    cur = rp.current
    x, saved = (cur.state(t)[0], cur.state(t, 1)[0]), rp.state()
    monkeypatch.setattr(replan_qp, "evaluate_point", spy)
    up = rp.update(t, x, target, budget_s=10.0)
    assert up.steps == 1 and calls[0] is True and calls[1:] and not any(calls[1:])  # the trial (and its correction's)
    assert False not in costs  # nor its cost: evaluated when read
    assert len(calls) == 3 and not violations  # the corrected point evaluated once, its goal rows read from it
    rp.restore(saved)
    monkeypatch.setattr(replan_qp, "evaluate_point", lambda *a, derivatives=True, **k: evaluate(*a, **k))
    ref = rp.update(t, x, target, budget_s=10.0)
    assert np.array_equal(up.coeffs, ref.coeffs) and up.T == ref.T and up.guarded == ref.guarded
    assert up.J == ref.J and up.violation == ref.violation and up.stationarity == ref.stationarity > 0.0


def test_a_projected_plans_cost_is_evaluated_when_read_and_is_the_cost_of_its_coefficients(catch, monkeypatch):
    """An update whose guard projected its plan does not evaluate the projected plan's cost (the controller does not
    need it): ``J`` evaluates it when read, once, and it is the cost of the returned coefficients (a problem built
    afresh on the plan's mesh).
    """
    from hoc_cli.goals.plan import GoalProblem
    from hoc_cli.realtime.replanner import Deferred

    problem, plan = catch
    rp = Replanner(problem, plan, max_steps=1)
    value, calls = GoalProblem.value, []
    monkeypatch.setattr(GoalProblem, "value", lambda self, x: calls.append(1) or value(self, x))
    p1, v1 = P0 + [0.01, -0.005, 0.0], V0 + [0.02, 0.0, -0.03]
    guarded = []
    for k in range(6):
        tk = 0.05 + 0.01 * k
        cur, n = rp.current, len(calls)
        up = rp.update(tk, (cur.state(tk)[0], cur.state(tk, 1)[0]), Target(p1 + v1 * tk + 0.5 * G * tk**2, v1 + G * tk, G),
                       budget_s=10.0)
        assert len(calls) == n  # no cost evaluated in the update
        if up.guarded:
            guarded.append(up)
    assert guarded  # (the first 4 of the 6)
    for up in guarded:
        assert isinstance(up.cost, Deferred)
        n = len(calls)
        J = up.J
        assert up.J == J and len(calls) == n + 1  # evaluated once
        fresh = GoalProblem(problem.system, up.mesh, up.coeffs[0, 0], up.coeffs[0, 1], problem.goals(), G=rp.G)
        assert abs(value(fresh, fresh.layout.pack(up.coeffs)) - J) <= 1e-12 * abs(J)
        assert abs(up.J_steps - J) <= 1e-5 * abs(J) and up.J_steps != J  # the steps' point, before the projection (3e-11 to 8e-7)


def test_a_budget_below_one_step_still_takes_exactly_one_and_a_long_one_converges(catch):
    """Without measured step times (no warm-up) nothing predicts a step's time: the first update takes exactly one
    step whatever its budget. With the warm-up's times the same budget skips the update.
    """
    problem, plan = catch
    warm = Replanner(problem, plan, max_steps=10)
    assert len(warm.first_times) == 1 and set(warm.to_step_end) >= {"newton", "programme", "trial"}
    cur = warm.current
    up = warm.update(0.02, (cur.state(0.02)[0], cur.state(0.02, 1)[0]),
                     Target(P0 + V0 * 0.02 + 0.5 * G * 0.0004, V0 + G * 0.02, G), budget_s=1e-6)
    assert up.steps == 0 and up.status == "skipped" and up.coeffs is cur.coeffs
    rp = Replanner(problem, plan, max_steps=10, warm_up=False)
    cur = rp.current
    up = rp.update(0.02, (cur.state(0.02)[0], cur.state(0.02, 1)[0]),
                   Target(P0 + V0 * 0.02 + 0.5 * G * 0.0004, V0 + G * 0.02, G), budget_s=1e-6)
    assert up.steps == 1 and up.status == "budget"
    cur = rp.current  # a budget far above a step: the steps go on to convergence
    up = rp.update(0.03, (cur.state(0.03)[0], cur.state(0.03, 1)[0]),
                   Target(P0 + V0 * 0.03 + 0.5 * G * 0.0009, V0 + G * 0.03, G), budget_s=10.0)
    assert up.steps > 1 and up.status == "converged" and up.violation < 1e-9


def test_a_step_asks_at_each_checkpoint_in_order_and_stops_where_it_is_told(catch, monkeypatch):
    """``qp_steps``' checkpoints: a free-T step passes newton, slope, then one programme per round, then trial; a
    ``late`` that says True at a checkpoint raises ``OutOfTime`` there, before the work that follows it.
    """
    import hoc_cli.goals.replan_qp as replan_qp
    import hoc_cli.realtime.replanner as replanner

    problem, plan = catch
    rp = Replanner(problem, plan, max_steps=1, warm_up=False)
    seen: list[str] = []
    real = replan_qp.qp_steps
    monkeypatch.setattr(replanner, "qp_steps", lambda *args, **kwargs: real(
        *args, **{**kwargs, "late": lambda name: seen.append(name) or False}))
    cur = rp.current
    up = rp.update(0.05, (cur.state(0.05)[0], cur.state(0.05, 1)[0]),
                   Target(P0 + [0.01, 0.0, 0.0] + V0 * 0.05 + 0.5 * G * 0.0025, V0 + G * 0.05, G), 10.0)
    monkeypatch.undo()
    assert up.steps == 1 and seen[:2] == ["newton", "slope"] and seen[-1] == "trial"
    assert set(seen[2:-1]) == {"programme"} and len(seen) >= 4
    for name in replan_qp.CHECKPOINTS:
        asked: list[str] = []

        def late(at, name=name, asked=asked):
            asked.append(at)
            return at == name

        cur = rp.current
        x = (cur.state(0.07)[0], cur.state(0.07, 1)[0])
        with pytest.raises(replan_qp.OutOfTime):
            replan_qp.qp_steps(problem.system, _start(cur, x, rp), rp.goals, [np.zeros(6), np.zeros(0)],
                               replan_qp.ActiveRows.empty(), free=rp.time_range(0.07), limits=problem.limits,
                               tol=1e-12, max_steps=1, rho_aug=1.0, quick=True, late=late)
        assert asked[-1] == name and asked.count(name) == 1


def test_a_later_step_stopped_at_a_checkpoint_keeps_the_steps_completed_before_it(catch):
    """``late`` True in the second step: the steps end at the point the first one reached (no ``OutOfTime``), the
    same point as one step alone."""
    import hoc_cli.goals.replan_qp as replan_qp

    problem, plan = catch
    rp = Replanner(problem, plan, max_steps=1, warm_up=False)
    cur = rp.current
    x = (cur.state(0.07)[0], cur.state(0.07, 1)[0])
    calls = []

    def late(at):
        calls.append(at)
        return calls.count("newton") == 2  # the second step's first checkpoint

    def run(max_steps, late):
        return replan_qp.qp_steps(problem.system, _start(cur, x, rp), rp.goals, [np.zeros(6), np.zeros(0)],
                                  replan_qp.ActiveRows.empty(), free=rp.time_range(0.07), limits=problem.limits,
                                  tol=1e-12, max_steps=max_steps, rho_aug=1.0, quick=True, late=late)

    cut, one = run(5, late), run(1, None)
    assert calls.count("newton") == 2 and cut.steps == one.steps == 1 and cut.factor is None
    assert cut.T == one.T and np.array_equal(cut.point.C, one.point.C)


def _start(cur, x, rp):
    """The ``qp_steps`` start of the plan in force shifted to 0.07 s from the state x (as ``Replanner.update``'s)."""
    from hoc_cli.realtime.replanner import _Boundary, _Start

    shifted = shift_plan(cur.mesh, cur.coeffs, cur.t0, 0.07, cur.t_end - 0.07)
    C = shifted.coeffs
    C[0, 0], C[0, 1] = x
    return _Start(mesh=shifted.mesh, problem=_Boundary(x, rp.problem.cost), G=rp.G, coeffs=C)


def test_an_update_whose_measured_rest_does_not_fit_is_abandoned_and_keeps_the_plan_in_force(catch):
    """The hard budget: with a measured time from the "programme" checkpoint to the step's end longer than the
    budget, the update stops there ("abandoned"), returns the plan in force unchanged within the budget, and that
    measurement is forgotten, so the next update with the same budget takes its step.
    """
    from collections import deque

    problem, plan = catch
    rp = Replanner(problem, plan, max_steps=1)
    before = rp.current
    rp.to_step_end["programme"] = deque([5.0])  # 5 s from the first programme to the step's end
    tk = 0.05
    target = Target(P0 + [0.01, 0.0, 0.0] + V0 * tk + 0.5 * G * tk**2, V0 + G * tk, G)
    up = rp.update(tk, (before.state(tk)[0], before.state(tk, 1)[0]), target, budget_s=2.0)
    assert up.status == "abandoned" and up.steps == 0 and up.worked and up.wall_time_s < 2.0
    assert up.coeffs is before.coeffs and up.t0 == before.t0 and rp.active is not None
    assert not rp.to_step_end["programme"]
    again = rp.update(tk, (before.state(tk)[0], before.state(tk, 1)[0]), target, budget_s=2.0)
    assert again.status in ("budget", "converged") and again.steps == 1 and again.worked
    assert max(rp.to_step_end["programme"]) < 2.0  # measured by the step just taken


def test_one_step_at_a_fixed_catch_time_keeps_every_kinematic_row_without_the_guard(catch, monkeypatch):
    """The guarantee of one step alone (docs/realtime.md): at a fixed T the Bernstein rows are linear in the
    coefficients, so the step from a plan within them, which imposes those within 5 % of their bound, stays within
    all of them (rounding: 1e-9). The guard is replaced by a probe that records the step's rows and returns the
    plan as it is.
    """
    import hoc_cli.realtime.replanner as replanner

    problem, plan = catch
    seen = []

    def probe(system, limits, rows, C, free, keep=None, near=None):
        seen.append(worst_row(system, limits, rows, C))
        return C

    monkeypatch.setattr(replanner, "guard", probe)
    rp = Replanner(problem, plan, max_steps=1, warm_up=False)
    p1, v1 = P0 + [0.01, -0.005, 0.0], V0 + [0.02, 0.0, -0.03]
    for k in range(3):
        tk = 0.05 + 0.02 * k
        cur = rp.current
        up = rp.update(tk, (cur.state(tk)[0], cur.state(tk, 1)[0]),
                       Target(p1 + v1 * tk + 0.5 * G * tk**2, v1 + G * tk, G), 10.0, free_time=False)
        assert up.steps == 1 and up.status != "held" and abs(up.t_end - cur.t_end) < 1e-12  # the catch time kept
    assert len(seen) == 3 and max(seen) <= 1e-9


def test_the_python_example_of_docs_realtime_runs_as_printed(request, capsys):
    import re

    text = (request.config.rootpath / "docs" / "realtime.md").read_text()
    code = re.search(r"```python\n(.*?)```", text, re.S).group(1)
    exec(compile(code, "docs/realtime.md", "exec"), {})
    steps, status = capsys.readouterr().out.split()[:2]
    # the budget is wall time: on a loaded machine the step may not fit (the example's comment says so)
    assert status in ("budget", "converged", "skipped", "abandoned")
    assert (int(steps) >= 1) == (status in ("budget", "converged"))


def test_an_update_runs_on_one_blas_thread_when_numpy_loaded_its_blas_first():
    """numpy imported first with two OpenBLAS threads (the docs' example's order): the replanner's steps and the
    loop's updates run on one, and the counts are restored after (``optimize.blas.one_thread``)."""
    import json
    import os
    import subprocess
    import sys

    code = """
import numpy, scipy.linalg
import json
from _robots import lbr7_catch_problem
import hoc_cli
import hoc_cli.realtime.replanner as replanner
from hoc_cli.optimize.blas import thread_counts
from hoc_cli.realtime import Replanner, Target
before = thread_counts()
problem = lbr7_catch_problem()
plan = hoc_cli.solve(problem)
seen = []
steps = replanner.qp_steps
replanner.qp_steps = lambda *a, **k: seen.append(thread_counts()) or steps(*a, **k)
rp = Replanner(problem, plan, max_steps=1)
cur = rp.current
p, v = rp.goals.final.target(0.05)
up = rp.update(0.05, (cur.state(0.05)[0], cur.state(0.05, 1)[0]), Target(p + 0.01, v, rp.goals.final.acceleration), 10.0)
print(json.dumps([before, sorted(set(map(tuple, seen))), thread_counts(), up.steps]))
"""
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    tests = os.path.dirname(__file__)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=tests,
                         env=env | {"OPENBLAS_NUM_THREADS": "2", "PYTHONPATH": tests})
    assert out.returncode == 0, out.stderr
    before, seen, after, steps = json.loads(out.stdout)
    assert before and all(n == 2 for n in before) and steps == 1
    assert seen == [[1] * len(before)] and after == before


def test_a_wrong_scipy_nnls_answer_is_repaired_from_its_passive_set(monkeypatch):
    """``_cold_nnls(M, repair=True)`` (the real-time steps): when SciPy's answer fails the KKT test, hoc's NNLS starts
    from SciPy's passive set and ends at the minimiser (the residual of the answer from no active row), in fewer
    iterations than from none. SciPy is replaced by an answer with one passive column dropped.
    """
    import scipy.optimize

    from hoc_cli.goals import qp_step
    from hoc_cli.optimize import nnls as hoc_nnls

    rng = np.random.default_rng(5)
    M = np.vstack([rng.normal(size=(30, 60)), rng.uniform(-1.0, 0.2, size=(1, 60))])
    f = qp_step._unit(M)
    ref = hoc_nnls.nnls(M, f)
    assert ref.passive.size >= 3
    wrong = np.array(ref.w)
    wrong[ref.passive[0]] = 0.0
    monkeypatch.setattr(scipy.optimize, "nnls", lambda A, b, maxiter=None: (wrong, 0.0))
    starts, how = [], []
    warm = qp_step.warm_nnls
    monkeypatch.setattr(qp_step, "warm_nnls", lambda *a, **k: starts.append(k.get("passive")) or
                        how.append(k.get("retriangulate", False)) or warm(*a, **k))
    for repair in (False, True):
        w = qp_step._cold_nnls(M, repair=repair)
        assert np.abs(M @ w - M @ ref.w).max() <= 1e-12
    assert starts[0] is None and sorted(starts[1]) == sorted(ref.passive[1:])
    assert how == [False, True]  # the real-time repair refactors dropped columns by one QR, the offline one as before


def test_the_dense_factor_is_the_banded_factor_on_the_free_coefficients():
    """``dense_factor``: U[j − d, j] = ab[u − d, j] of the banded factor, its free rows and columns, entry for entry."""
    from types import SimpleNamespace

    from hoc_cli.goals.replan_point import dense_factor

    rng = np.random.default_rng(2)
    n, u = 40, 7
    free = rng.random(n) > 0.3
    W = SimpleNamespace(factor=rng.normal(size=(u + 1, n)), free=free)
    full = np.zeros((n, n))
    for j in range(n):
        for d in range(min(u, j) + 1):
            full[j - d, j] = W.factor[u - d, j]
    np.testing.assert_array_equal(dense_factor(W), full[np.ix_(free, free)])
