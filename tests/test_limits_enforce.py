"""Joint limits enforced by the augmented Lagrangian: against an analytic constrained optimum,
the exact check on every element, derivatives against central differences, and no price when
nothing binds."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hoc_cli.constraints import JointLimits, check_limits, shortest_duration
from hoc_cli.constraints.augmented_lagrangian import MARGIN
from hoc_cli.constraints.bernstein import bernstein_rows
from hoc_cli.constraints.bounds import KINDS
from hoc_cli.constraints.extrema import element_polynomials, extrema
from hoc_cli.constraints.penalty import LimitRows, LimitTerms
from hoc_cli.elements import HermiteMesh
from hoc_cli.model import load_robot
from hoc_cli.planner import plan
from hoc_cli.problem import ControlProblem
from hoc_cli.system import LinearOscillator, RobotSystem
from tests._robots import ROBOTS


def velocity_limited_optimum(D: float, T: float, v: float) -> float:
    """min ½∫q̈² over rest-to-rest moves 0 → D in T with |q̇| <= v, for D/T < v < 1.5 D/T.

    Derived for docs/limits.md: the velocity bound is a first-order state constraint, so u = q̈ is
    continuous at the junctions. Off the bound q is cubic; the arc [0, t1] with q̇(0) = 0,
    q̇(t1) = v, q̈(t1) = 0 is q̇ = v(2t/t1 − t²/t1²) and covers 2v t1/3; the mirror arc ends the
    move and the bound holds on [t1, T − t1]. Distance: vT − 2v t1/3 = D gives t1 = 1.5 (T − D/v),
    and J* = 2 · ½ ∫₀^t1 (2v/t1)² (1 − t/t1)² dt = 4v² / (3 t1).
    """
    t1 = 1.5 * (T - D / v)
    return 4 * v**2 / (3 * t1)


@pytest.mark.parametrize("order", ["cubic", "quintic"])
def test_velocity_limited_move_converges_to_the_analytic_optimum_from_above(order):
    system = LinearOscillator(1, omega=0.0)
    D, T, v = 1.0, 1.0, 1.3  # the unconstrained optimum peaks at 1.5 rad/s; junction t1 = 0.346 s, off the nodes
    J_star = velocity_limited_optimum(D, T, v)
    limits = JointLimits.from_arrays(system.joint_names, velocity=[v])
    Ns = np.array([16, 32, 64, 128, 256])
    errors = []
    for N in Ns:
        result = plan(system, HermiteMesh(order, T, int(N)), [0.0], [0.0], [D], [0.0], limits=limits)
        assert result.converged and result.limits.status == "converged"
        assert result.limits.check.violations() == []
        errors.append((result.J - J_star) / J_star)
    errors = np.array(errors)
    # Bernstein rows bound q̇_h on every whole element: each plan is feasible for the continuous
    # problem, so its cost cannot fall below the continuous optimum (quadrature is exact here).
    assert np.all(errors > 0)
    order_fit = -np.polyfit(np.log(Ns), np.log(errors), 1)[0]
    assert order_fit >= 2.0, (errors, order_fit)  # measured: 3.0 (cubic), 2.9 (quintic); see docs/limits.md
    assert errors[-1] < 1e-7


def test_the_velocity_bound_is_active_on_the_cruise_arc_only():
    system = LinearOscillator(1, omega=0.0)
    D, T, v = 1.0, 1.0, 1.3
    limits = JointLimits.from_arrays(system.joint_names, velocity=[v])
    result = plan(system, HermiteMesh("quintic", T, 32), [0.0], [0.0], [D], [0.0], limits=limits)
    (active,) = result.limits.active_limits()
    assert (active["joint"], active["kind"]) == ("q0", "velocity")
    t1 = 1.5 * (T - D / v)
    lo, hi = active["intervals"][0][0], active["intervals"][-1][1]
    h = T / 32
    assert abs(lo - t1) <= h and abs(hi - (T - t1)) <= h


def test_a_move_too_fast_for_its_velocity_limit_is_infeasible_and_names_the_shortest_duration():
    system = LinearOscillator(1, omega=0.0)
    limits = JointLimits.from_arrays(system.joint_names, velocity=[0.8])  # needs T >= 1/0.8 = 1.25 s
    result = plan(system, HermiteMesh("quintic", 1.0, 8), [0.0], [0.0], [1.0], [0.0], limits=limits)
    assert result.limits.status == "infeasible" and not result.converged
    T_min, joint, kind = shortest_duration(limits, [0.0], [0.0], [1.0], [0.0])
    assert (joint, kind) == ("q0", "velocity") and T_min == pytest.approx(1.25)


def test_when_nothing_binds_the_result_is_the_unconstrained_optimum_bit_for_bit():
    model = load_robot(ROBOTS / "two_link.urdf")
    system = RobotSystem(model)
    mesh = HermiteMesh("quintic", 1.5, 16)
    args = (system, mesh, [0.0, 0.0], [0.0, 0.0], [1.2, -0.6], [0.0, 0.0])
    free = plan(*args)
    limited = plan(*args, limits=JointLimits.from_model(model))
    assert limited.limits.status == "converged" and limited.limits.outer_iterations == 1
    assert limited.J == free.J and np.array_equal(limited.coeffs, free.coeffs)
    assert limited.optimizer.iterations == free.optimizer.iterations


@pytest.mark.parametrize("order", ["cubic", "quintic"])
@pytest.mark.parametrize("deriv", [0, 1, 2, 3])
def test_exact_extrema_agree_with_numpy_roots_of_each_element_polynomial(order, deriv):
    rng = np.random.default_rng(3 + deriv)
    mesh = HermiteMesh(order, 1.7, 4)
    C = rng.normal(size=(5, mesh.m, 2))
    ex = extrema(mesh, C, deriv)
    poly = element_polynomials(mesh, C, deriv)
    for e in range(mesh.N):
        for j in range(2):
            p = np.polynomial.Polynomial(poly[e, j])
            crit = [r.real for r in p.deriv().roots() if abs(r.imag) < 1e-9 and 0 <= r.real <= 1]
            vals = p(np.array([0.0, 1.0] + crit))
            assert ex.max[e, j] == pytest.approx(vals.max(), abs=1e-12 * (1 + abs(vals).max()))
            assert ex.min[e, j] == pytest.approx(vals.min(), abs=1e-12 * (1 + abs(vals).max()))
            assert p(ex.s_max[e, j]) == pytest.approx(ex.max[e, j], abs=1e-12 * (1 + abs(vals).max()))


@pytest.mark.parametrize("order", ["cubic", "quintic"])
@pytest.mark.parametrize("deriv", [0, 1, 2, 3])
def test_bernstein_rows_enclose_each_element_polynomial_and_match_it_at_the_ends(order, deriv):
    rng = np.random.default_rng(11 + deriv)
    mesh = HermiteMesh(order, 2.0, 5)
    C = rng.normal(size=(6, mesh.m, 3))
    R, part = bernstein_rows(mesh, deriv)
    beta = np.einsum("ka,ean->ekn", R, mesh.local_coefficients(C))
    ex = extrema(mesh, C, deriv)
    assert np.all(beta.max(axis=1) >= ex.max - 1e-12) and np.all(beta.min(axis=1) <= ex.min + 1e-12)
    d = beta.shape[1] // 2 - 1
    left = mesh.evaluate(C, mesh.nodes[:-1] + 1e-300, deriv)
    assert np.allclose(beta[:, 0], left, rtol=0, atol=1e-10)  # β_0 of the first part is the value at s = 0
    assert np.allclose(beta[:, d], mesh.evaluate(C, (np.arange(mesh.N) + 0.5) * mesh.h, deriv), atol=1e-10)


def test_limit_terms_gradient_matches_central_differences_with_every_kind_active():
    model = load_robot(ROBOTS / "two_link.urdf")
    system = RobotSystem(model)
    mesh = HermiteMesh("quintic", 1.0, 3)
    problem = ControlProblem(system, mesh, [0.0, 0.0], [0.0, 0.0], [1.2, -0.6], [0.0, 0.0])
    limits = JointLimits.from_arrays(model.joint_names, lower=[-0.1, -0.5], upper=[0.9, 0.2], velocity=[1.0, 0.5],
                                     acceleration=[3.0, 2.0], effort=[20.0, 5.0], jerk=[10.0, 8.0])
    rows = LimitRows.build(mesh, problem.layout.free, 2)
    rng = np.random.default_rng(5)
    lam_lo = tuple(rng.uniform(0, 1, rows.shape(k, 2)) * (rng.uniform(size=rows.shape(k, 2)) < 0.3) for k in range(len(KINDS)))
    lam_hi = tuple(rng.uniform(0, 1, rows.shape(k, 2)) * (rng.uniform(size=rows.shape(k, 2)) < 0.3) for k in range(len(KINDS)))
    terms = LimitTerms(system, limits, rows, np.ones((len(KINDS), 2), bool), lam_lo, lam_hi, rho=50.0, margin=MARGIN)
    x = problem.initial_guess() + 0.05 * rng.normal(size=problem.layout.size)
    C = problem.coefficients(x)
    g = problem.layout.pack(terms.evaluate(C).grad)
    assert np.count_nonzero(g) > 10
    num = np.empty_like(g)
    for i in range(x.size):
        dx = np.zeros_like(x)
        dx[i] = 1e-6
        num[i] = (terms.evaluate(problem.coefficients(x + dx), grad=False).value
                  - terms.evaluate(problem.coefficients(x - dx), grad=False).value) / 2e-6
    assert np.max(np.abs(g - num)) <= 1e-6 * np.max(np.abs(g))


def test_check_reports_the_true_peak_between_the_nodes():
    mesh = HermiteMesh("quintic", 1.0, 1)
    C = np.zeros((2, 3, 1))
    C[0, 1, 0], C[1, 1, 0] = 4.0, -4.0  # q = 0 at both nodes; it rises and returns: its peak is inside
    limits = JointLimits.from_arrays(("j",), lower=[-1.0], upper=[0.5])
    t = np.linspace(0.0, 1.0, 200001)
    dense = mesh.evaluate(C, t, 0)[:, 0]
    (v,) = check_limits(LinearOscillator(1, omega=0.0), limits, mesh, C).violations()
    assert (v["joint"], v["kind"], v["limit"]) == ("j", "position", [-1.0, 0.5])
    assert dense.max() - 1e-9 <= v["worst"] <= dense.max() + 1e-15  # the exact maximum, never below a sample
    assert v["t"] == pytest.approx(t[np.argmax(dense)], abs=1e-4)


def test_feasible_is_true_exactly_when_no_violation_is_listed():
    """``LimitCheck.feasible`` (vectorised) agrees with ``violations()`` being empty: every kind, either side, at and
    just beyond the tolerance, with unbounded joints (−inf excess) and a NaN value (never a violation)."""
    mesh = HermiteMesh("quintic", 1.0, 1)
    limits = JointLimits.from_arrays(("a", "b"), lower=[-1.0, -np.inf], upper=[0.5, np.inf], velocity=[2.0, 3.0],
                                     acceleration=[10.0, 10.0], jerk=[100.0, 100.0], effort=[5.0, 7.0])
    base = check_limits(LinearOscillator(2, omega=0.0), limits, mesh, np.zeros((2, 3, 2)))
    tol_lo, tol_hi = base.tolerance()
    rng = np.random.default_rng(0)
    seen = set()
    for trial in range(400):
        hi = np.where(np.isfinite(base.hi_excess), -1.0, -np.inf)
        lo = np.where(np.isfinite(base.lo_excess), -1.0, -np.inf)
        k, j, side = rng.integers(len(KINDS)), rng.integers(2), rng.integers(2)
        excess, tol = (hi, tol_hi) if side else (lo, tol_lo)
        if np.isfinite(excess[k, 0, j]):
            excess[k, 0, j] = tol[k, j] * rng.choice([0.5, 1.0, 1.5, 3.0]) if trial % 7 else np.nan
        chk = dataclasses.replace(base, hi_excess=hi, lo_excess=lo)
        assert chk.feasible == (not chk.violations())
        seen.add(chk.feasible)
    assert seen == {True, False}
