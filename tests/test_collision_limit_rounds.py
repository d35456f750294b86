"""The joint limits' rounds inside the collision loop (``collision.limit_rounds``): the limits' own term
(``LimitTerm``) driven by ``auglag``'s steps, its state carried from one outer iteration to the next.

A rest-to-rest move of a free mass (LinearOscillator, ω = 0) whose unconstrained optimum breaks a
velocity bound (docs/limits.md derives its continuous optimum); the rounds run with no collision rows,
as the collision loop runs them, one call per outer iteration.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from hoc_cli.collision.limit_rounds import LimitState
from hoc_cli.constraints import JointLimits
from hoc_cli.constraints.bounds import KINDS
from hoc_cli.elements import HermiteMesh
from hoc_cli.optimize import cg
from hoc_cli.optimize.result import Status
from hoc_cli.planner import plan
from hoc_cli.problem import ControlProblem
from hoc_cli.system import LinearOscillator
from tests.test_limits_enforce import velocity_limited_optimum

D, T, V = 1.0, 1.0, 1.3  # the unconstrained optimum peaks at 1.5 rad/s


def _move():
    system = LinearOscillator(1, omega=0.0)
    limits = JointLimits.from_arrays(system.joint_names, velocity=[V])
    mesh = HermiteMesh("quintic", T, 16)
    return system, limits, mesh, ControlProblem(system, mesh, [0.0], [0.0], [D], [0.0])


def newton_solve(p, x: np.ndarray, tol: float):
    """The inner solve as the planner makes it on a penalised problem: line-searched Newton steps."""
    def f(v):
        ev = p.evaluate(v)
        return ev.J, ev.grad, ev
    return cg.minimize(f, x, precondition=p.newton, method="newton", c2=0.9, tol=tol, noise=lambda ev: ev.noise)


def test_the_rounds_with_their_state_carried_reach_the_plan_of_the_limits_own_loop():
    system, limits, mesh, problem = _move()
    own = plan(system, mesh, [0.0], [0.0], [D], [0.0], limits=limits)
    assert own.converged and own.limits.status == "converged"
    lim = LimitState(system, limits, None, problem)
    x = problem.initial_guess()
    res, x, met = lim.rounds(problem, x, 1e-10, newton_solve, exact=True)  # the first outer iteration
    rho = lim.rho
    res, x, met = lim.rounds(problem, x, 1e-10, newton_solve, exact=True)  # the next, from its λ, ρ, working set
    assert met and res.converged and res.iterations == 0  # the carried multipliers hold the plan where it was
    assert lim.rho == rho and lim.working[KINDS.index("velocity")].all()
    J = problem.bare_cost(x)
    assert abs(J - own.J) <= 1e-9 * own.J
    assert J > velocity_limited_optimum(D, T, V)  # feasible for the continuous problem: not below its optimum
    C = problem.coefficients(x)
    assert np.max(np.abs(mesh.evaluate(C, np.linspace(0.0, T, 2001))[1])) <= V * (1 + 1e-9)
    result = lim.result(res, x, J, 2)
    assert result.status == "converged" and result.check.violations() == []
    assert [a["kind"] for a in result.active_limits()] == ["velocity"]


def test_the_penalty_does_not_grow_after_an_inner_solve_that_failed():
    """The third round's inner solve fails where it started: the violation did not fall, but a failed solve says
    nothing about ρ (``auglag.update``, as in the limits' own loop); the rounds stop there."""
    system, limits, mesh, problem = _move()
    calls, rho = [], []

    def failing(p, x, tol):
        res = newton_solve(p, x, tol)
        calls.append(res)
        if len(calls) == 3:
            rho.append(lim.rho)  # after the second round's update
            return dataclasses.replace(res, x=x, status=Status.LINE_SEARCH_FAILED)
        return res

    lim = LimitState(system, limits, None, problem)
    res, x, met = lim.rounds(problem, problem.initial_guess(), 1e-10, failing, exact=True)
    assert len(calls) == 3 and not met and not res.converged
    assert rho[0] is not None and lim.rho == rho[0]
