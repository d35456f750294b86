"""The SQP that imposes the kinematic limits: its pieces against dense references, and the whole
against the augmented Lagrangian (an independent method) on a robot whose velocity and acceleration
limits bind."""
from __future__ import annotations

import numpy as np
import pytest

from hoc_cli.banded import BandedSPD
from hoc_cli.constraints import JointLimits, check_limits
from hoc_cli.constraints.augmented_lagrangian import MARGIN, enforce
from hoc_cli.constraints.bounds import KINDS
from hoc_cli.constraints.penalty import LimitRows, LimitTerms
from hoc_cli.constraints.qp import QPModel, QPRows
from hoc_cli.constraints.qp_steps import line_minimum, pseudo_solve
from hoc_cli.constraints.sqp import kinematic_working
from hoc_cli.elements import HermiteMesh
from hoc_cli.model import load_robot
from hoc_cli.optimize import minimize
from hoc_cli.planner import plan
from hoc_cli.problem import ControlProblem
from hoc_cli.system import RobotSystem
from tests._robots import ROBOTS

START, GOAL = [0.0, 0.0], [1.2, -0.6]


def _problem(N: int = 6, split: tuple[int, ...] = ()):
    model = load_robot(ROBOTS / "two_link.urdf")
    system = RobotSystem(model)
    mesh = HermiteMesh("quintic", 1.5, N)
    mesh = mesh.split(list(split)) if split else mesh
    return model, system, ControlProblem(system, mesh, START, [0.0, 0.0], GOAL, [0.0, 0.0])


def _qp(split: tuple[int, ...] = (), rho: float = 3000.0, seed: int = 3):
    """A QP model on the two-link arm with position, velocity and acceleration rows, random multipliers."""
    model, system, problem = _problem(split=split)
    limits = JointLimits.from_arrays(model.joint_names, lower=[-0.1, -0.5], upper=[0.9, 0.2], velocity=[1.0, 0.5],
                                     acceleration=[3.0, 2.0])
    rows = LimitRows.build(problem.mesh, problem.layout.free, 2)
    rng = np.random.default_rng(seed)
    lam = tuple(tuple(rng.uniform(0, 1, rows.shape(k, 2)) * (rng.uniform(size=rows.shape(k, 2)) < 0.3)
                      for k in range(len(KINDS))) for _ in range(2))
    # a row's two sides are never active together (it would take λ of order ρ × its range): one side each
    lam = (lam[0], tuple(np.where(lo > 0, 0.0, hi) for lo, hi in zip(*lam)))
    working = kinematic_working(limits)
    terms = LimitTerms(system, limits, rows, working, lam[0], lam[1], rho=rho, margin=MARGIN)
    ev = problem.evaluate(problem.initial_guess())
    qrows = QPRows.build(rows, limits, working, problem.layout.free, MARGIN)
    qp = QPModel(problem, ev, qrows, qrows.values(terms.evaluate(problem.coefficients(ev.x), grad=False)))
    lam = qrows.gather(*lam)  # the multipliers on the rows not imposed (data rows) are dropped ...
    lo, hi = qrows.scatter(lam)  # ... so the reference terms take them as 0 too
    terms = LimitTerms(system, limits, rows, working, lo, hi, rho=rho, margin=MARGIN)
    return problem, ev, terms, qp, lam, rho * qrows.w, rng


@pytest.mark.parametrize("split", [(), (0, 3, 4)], ids=["uniform", "nonuniform"])
def test_qp_model_is_the_augmented_lagrangian_of_the_penalty_terms(split):
    """q(d), its gradient, the rows, μ and the Newton matrix of the explicit rows against the same
    quantities from ``LimitTerms`` (per-kind arrays, an independent assembly) at random d."""
    problem, ev, terms, qp, lam, rw, rng = _qp(split)
    N, L, _ = qp.H.shape
    mn = L // 2
    dense = np.zeros(((N + 1) * mn, (N + 1) * mn))  # H assembled from its element blocks
    for e in range(N):
        dense[e * mn:e * mn + L, e * mn:e * mn + L] += qp.H[e]
    free = problem.layout.free
    for _ in range(3):
        d = 0.1 * rng.normal(size=ev.x.size)
        q, r, g, mu = qp.value(d, lam, rw)
        C = problem.coefficients(ev.x + d)
        pv = terms.evaluate(C)
        Hd = dense[np.ix_(free, free)] @ d
        assert np.allclose(qp.Hd(d), Hd, rtol=1e-12, atol=1e-12 * np.abs(Hd).max())
        assert q == pytest.approx(float(ev.grad @ d + 0.5 * d @ Hd) + pv.value, rel=1e-12)
        assert np.allclose(r, ev.grad + Hd + problem.layout.pack(pv.grad), rtol=1e-12, atol=1e-12 * np.abs(r).max())
        assert np.allclose(g, qp.qrows.values(pv), rtol=1e-12, atol=1e-12)
        assert np.allclose(qp.qrows.at(C), g, rtol=1e-12, atol=1e-12)
        assert np.allclose(mu, qp.qrows.gather(pv.mu_lo, pv.mu_hi), rtol=1e-12, atol=1e-12)
        assert (mu > 0).any() and not (mu > 0).all()
        assert not any(((lo > 0) & (hi > 0)).any() for lo, hi in zip(pv.mu_lo, pv.mu_hi))  # one side per row
        K = qp.newton(mu > 0, rw)
        ref = problem.banded(qp.H + terms.newton_blocks(C, pv))
        v = rng.normal(size=ev.x.size)
        assert np.allclose(K.solve(v), ref.solve(v), rtol=1e-9, atol=1e-12 * np.abs(ref.solve(v)).max())


def test_line_minimum_is_the_minimiser_of_the_piecewise_quadratic_model_along_the_step():
    problem, ev, terms, qp, lam, rw, rng = _qp()
    d = 0.05 * rng.normal(size=ev.x.size)
    s = 0.3 * rng.normal(size=ev.x.size)
    q0, r0, g0, _ = qp.value(d, lam, rw)
    _, _, g1, _ = qp.value(d + s, lam, rw)
    slope = float(r0 @ s)
    if slope > 0:  # make s a descent direction
        s, slope = -s, -slope
        _, _, g1, _ = qp.value(d + s, lam, rw)
    a = line_minimum(slope, float(s @ qp.Hd(s)), lam, rw, g0, g1)
    grid = np.linspace(0.0, 3.0 * max(a, 1e-3), 3001)
    values = np.array([qp.value(d + t * s, lam, rw)[0] for t in grid])
    assert a > 0
    assert qp.value(d + a * s, lam, rw)[0] <= values.min() + 1e-12 * abs(values.min())
    eps = 1e-6 * a  # the directional derivative changes sign at a
    assert float(qp.value(d + (a - eps) * s, lam, rw)[1] @ s) < 0 < float(qp.value(d + (a + eps) * s, lam, rw)[1] @ s)


@pytest.mark.parametrize("split", [(), (0, 3, 4, 5, 9)], ids=["uniform", "nonuniform"])
def test_sqp_and_augmented_lagrangian_agree_where_velocity_and_acceleration_limits_bind(split):
    model, system, problem = _problem(N=12, split=split)
    assert problem.mesh.uniform == (not split)
    free = plan(system, problem.mesh, START, [0.0, 0.0], GOAL, [0.0, 0.0])
    t = np.linspace(0, 1.5, 301)
    dq = np.abs(free.mesh.evaluate(free.coeffs, t, 1)).max(axis=0)
    ddq = np.abs(free.mesh.evaluate(free.coeffs, t, 2)).max(axis=0)
    # joint 0's velocity 10 % below its free peak, joint 1's acceleration 20 % below
    limits = JointLimits.from_arrays(model.joint_names, velocity=[0.9 * dq[0], np.inf],
                                     acceleration=[np.inf, 0.8 * ddq[1]])

    inner = _newton_inner

    x0 = problem.initial_guess()
    results = {use: enforce(problem, system, limits, x0, 1e-11, inner, use_sqp=use) for use in (True, False)}
    for r in results.values():
        assert r.status == "converged"
        assert check_limits(system, limits, problem.mesh, problem.coefficients(r.x)).violations() == []
        kinds = {(a["joint"], a["kind"]) for a in r.active_limits()}
        assert kinds == {(model.joint_names[0], "velocity"), (model.joint_names[1], "acceleration")}
    assert "SQP" in results[True].message and "SQP" not in results[False].message
    assert results[True].sqp == "converged" and results[False].sqp == ""
    assert results[True].inner.decrement >= 0  # |gᵀd + ½dᵀHd|, never a negative rounding residue
    # the SQP's multipliers are KKT multipliers of the plan: ∇J + Σ μ ∇g = 0 to the level the stopping
    # test (tol 1e-11) leaves, measured 2.3e-7 relative (free_time's envelope derivative relies on them;
    # multipliers that miss the ρ·g part of an exact-multiplier step are off by 1e-3)
    r = results[True]
    pv = r.penalty
    terms = LimitTerms(system, limits, r.rows, np.ones((len(KINDS), 2), bool), pv.mu_lo, pv.mu_hi, rho=1e-30, margin=MARGIN)
    grad = problem.evaluate(r.x).grad
    stationarity = grad + problem.layout.pack(terms.evaluate(problem.coefficients(r.x)).grad)
    assert np.abs(stationarity).max() <= 2e-6 * np.abs(grad).max()
    J_sqp, J_al = results[True].J, results[False].J
    assert J_sqp > free.J * (1 + 1e-4)  # the limits cost something
    assert J_sqp == pytest.approx(J_al, rel=1e-9)



@pytest.mark.parametrize("grouped", [False, True])
def test_pseudo_solve_is_the_pseudo_inverse_of_the_active_rows_schur_complement(grouped):
    """δ = S⁺g and K⁻¹Aᵀδ for S = A K⁻¹ Aᵀ with dependent rows (repeated and combined), against dense
    numpy (pinv and solve) on a banded SPD K with fixed coefficients; grouped: the rows split in two
    groups touching disjoint coefficients (two joints), each with its own dependent rows."""
    rng = np.random.default_rng(7)
    N, mn = 6, 4
    L = 2 * mn
    size = (N + 1) * mn
    M = rng.normal(size=(N, L, L))
    blocks = M @ np.swapaxes(M, 1, 2) + 0.5 * np.eye(L)
    free = np.ones(size, bool)
    free[:mn] = free[-mn:] = False
    K = BandedSPD.assemble(blocks, stride=mn, size=size, free=free, shift=0.0)
    dense = np.zeros((size, size))
    for e in range(N):
        dense[e * mn:e * mn + L, e * mn:e * mn + L] += blocks[e]
    Kf = dense[np.ix_(free, free)]
    elements = [0, 1, 1, 2, 3, 3, 4, 5, 5, 2, 2, 4]
    A = np.zeros((len(elements), size))
    groups = np.array([0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1]) if grouped else None
    for i, e in enumerate(elements):
        A[i, e * mn:e * mn + L] = rng.normal(size=L)
        if grouped:  # group g touches the coefficients of parity g only
            A[i, np.arange(size) % 2 != groups[i]] = 0.0
    A[2] = 2.0 * A[1]  # dependent rows, consistent targets below
    A[5] = A[4] - 0.5 * A[3]
    A[10] = -A[9]
    A[:, ~free] = 0.0
    g = A[:, free] @ rng.normal(size=free.sum())
    delta, step = pseudo_solve(K, A.T.copy(), g, groups)
    Af = A[:, free]
    S = Af @ np.linalg.solve(Kf, Af.T)
    ref = np.linalg.pinv(S, rcond=1e-12) @ g
    assert np.allclose(delta, ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())
    assert np.allclose(step, np.linalg.solve(Kf, Af.T @ ref), rtol=1e-9, atol=1e-12)
    assert np.allclose(Af @ step, g, rtol=1e-9, atol=1e-12 * np.abs(g).max())  # the rows reach their targets


def _newton_inner(p, x0, tol):
    """The inner minimiser of the augmented Lagrangian in these tests: Newton steps on ``p``'s Newton matrix."""
    return minimize(lambda x: (lambda ev: (ev.J, ev.grad, ev))(p.evaluate(x)), x0, precondition=p.newton,
                    method="newton", c2=0.9, tol=tol)


def _velocity_limited():
    """(system, problem, limits): the N = 12 problem with joint 0's velocity 10 % below its free peak."""
    model, system, problem = _problem(N=12)
    free = plan(system, problem.mesh, START, [0.0, 0.0], GOAL, [0.0, 0.0])
    dq = np.abs(free.mesh.evaluate(free.coeffs, np.linspace(0, 1.5, 301), 1)).max(axis=0)
    return system, problem, JointLimits.from_arrays(model.joint_names, velocity=[0.9 * dq[0], np.inf])


def test_a_stalled_augmented_lagrangian_from_a_start_within_the_limits_is_not_called_infeasible(monkeypatch):
    """A start within the limits proves the task feasible: when the penalty grows out of range anyway
    (made to happen at once here by shrinking RHO_RANGE), the result is "not_converged" and the start."""
    import hoc_cli.constraints.auglag as al

    system, problem, limits = _velocity_limited()
    inner = _newton_inner

    solved = enforce(problem, system, limits, problem.initial_guess(), 1e-11, inner)
    assert solved.status == "converged" and solved.check.violations() == []
    monkeypatch.setattr(al, "RHO_RANGE", 1e-6)
    outside = np.array(problem.initial_guess())  # min-jerk: outside this velocity limit
    assert check_limits(system, limits, problem.mesh, problem.coefficients(outside)).violations()
    assert enforce(problem, system, limits, outside, 1e-11, inner).status == "infeasible"
    r = enforce(problem, system, limits, solved.x, 1e-11, inner, working=solved.working)
    assert r.status == "not_converged" and "stalled" in r.message
    assert np.array_equal(r.x, solved.x) and r.check.violations() == []


def test_an_augmented_lagrangian_still_converging_at_the_penalty_cap_goes_on(monkeypatch):
    """At the penalty cap (made to come early here: RHO_RANGE = 1e3, where the uncapped iteration grows ρ
    1e4-fold) an iteration whose violations still fall is not infeasible: ρ stays at the cap, the
    multiplier updates go on, and it converges to the optimum of the uncapped iteration (J to 1e-9)."""
    import hoc_cli.constraints.auglag as al

    system, problem, limits = _velocity_limited()
    inner = _newton_inner

    reference = enforce(problem, system, limits, problem.initial_guess(), 1e-11, inner)
    assert reference.status == "converged"
    monkeypatch.setattr(al, "RHO_RANGE", 1e3)
    capped = enforce(problem, system, limits, problem.initial_guess(), 1e-11, inner)
    assert capped.status == "converged" and capped.check.violations() == []
    assert capped.J == pytest.approx(reference.J, rel=1e-9)
    assert capped.rho <= reference.rho / 5  # the penalty stayed at the cap
