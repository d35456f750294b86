"""The fixed-T solve of a task with goals, as ``hoc_cli.free_time.minimize_time`` and the free-T
SQP (``hoc_cli.goals.free_time_sqp``) call it: ``solve(T, nearest) -> TimePoint``.

It sits in ``goals/`` because it solves goal problems; ``free_time`` (the search over T) knows
nothing of goals and takes any such ``solve``.
"""
from __future__ import annotations

import dataclasses

from hoc_cli.free_time import TimePoint, constraint_start, plan_time_derivative, rescale
from hoc_cli.goals.mesh import scaled_mesh
from hoc_cli.goals.plan import plan_goals
from hoc_cli.goals.warm import initial_plan


class GoalSolver:
    """``solve(T, nearest)`` for ``minimize_time`` with goals (``hoc_cli.goals.plan_goals``) on N elements,
    equal or with nodes at ``fractions`` (N + 1,) of T (``hoc_cli.goals.mesh``: the vias stay nodes).

    Warm-started from ``nearest`` rescaled to T, with its multipliers (with a constraint, its loop's and the
    limits' too: ``hoc_cli.free_time.constraint_start``; the first solve coarse to fine from the initial guess):
    solves from scratch at distant T may land in other local minima, and J*(T) would jump. The penalty restarts
    from its default (carrying one grown at another T was measured 2-3× slower on the lbr7 catch). ``initial(T)``: the initial trajectory at T as a plan with
    zero multipliers (``hoc_cli.goals.warm.initial_plan``), the start of Newton steps from scratch.
    """

    def __init__(self, system, order: str, N: int, q0, dq0, goals, *, limits=None, fractions=None,
                 **plan_options) -> None:
        self.system, self.order, self.N, self.q0, self.dq0, self.goals = system, order, N, q0, dq0, goals
        self.limits, self.fractions, self.plan_options = limits, fractions, plan_options

    def mesh(self, T: float):
        return scaled_mesh(self.order, T, self.N, self.fractions)

    def __call__(self, T: float, nearest: TimePoint | None) -> TimePoint:
        warm = {}
        if nearest is not None:
            warm = {"C_init": rescale(nearest.result.coeffs, nearest.T, T),
                    "terms": dataclasses.replace(nearest.result.terms, rho=0.0)}
            warm |= constraint_start(nearest.result, T / nearest.T)  # a constraint's and the limits' multipliers
        result = plan_goals(self.system, self.mesh(T), self.q0, self.dq0, self.goals, limits=self.limits, **warm,
                            **self.plan_options)
        d = plan_time_derivative(result, self.system, self.limits,
                                 goals=result.terms if result.problem.points else None)
        return TimePoint(T=T, J=result.J, dJ_dT=d, result=result)

    def initial(self, T: float):
        """The initial trajectory on the mesh at T as a ``GoalResult`` with zero multipliers."""
        return initial_plan(self.system, self.mesh(T), self.q0, self.dq0, self.goals,
                            cost=self.plan_options.get("cost", "covariant"), G=self.plan_options.get("G"))


def goal_solver(system, order: str, N: int, q0, dq0, goals, *, limits=None, fractions=None,
                **plan_options) -> GoalSolver:
    """``solve(T, nearest)`` for ``minimize_time`` with goals: a ``GoalSolver``."""
    return GoalSolver(system, order, N, q0, dq0, goals, limits=limits, fractions=fractions, **plan_options)
