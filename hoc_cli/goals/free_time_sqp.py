"""A free final time by Newton (SQP) steps in (x, T) together, from one fixed-T solve at the guess.

``hoc_cli.free_time.minimize_time`` finds the optimal T by a one-dimensional search over fixed-T solves
(each a full solve with its goal and limit loops: 7 solves and ~50 s for the lbr7 catch). Here the
problem at the guess T is solved once, and the warm replan's SQP steps (``hoc_cli.goals.replan``: x, T
and the multipliers together, the limits as inequality rows of each step's QP) move T to where
F'(T) = dJ*/dT + weight vanishes or a bound holds it: the same first-order conditions as the search's
end, at the cost of one solve and some tens of Newton steps (the catch: 5 s). When the steps do not
converge the search runs as before, seeded with the solve at the guess. Pure maths: no I/O.
"""
from __future__ import annotations

import math
from collections.abc import Callable

from hoc_cli.free_time import FreeTimeResult, TimePoint, minimize_time
from hoc_cli.goals.replan import TimeRange, replan

MAX_STEPS = 60  # Newton steps before the search takes over


def minimize_time_sqp(solve: Callable[[float, TimePoint | None], TimePoint], system, goals, T_min: float,
                      T_max: float, *, guess: float | None = None, weight: float = 0.0, limits=None,
                      max_steps: int = MAX_STEPS) -> FreeTimeResult:
    """The free-T optimum (module docstring); ``solve`` as ``minimize_time``'s (``goal_solver``), whose results are
    ``GoalResult`` on uniform meshes; ``goals``: the ``Goals``; ``limits``: the enforced ``JointLimits`` or None.
    """
    guess = math.sqrt(T_min * T_max) if guess is None else min(max(guess, T_min), T_max)
    first = solve(guess, None)
    if getattr(first.result, "converged", False):
        r = replan(system, first.result, goals, free=TimeRange(T_min, T_max, weight), limits=limits,
                   fallback=False, max_steps=max_steps)
        if r.converged:
            J = r.plan.J
            point = TimePoint(T=r.T, J=J, dJ_dT=r.dJ_dT, result=r.plan)
            bound = "min" if r.T <= T_min and r.dJ_dT + weight > 0 else "max" if r.T >= T_max and r.dJ_dT + weight < 0 else None
            return FreeTimeResult(T=r.T, J=J, dJ_dT=r.dJ_dT, objective=J + weight * r.T, weight=weight, bound=bound,
                                  point=point, history=[first, point], converged=True)

    def seeded(T: float, nearest: TimePoint | None) -> TimePoint:
        return first if T == first.T else solve(T, nearest)

    return minimize_time(seeded, T_min, T_max, guess=guess, weight=weight)
