"""Multipliers carried from one mesh to another (``constraints/prolong.py``): against the analytic
multiplier density of a velocity-limited move, and warm-started solves against cold ones."""
from __future__ import annotations

import numpy as np
import pytest

from hoc_cli.constraints import JointLimits, enforce
from hoc_cli.constraints.bounds import KINDS
from hoc_cli.constraints.penalty import LimitRows
from hoc_cli.constraints.prolong import Duals, prolong
from hoc_cli.constraints.sqp import sqp
from hoc_cli.elements import HermiteMesh
from hoc_cli.optimize import minimize
from hoc_cli.planner import plan, resample
from hoc_cli.problem import ControlProblem
from hoc_cli.system import LinearOscillator

D, T, V = 1.0, 1.0, 1.3  # rest to rest 0 → D in T with |q̇| <= V: the cruise arc is [t1, T − t1]
T1 = 1.5 * (T - D / V)
VELOCITY = 1


def arc_density() -> float:
    """The multiplier density η [cost units per (rad/s) per s] of q̇ <= V on the cruise arc.

    Derived for this test: with the Lagrangian ½∫q̈² + ∫η (q̇ − V), stationarity gives q⃛ = η + c
    (in the sense of distributions). Off the arc q is cubic with q⃛ = −2V/t1² (the arc
    q̇ = V(2t/t1 − t²/t1²)), on it q̈ = 0, so η = 2V/t1², constant, with no atom at the junctions
    (q̈ is continuous there). Its mass η (T − 2 t1) equals −dJ*/dV, J* = 4V²/(3 t1) (the
    sensitivity of the optimum to the bound), which ``test_the_multiplier_mass_is_the_sensitivity``
    checks.
    """
    return 2 * V / T1**2


def solve(N: int):
    system = LinearOscillator(1, omega=0.0)
    limits = JointLimits.from_arrays(system.joint_names, velocity=[V])
    r = plan(system, HermiteMesh("quintic", T, N), [0.0], [0.0], [D], [0.0], limits=limits)
    assert r.converged
    return system, limits, r


def part_density(rows: LimitRows, mu: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """(part midpoints [s], Σ μ/σ per part over its duration): the rows' multiplier density, (N·P,) each."""
    mesh, P = rows.mesh, rows.pieces
    per_part = np.stack([mu[:, rows.part[VELOCITY] == p, 0].sum(axis=1) for p in range(P)], axis=1)  # (N, P)
    mid = mesh.time_of(np.arange(mesh.N)[:, None], (np.arange(P)[None, :] + 0.5) / P)
    return mid.ravel(), (per_part / sigma / (mesh.hs[:, None] / P)).ravel()


def test_the_multiplier_mass_is_the_sensitivity_of_the_optimum_to_the_bound():
    _, limits, r = solve(64)
    sigma = limits.scale_of("velocity")[0]
    mass = float(r.limits.penalty.mu_hi[VELOCITY].sum()) / sigma
    dJ_dV = 8 * V / (3 * T1) - 4 * V**2 / (3 * T1**2) * 1.5 * D / V**2
    assert mass == pytest.approx(-dJ_dV, rel=2e-2)
    assert mass == pytest.approx(arc_density() * (T - 2 * T1), rel=2e-2)


def test_prolonged_multipliers_keep_the_density_of_the_arc_and_its_mass():
    _, limits, r = solve(32)
    sigma = limits.scale_of("velocity")[0]
    coarse = r.limits.duals()
    fine_mesh = HermiteMesh("quintic", T, 64)
    free = ControlProblem(LinearOscillator(1, omega=0.0), fine_mesh, [0.0], [0.0], [D], [0.0]).layout.free
    fine = LimitRows.build(fine_mesh, free, 1)
    lo, hi = prolong(coarse, fine)
    assert not np.any(lo[VELOCITY]) and hi[VELOCITY].shape == fine.shape(VELOCITY, 1)
    assert hi[VELOCITY].sum() == pytest.approx(coarse.mu_hi[VELOCITY].sum(), rel=1e-12)  # the mass
    t, density = part_density(fine, hi[VELOCITY], sigma)
    t_c, density_c = part_density(coarse.rows, coarse.mu_hi[VELOCITY], sigma)
    # each fine part takes the density of the coarse part it lies in
    np.testing.assert_allclose(density, density_c[np.searchsorted(t_c + 0.5 * (t_c[1] - t_c[0]), t)], rtol=1e-12)
    # the discrete multipliers spread unevenly over the redundant rows of a whole active element
    # (±10 % per part here), but their mean over the arc is the continuous density
    inside = (t > T1 + 0.1) & (t < T - T1 - 0.1)  # away from the junctions
    assert inside.sum() >= 10
    assert density[inside].mean() == pytest.approx(arc_density(), rel=2e-2)
    assert np.all(density[(t < T1 - 0.1) | (t > T - T1 + 0.1)] == 0)


def test_prolong_on_the_same_mesh_is_the_identity():
    _, _, r = solve(16)
    d = r.limits.duals()
    again = LimitRows.build(d.rows.mesh, r.problem.layout.free, 1)
    lo, hi = prolong(Duals(d.rows, d.mu_lo, d.mu_hi), again)
    for k in range(len(KINDS)):
        np.testing.assert_array_equal(lo[k], d.mu_lo[k])
        np.testing.assert_array_equal(hi[k], d.mu_hi[k])


def test_a_warm_started_augmented_lagrangian_reaches_the_cold_optimum_in_fewer_outer_rounds():
    """The augmented Lagrangian alone (no SQP) re-solving the plan on 32 elements with 4 more Gauss
    points (what the planner's quadrature check does): started from that plan's multipliers, the same
    optimum in fewer outer rounds than from λ = 0 (measured: 1 against 14). The two stop at
    different points of the augmented Lagrangian's own accuracy (rows within 1e-8 of their bounds
    count as active), so J agrees to 1e-8.
    """
    system, limits, first = solve(32)
    problem = ControlProblem(system, first.mesh, [0.0], [0.0], [D], [0.0], G=first.G + 4)
    x0 = problem.layout.pack(first.coeffs)

    def inner(p, x, tol):
        return minimize(lambda y: (lambda ev: (ev.J, ev.grad, ev))(p.evaluate(y)), x, precondition=p.newton,
                        method="newton", c2=0.9, tol=tol, noise=lambda ev: ev.noise)

    runs = {}
    for name, duals in (("cold", None), ("warm", first.limits.duals())):
        er = enforce(problem, system, limits, x0, 1e-10, inner, working=first.limits.working, duals=duals)
        assert er.status == "converged" and er.check.violations() == []
        runs[name] = er
    assert runs["warm"].J == pytest.approx(runs["cold"].J, rel=1e-8)
    assert runs["warm"].outer_iterations <= runs["cold"].outer_iterations - 3, \
        (runs["warm"].outer_iterations, runs["cold"].outer_iterations)


def test_multipliers_from_another_mesh_do_not_start_the_augmented_lagrangian():
    """A coarser mesh's multipliers start only the SQP's QP: the loop's result is the cold one, bit for bit."""
    system, limits, coarse = solve(16)
    mesh = HermiteMesh("quintic", T, 32)
    problem = ControlProblem(system, mesh, [0.0], [0.0], [D], [0.0])
    x0 = problem.layout.pack(resample(coarse.mesh, coarse.coeffs, mesh))

    def inner(p, x, tol):
        return minimize(lambda y: (lambda ev: (ev.J, ev.grad, ev))(p.evaluate(y)), x, precondition=p.newton,
                        method="newton", c2=0.9, tol=tol, noise=lambda ev: ev.noise)

    cold = enforce(problem, system, limits, x0, 1e-10, inner, working=coarse.limits.working)
    warm = enforce(problem, system, limits, x0, 1e-10, inner, working=coarse.limits.working,
                   duals=coarse.limits.duals())
    assert warm.J == cold.J and warm.outer_iterations == cold.outer_iterations


def test_the_sqp_keeps_its_cold_path_where_its_first_qp_needs_no_modification():
    """Given multipliers start the SQP's first QP only where that QP, from λ = 0, needs H's modification
    (the torque cost); here H is positive definite and the SQP is the cold one, bit for bit."""
    system, limits, coarse = solve(32)
    mesh = HermiteMesh("quintic", T, 64)
    problem = ControlProblem(system, mesh, [0.0], [0.0], [D], [0.0])
    x0 = problem.layout.pack(resample(coarse.mesh, coarse.coeffs, mesh))
    warm = prolong(coarse.limits.duals(), LimitRows.build(mesh, problem.layout.free, 1))
    assert np.any(warm[1][VELOCITY] > 0)
    cold_run = sqp(problem, system, limits, x0, 1e-10, working=coarse.limits.working)
    warm_run = sqp(problem, system, limits, x0, 1e-10, working=coarse.limits.working, multipliers=warm)
    assert cold_run.result.converged and warm_run.result.converged
    np.testing.assert_array_equal(warm_run.result.x, cold_run.result.x)
