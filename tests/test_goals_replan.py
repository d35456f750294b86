"""Warm replans (``hoc_cli.goals.replan``): from the previous optimum after the target moves, the same
optimum as a cold solve of the moved task (J, T, the link at the target to 1e-9) in a few Newton steps."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hoc_cli.dynamics import link_poses, link_velocity
from hoc_cli.elements import HermiteMesh
from hoc_cli.free_time import rescale
from hoc_cli.goals import FrameResidual, Goals, inverse_kinematics, plan_goals
from hoc_cli.goals.free_time_sqp import minimize_time_sqp
from hoc_cli.goals.replan import TimeRange, curvature_of, replan
from hoc_cli.goals.time_solver import goal_solver
from hoc_cli.model import load_robot
from hoc_cli.system import RobotSystem
from tests._robots import ROBOTS

MODEL = load_robot(ROBOTS / "two_link.urdf")
SYSTEM = RobotSystem(MODEL)
Q0, Z = np.array([0.0, 0.0]), np.zeros(2)
QG = np.array([1.0, -0.5])


def goals_at(dx: float, moving: bool = False) -> Goals:
    p = link_poses(MODEL, QG)["tool"][:3, 3] + np.array([dx, 0.0, 0.0])
    if moving:
        res = FrameResidual(MODEL, "tool", p - [0.1, 0.0, 0.0], velocity=np.array([0.2, 0.0, 0.0]),
                            acceleration=np.zeros(3), match_velocity=True)
        return Goals(final=res, q1_guess=inverse_kinematics(res, QG, 0.5), dq1_guess=Z)
    res = FrameResidual(MODEL, "tool", p)
    return Goals(final=res, q1_guess=inverse_kinematics(res, QG, 1.0))


@pytest.mark.parametrize("dx", [0.0, 0.002, 0.01, 0.03])
def test_fixed_time_replan_meets_the_cold_optimum(dx):
    """No Newton step for an unchanged goal, ≤ 4 for a move of up to 3 cm; the reported gradient is the
    Lagrangian's (∇J + Dᵀλ), far below the cost's own."""
    mesh = HermiteMesh("quintic", 1.0, 8)
    previous = plan_goals(SYSTEM, mesh, Q0, Z, goals_at(0.0))
    warm = replan(SYSTEM, previous, goals_at(dx), fallback=False)
    cold = plan_goals(SYSTEM, mesh, Q0, Z, goals_at(dx))
    assert warm.converged and not warm.fallback
    assert (warm.steps == 0) if dx == 0.0 else (0 < warm.steps <= 4)
    problem = warm.plan.problem
    cost_gradient = problem.evaluate(problem.layout.pack(warm.plan.coeffs)).grad
    assert 0 < warm.plan.optimizer.grad_norm <= 1e-6 * np.max(np.abs(cost_gradient))
    assert warm.plan.J == pytest.approx(cold.J, rel=1e-8)
    p = link_poses(MODEL, warm.plan.coeffs[-1, 0])["tool"][:3, 3]
    assert np.max(np.abs(p - goals_at(dx).final.position)) <= 1e-9


def test_free_time_replan_converges_in_a_few_steps_to_the_free_time_optimum():
    """A link goal with a free T (weight 0: with gravity J*(T) has an interior minimum, T ≈ 0.93): from the
    free-T optimum, the target moved by 2 cm and by −3 cm. The replan takes ≤ 4 Newton steps, makes
    F'(T) = dJ*/dT vanish, has the J of a cold fixed-T solve at its T (1e-8), meets the goal to
    1e-9, and fixed-T plans at T ± 1 % cost no less."""
    span = TimeRange(0.5, 2.0, weight=0.0)
    previous = plan_goals(SYSTEM, HermiteMesh("quintic", 1.0, 8), Q0, Z, goals_at(0.0))
    first = replan(SYSTEM, previous, goals_at(0.0), free=span, fallback=False)
    assert first.converged and 0.8 < first.T < 1.0
    assert replan(SYSTEM, first, goals_at(0.0), free=span, fallback=False).steps == 0
    for dx in (0.02, -0.03):
        moved = goals_at(dx)
        warm = replan(SYSTEM, first, moved, free=span, fallback=False)
        assert warm.converged and not warm.fallback and warm.steps <= 4
        assert abs(warm.dJ_dT) <= 1e-7 * abs(warm.plan.J) / warm.T
        T = warm.T
        cold = plan_goals(SYSTEM, HermiteMesh("quintic", T, 8), Q0, Z, moved)
        assert warm.plan.J == pytest.approx(cold.J, rel=1e-8)
        p = link_poses(MODEL, warm.plan.coeffs[-1, 0])["tool"][:3, 3]
        assert np.max(np.abs(p - moved.final.position)) <= 1e-9
        for factor in (0.99, 1.01):
            other = plan_goals(SYSTEM, HermiteMesh("quintic", T * factor, 8), Q0, Z, moved)
            assert other.converged
            assert other.J >= warm.plan.J


def test_free_time_replan_of_a_moving_target_is_a_free_time_optimum():
    """From the free-T optimum of a moving target (``minimize_time_sqp``: a plan at the guess, then Newton steps
    in x and T; against the search in tests/test_replan_limits.py), after the target moves, the replan's T
    makes F'(T) = dJ*/dT + weight vanish, the link meets the target in position and velocity at T to 1e-9, and
    fixed-T plans at T ± 2 % cost no less."""
    span = TimeRange(0.3, 1.5, weight=1.0)
    solver = goal_solver(SYSTEM, "quintic", 8, Q0, Z, goals_at(0.0, moving=True))
    previous = minimize_time_sqp(solver, SYSTEM, goals_at(0.0, moving=True), span.min, span.max, guess=0.6,
                                 weight=span.weight)
    assert previous.converged and previous.bound is None and curvature_of(previous) > 0
    same = replan(SYSTEM, previous, goals_at(0.0, moving=True), free=span, fallback=False)
    assert same.steps == 0 and same.converged  # from its own optimum: converged at once
    moved = goals_at(0.003, moving=True)
    warm = replan(SYSTEM, previous, moved, free=span, fallback=False, max_steps=100)
    assert warm.converged and not warm.fallback
    assert abs(warm.dJ_dT + span.weight) <= 1e-7 * (abs(warm.plan.J) / warm.T + span.weight)
    C, T = warm.plan.coeffs, warm.T
    p, v = moved.final.target(T)
    assert np.max(np.abs(link_poses(MODEL, C[-1, 0])["tool"][:3, 3] - p)) <= 1e-9
    assert np.max(np.abs(link_velocity(MODEL, C[-1, 0], C[-1, 1], "tool")[:3] - v)) <= 1e-9
    for factor in (0.98, 1.02):
        other = plan_goals(SYSTEM, HermiteMesh("quintic", T * factor, 8), Q0, Z, moved,
                           C_init=rescale(C, T, T * factor), terms=dataclasses.replace(warm.plan.terms, rho=0.0))
        assert other.converged
        assert other.J + span.weight * T * factor >= warm.plan.J + span.weight * T
