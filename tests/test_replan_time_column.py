"""The exact T column of the free-T SQP steps (``replan_point.time_column``) against central differences in T.

Along the rescaled family (fixed s-domain free coefficients, ``free_time.rescale``; the fixed coefficients at their
t-domain values) the steps need b = ∂∇ℒ/∂T, h = ∂²ℒ/∂T² = ∂F/∂T, the goal rows' c_T and the working set's and candidate
limit rows' T columns. The reference: ℒ's gradient (scaled back to the x of T), F and the rows at T ± d and T ± d/2,
d = 1e-3·T, central differences combined by Richardson's extrapolation (truncation O(d⁴): ~1e-11 relative here).
What is measured: ‖exact − reference‖∞ / ‖reference‖∞ per quantity (h: |exact − reference| / |reference|). The
start velocity is not zero (the fixed q̇(0) coefficients then move relative to the family: their term is checked),
the multipliers are not the optimum's, and the working set holds rows of both kinematic kinds near their bounds.
"""
from __future__ import annotations

import numpy as np
import pytest

import hoc_cli
import hoc_cli.goals.replan as replan_module
from hoc_cli import Free, JointLimits, OptimalControlProblem, RobotSystem, link_goal, load_robot
from hoc_cli.free_time import fixed_coefficient_motion, rescale, row_time_derivatives
from hoc_cli.goals.active_limits import ActiveRows
from hoc_cli.goals.replan_point import evaluate_point, row_values, time_column
from tests._robots import ROBOTS, lbr7_catch_problem


def _two_link_goal() -> OptimalControlProblem:
    """The two-link arm's tool to a target moving with constant acceleration, matching its velocity, free T."""
    two = load_robot(str(ROBOTS / "two_link.urdf"))
    arm = RobotSystem(two)
    goal = link_goal(arm, "tool", position=[1.0, 0.0, 1.2], velocity=[0.1, 0.0, 0.2], acceleration=[0.0, 0.0, -1.0],
                     match_velocity=True)
    return OptimalControlProblem(arm, q0=[0.0, 0.0], dq0=np.zeros(2), link_goal=goal, time=Free(0.8, 3.0, guess=1.5),
                                 N=6, limits=JointLimits.from_model(two))


_CASES = {"lbr7 catch": lambda: lbr7_catch_problem(8), "two-link moving target": _two_link_goal}


@pytest.fixture(scope="module", params=[(name, fr) for name in _CASES for fr in (False, True)],
                ids=lambda p: p[0] + (", non-uniform mesh" if p[1] else ""))
def case(request):
    """(point at T, its evaluation at another T, the exact column, the working set, everything the reference needs)."""
    name, non_uniform = request.param
    ocp = _CASES[name]()
    r = hoc_cli.solve(ocp).result
    rng = np.random.default_rng(3)
    mesh, limits, goals = r.mesh, ocp.limits, ocp.goals()
    T = mesh.T
    fractions = np.linspace(0.0, 1.0, mesh.N + 1) ** 1.3 if non_uniform else None
    C = np.array(r.coeffs)
    n = C.shape[2]
    dq0 = 0.3 * rng.standard_normal(n)
    C[0, 1] = dq0
    C[1:-1] *= 1.0 + 0.01 * rng.standard_normal(C[1:-1].shape)
    q0 = r.problem.boundary[0]
    lam_goal = [np.asarray(v) + 0.1 * rng.standard_normal(np.shape(v)) for v in r.terms.lam]
    cache: dict = {}

    def at(Tp, active, lam):
        return evaluate_point(ocp.system, mesh.order, mesh.N, Tp, rescale(C, T, Tp), q0, dq0, goals, r.problem.cost, r.G,
                              lam, limits, None, 0.0, True, cache, active, fractions=fractions)

    first = at(T, ActiveRows.empty(), lam_goal + [np.zeros(0)])
    g = row_values(limits, first.rows, first.C)
    finite = [np.concatenate([x[np.isfinite(x)] for x in g.g_lo + g.g_hi])]
    cut = np.quantile(finite[0], 0.8)  # the fifth of the rows nearest their bounds
    active = ActiveRows.where(tuple(x >= cut for x in g.g_lo), tuple(x >= cut for x in g.g_hi))
    mu = rng.uniform(0.5, 2.0, active.size) * 0.01 * max(abs(first.J), 1.0)
    lam = lam_goal + [mu]
    pt = at(T, active, lam)
    Hs = pt.problem.hessian_samples(pt.ev)[0]
    return dict(pt=pt, at=at, T=T, C=C, active=active, lam=lam, col=time_column(pt, lam, active, Hs), limits=limits,
                r=sum(v.size for v in lam_goal))


def _reference(f, T: float):
    """Richardson's extrapolation of central differences of f (a tuple of arrays) at T, steps 1e-3·T and half."""
    def central(d):
        return [(a - b) / (2.0 * d) for a, b in zip(f(T + d), f(T - d))]

    d = 1e-3 * T
    return [(4.0 * y - x) / 3.0 for x, y in zip(central(d), central(0.5 * d))]


def _rel(a, b) -> float:
    return float(np.max(np.abs(np.asarray(a) - b)) / np.max(np.abs(b)))


def test_the_working_set_has_rows_of_both_kinematic_kinds(case):
    assert case["active"].size > 0
    assert np.any(case["active"].kind == 0) and np.any(case["active"].kind == 1)


def test_b_h_and_the_goal_and_working_set_rows_match_central_differences(case):
    pt, T, C, r = case["pt"], case["T"], case["C"], case["r"]
    layout = pt.problem.layout

    def family(Tp):
        p = case["at"](Tp, case["active"], case["lam"])
        return layout.pack(rescale(np.ones_like(C), T, Tp)) * p.g, np.array([p.F]), p.c[:r], p.c[r:]

    b, h, c_T, held_T = _reference(family, T)
    col = case["col"]
    assert _rel(col.b, b) <= 1e-6  # measured 1e-9 to 3e-9: the sample Hessians' own differences (relative step 1e-8)
    assert abs(col.h - h[0]) <= 1e-6 * abs(h[0])  # measured 2e-10 to 1e-9
    assert _rel(col.c_T, c_T) <= 1e-9  # measured ~1e-13
    assert _rel(col.held_T, held_T) <= 1e-9  # measured ~1e-11


def test_every_candidate_row_s_t_column_matches_central_differences(case):
    pt, T, limits = case["pt"], case["T"], case["limits"]
    layout = pt.problem.layout
    g = row_values(limits, pt.rows, pt.C)
    rows = ActiveRows.where(tuple(np.isfinite(x) for x in g.g_lo), tuple(np.isfinite(x) for x in g.g_hi))
    _, A_full = rows.jacobian(pt.rows, limits, layout.free)
    V1 = fixed_coefficient_motion(layout.free, pt.C, T)[0]
    a_T = row_time_derivatives(A_full @ pt.C.ravel(), rows.kind, T, A_full @ V1.ravel())[0]

    def values(Tp):
        p = case["at"](Tp, case["active"], case["lam"])
        return (rows.jacobian(p.rows, limits, layout.free)[1] @ p.C.ravel(),)

    assert _rel(a_T, _reference(values, T)[0]) <= 1e-9  # measured ~1e-11


def test_the_free_time_steps_evaluate_the_lagrangian_once_per_step(monkeypatch):
    """Each free-T step's T column comes from the Newton matrix's own sample Hessians: one evaluation per step
    (the difference at T + δ took a second), but at a replan's first step when its Newton matrix is the last one
    of the replan it starts from (no sample Hessians at hand).
    """
    outcomes = []
    steps = replan_module.qp_steps

    def spy(*args, **kwargs):
        out = steps(*args, **kwargs)
        outcomes.append((kwargs.get("free") is not None, out.steps, out.evals))
        return out

    monkeypatch.setattr(replan_module, "qp_steps", spy)
    plan = hoc_cli.solve(lbr7_catch_problem(8))
    assert plan.converged
    free_steps = [(s, e) for free, s, e in outcomes if free]
    assert sum(s for s, _ in free_steps) >= 10  # steps in x and T were taken (else nothing is checked)
    for s, e in free_steps:
        assert e <= s + 2  # s + 1 points, at most one difference (the first step's); with the difference: 2(s + 1)


def test_a_frame_residual_at_several_durations_is_its_residual_at_each_and_the_goal_column_takes_one_pass(monkeypatch):
    """``FrameResidual.batch`` with T (K,) gives each sample's residual at its own T, the very numbers of K calls; the
    goal rows' T column (``GoalTerms.time_column``: the residual at T ± ε along the family) then runs the kinematics once
    per point instead of twice (an orientation row and a velocity row included).
    """
    import hoc_cli.goals.residuals as residuals
    from hoc_cli.elements import HermiteMesh
    from hoc_cli.goals.residuals import FrameResidual
    from hoc_cli.goals.terms import GoalPoint, GoalTerms

    lbr = load_robot(str(ROBOTS / "lbr7.urdf"))
    rng = np.random.default_rng(5)
    R0, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    res = FrameResidual(lbr, "lbr_flange", rng.normal(size=3), orientation=R0 * np.sign(np.linalg.det(R0)),
                        velocity=rng.normal(size=3), acceleration=np.array([0.0, 0.0, -9.81]), match_velocity=True)
    q, dq, T = rng.normal(size=(3, 7)), rng.normal(size=(3, 7)), np.array([0.31, 0.3, 0.29])
    out = res.batch(q, dq, T)
    assert out[3].shape == (3, res.size)
    for i in range(3):
        for got, ref in zip(out, res(q[i], dq[i], float(T[i]))):
            assert np.array_equal(got[i], ref)
    calls = []
    motion = residuals.link_motion
    monkeypatch.setattr(residuals, "link_motion", lambda *a: calls.append(1) or motion(*a))
    mesh = HermiteMesh("quintic", 0.4, 4)
    C = rng.normal(size=(5, 3, 7))
    terms = GoalTerms(mesh, [GoalPoint(1.0, res)], [rng.normal(size=res.size)], 0.0)
    V1, V2 = rng.normal(size=C.shape), rng.normal(size=C.shape)
    resid = terms.residuals(C)
    calls.clear()
    terms.time_column(C, 0.4, V1, V2, resid)
    assert len(calls) == 1


def test_the_goal_rows_and_their_curvature_samples_take_one_kinematics_pass_and_give_the_same_blocks(monkeypatch):
    """``GoalTerms.residuals_with_samples``: the residuals and the derivatives at the points ``newton_parts`` perturbs in
    one pass of the kinematics, the very numbers of ``residuals`` and ``newton_parts``' own pass (two passes)."""
    import hoc_cli.goals.residuals as residuals
    from hoc_cli.elements import HermiteMesh
    from hoc_cli.goals.residuals import FrameResidual, JointResidual
    from hoc_cli.goals.terms import GoalPoint, GoalTerms

    lbr = load_robot(str(ROBOTS / "lbr7.urdf"))
    rng = np.random.default_rng(6)
    frame = FrameResidual(lbr, "lbr_flange", rng.normal(size=3), velocity=rng.normal(size=3),
                          acceleration=np.array([0.0, 0.0, -9.81]), match_velocity=True)
    points = [GoalPoint(0.5, JointResidual(rng.normal(size=7))), GoalPoint(1.0, frame)]
    mesh = HermiteMesh("quintic", 0.4, 4)
    C = rng.normal(size=(5, 3, 7))
    terms = GoalTerms(mesh, points, [rng.normal(size=p.residual.size) for p in points], 0.3)
    calls = []
    motion = residuals.link_motion
    monkeypatch.setattr(residuals, "link_motion", lambda *a: calls.append(1) or motion(*a))
    res, samples = terms.residuals_with_samples(C)
    blocks = terms.newton_blocks(C, indefinite=True, res=res, samples=samples)
    assert len(calls) == 1 and samples[0] is None
    calls.clear()
    ref_res = terms.residuals(C)
    ref = terms.newton_blocks(C, indefinite=True, res=ref_res)
    assert len(calls) == 2
    for a, b in zip(res, ref_res):
        assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert np.array_equal(blocks, ref)
