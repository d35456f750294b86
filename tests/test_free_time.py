"""Free final time: the analytic optimum of a rest-to-rest move, dJ*/dT against finite differences
(the partial derivative at fixed s-domain coefficients, and the envelope derivative of re-solved
optima, limits active), and the bounds deciding when F' keeps its sign."""
from __future__ import annotations

import numpy as np
import pytest

from hoc_cli.constraints import JointLimits
from hoc_cli.elements import HermiteMesh
from hoc_cli.free_time import (
    cost_time_derivative,
    fixed_coefficient_correction,
    joint_goal_solver,
    minimize_time,
    plan_time_derivative,
    rescale,
)
from hoc_cli.model import load_robot
from hoc_cli.planner import plan
from hoc_cli.problem import ControlProblem
from hoc_cli.system import LinearOscillator, RobotSystem
from tests._robots import ROBOTS


@pytest.mark.parametrize("order", ["cubic", "quintic"])
@pytest.mark.parametrize("weight", [2.0, 0.5])
def test_rest_to_rest_free_time_matches_the_closed_form(order, weight):
    """q̈ = u, ½∫u² from rest at 0 to rest at D: the optimum is the cubic q = D(3τ² − 2τ³), τ = t/T, with
    ∫q̈² = D²/T³ ∫₀¹(6 − 12τ)² dτ = 12 D²/T³, so J*(T) = 6D²/T³ (exact on any Hermite mesh: the cubic is
    in the space). F = 6D²/T³ + wT is least where −18D²/T⁴ + w = 0: T* = (18D²/w)^¼, dJ*/dT = −w.
    """
    D = 1.0
    solve = joint_goal_solver(LinearOscillator(1, omega=0.0), order, 4, [0.0], [0.0], [D], [0.0])
    r = minimize_time(solve, 0.3, 5.0, guess=1.0, weight=weight, rtol=1e-10)
    T_star = (18 * D**2 / weight) ** 0.25
    assert r.bound is None
    assert abs(r.T / T_star - 1) < 1e-8
    assert abs(r.dJ_dT + weight) < 1e-8 * weight
    assert abs(r.J - 6 * D**2 / r.T**3) < 1e-12 * r.J
    assert len(r.history) <= 15


@pytest.mark.parametrize("order", ["cubic", "quintic"])
def test_partial_time_derivative_against_central_differences(order):
    """∂J/∂T with the s-domain coefficients fixed and x0, x1 kept in the t domain (nonzero q̇ at both ends)."""
    system = LinearOscillator(2, omega=1.3)
    bc = ([0.0, 0.1], [0.3, -0.2], [1.0, 0.5], [0.1, 0.4])
    T0 = 1.2

    def problem_at(T):
        return ControlProblem(system, HermiteMesh(order, T, 5), *bc)

    p = problem_at(T0)
    x = p.initial_guess() + 0.1 * np.random.default_rng(0).standard_normal(p.layout.size)
    C = p.coefficients(x)

    def J(T):
        q = problem_at(T)
        return q.value(q.layout.pack(rescale(C, T0, T)))  # the fixed coefficients come from x0, x1

    dT, G = cost_time_derivative(p, C)
    dT += fixed_coefficient_correction(p.layout.free, C, G, T0)
    h = 1e-5
    fd = (J(T0 + h) - J(T0 - h)) / (2 * h)
    assert abs(dT - fd) < 1e-8 * abs(fd)
    # G is ∂J/∂C over every coefficient: its free part is the design gradient
    assert np.allclose(p.layout.pack(G), p.evaluate(x).grad, rtol=1e-12, atol=1e-12 * np.abs(G).max())


def velocity_limited_cost(D, T, v):
    """J*(T) of the velocity-limited rest-to-rest move (tests/test_limits_enforce.py): 8v²/(9(T − D/v))."""
    return 8 * v**2 / (9 * (T - D / v))


@pytest.mark.parametrize("order", ["cubic", "quintic"])
def test_envelope_derivative_with_an_active_velocity_limit(order):
    """dJ*/dT with the limit's multipliers against central differences of re-solved optima, and
    against the continuous problem's −8v²/(9(T − D/v)²)."""
    system = LinearOscillator(1, omega=0.0)
    D, v, T, N = 1.0, 1.3, 1.0, 16
    limits = JointLimits.from_arrays(system.joint_names, velocity=[v])

    def solve(T):
        return plan(system, HermiteMesh(order, T, N), [0.0], [0.0], [D], [0.0], limits=limits)

    r = solve(T)
    assert r.limits.active_limits()
    d = plan_time_derivative(r, system, limits)
    h = 1e-4
    fd = (solve(T + h).J - solve(T - h).J) / (2 * h)
    assert abs(d - fd) < 1e-6 * abs(fd)
    exact = -8 * v**2 / (9 * (T - D / v) ** 2)
    assert abs(d / exact - 1) < 5e-3  # the mesh error (measured: 2e-4 quintic, 2e-3 cubic at N = 16)


def test_free_time_with_an_active_limit_approaches_the_analytic_optimum():
    """F = 8v²/(9(T − D/v)) + wT is least at T* = D/v + √(8v²/(9w)) (the limit active throughout)."""
    system = LinearOscillator(1, omega=0.0)
    D, v, w = 1.0, 1.3, 28.0
    limits = JointLimits.from_arrays(system.joint_names, velocity=[v])
    r = minimize_time(joint_goal_solver(system, "quintic", 32, [0.0], [0.0], [D], [0.0], limits=limits),
                      0.5, 3.0, guess=1.5, weight=w, rtol=1e-10)
    T_star = D / v + np.sqrt(8 * v**2 / (9 * w))
    assert r.bound is None and r.result.limits.status == "converged"
    assert abs(r.T / T_star - 1) < 1e-4
    assert abs(r.dJ_dT + w) < 1e-8 * w


def test_without_a_time_price_and_without_gravity_the_upper_bound_decides():
    system = LinearOscillator(1, omega=0.0)
    r = minimize_time(joint_goal_solver(system, "cubic", 4, [0.0], [0.0], [1.0], [0.0]), 0.5, 2.0, weight=0.0)
    assert r.bound == "max" and r.T == 2.0
    assert abs(r.dJ_dT + 18 / 2.0**4) < 1e-9
    r = minimize_time(joint_goal_solver(system, "cubic", 4, [0.0], [0.0], [1.0], [0.0]), 0.5, 2.0, weight=1e3)
    assert r.bound == "min" and r.T == 0.5


def test_gravity_gives_an_interior_optimum_at_zero_weight():
    """Pendulum held away from hanging (1 → 1.5 rad): short moves cost ~1/T³, holding costs ~T."""
    system = RobotSystem(load_robot(ROBOTS / "pendulum.urdf"))
    bc = ([1.0], [0.0], [1.5], [0.0])
    r = minimize_time(joint_goal_solver(system, "quintic", 8, *bc), 0.2, 3.0, weight=0.0, rtol=1e-10)
    assert r.bound is None
    assert abs(r.dJ_dT) < 1e-8 * r.J / r.T
    for f in (0.99, 1.01):  # a local minimum of J*(T) (warm-started neighbours on the same branch)
        T = r.T * f
        other = plan(system, HermiteMesh("quintic", T, 8), *bc, C_init=rescale(r.result.coeffs, r.T, T))
        assert other.J > r.J


def test_rescale_keeps_the_s_domain_trajectory():
    mesh = HermiteMesh("quintic", 1.0, 3)
    C = np.random.default_rng(1).standard_normal((4, 3, 2))
    C2 = rescale(C, 1.0, 2.5)
    t = np.linspace(0, 1, 7)
    for r in range(3):
        assert np.allclose(HermiteMesh("quintic", 2.5, 3).evaluate(C2, 2.5 * t, r) * 2.5**r, mesh.evaluate(C, t, r))
    with pytest.raises(ValueError):
        minimize_time(lambda T, p: None, 2.0, 1.0)


def test_a_search_out_of_solves_ends_not_converged_with_its_best_plan():
    """The rest-to-rest move of the closed-form test above with the search allowed 3 solves (it needs about 8):
    it ends at the solve with the smallest |F'|, not converged, its plan's status max_iter and its limits'
    outcome not converged; it raised RuntimeError (an internal error of ``hoc plan``) before."""
    D, weight = 1.0, 2.0
    limits = JointLimits.from_arrays(["x"], velocity=[10.0])  # far from binding: an outcome to mark
    solve = joint_goal_solver(LinearOscillator(1, omega=0.0), "quintic", 4, [0.0], [0.0], [D], [0.0], limits=limits)
    full = minimize_time(solve, 0.3, 5.0, guess=0.5, weight=weight, rtol=1e-10)
    assert full.converged and len(full.history) > 3
    r = minimize_time(solve, 0.3, 5.0, guess=0.5, weight=weight, rtol=1e-10, max_solves=3)
    assert not r.converged and len(r.history) == 3
    assert abs(r.dJ_dT + weight) == min(abs(p.dJ_dT + weight) for p in r.history)
    assert not r.result.converged and r.result.optimizer.status.value == "max_iter"
    assert r.result.limits.status == "not_converged" and "3 solves" in r.result.optimizer.message
    assert all(p.result.converged for p in r.history)  # the search's own solves are left as they were
