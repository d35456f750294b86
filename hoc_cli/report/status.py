"""How a plan ended: the one status enum of ``hoc plan --json``, ``hoc batch``'s rows and each start, and its words.

Every solver reports its own outcome (``hoc_cli.optimize.Status``, the limit and collision loops'
``status`` strings, a start's); the summary's ``status`` key is always one value of ``Status``
(``Status.of`` maps them and refuses any other). ``MESSAGES`` holds the words both reporters use:
``hoc plan``'s exit-1 line (``hoc: <word>: <message>; <kept> was written``) and ``hoc batch``'s counts.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass


class Status(str, enum.Enum):
    """The ``status`` of a plan, as written in the JSON summary and the batch results (the value)."""

    CONVERGED = "converged"  # every stopping test held (and the limits, collision and goals too)
    MAX_ITER = "max_iter"  # the iteration limit came first
    LINE_SEARCH_FAILED = "line_search_failed"  # no step made progress
    NOT_FINITE = "not_finite"  # the cost or gradient became NaN or infinite
    NOT_CONVERGED = "not_converged"  # an outer loop (limits, collision) stopped before its tests held
    INFEASIBLE = "infeasible"  # no trajectory within the limits (or clear of collisions) was found or can exist
    GOAL_MISSED = "goal_missed"  # the solver's tests held but a goal is not met (``hoc_cli.report.goals.goal_miss``)
    ERROR = "error"  # no plan: the task was refused or the solve failed (a batch row, a start)

    @classmethod
    def of(cls, value) -> Status:
        """The status of a solver's outcome: an enum whose value is a status (``hoc_cli.optimize.Status``)
        or the string itself; ValueError for anything that is not one of ``Status``.
        """
        return cls(getattr(value, "value", value))


@dataclass(frozen=True)
class StatusText:
    """The words of a status: ``word`` heads ``hoc plan``'s exit-1 line, ``kept`` names what of the plan
    is written, ``counted`` labels the status in ``hoc batch``'s closing counts.
    """

    word: str
    kept: str
    counted: str


_UNMET = StatusText("not converged", "the best iterate", "not converged")

MESSAGES: dict[Status, StatusText] = {
    Status.CONVERGED: StatusText("converged", "the plan", "converged"),
    Status.MAX_ITER: _UNMET,
    Status.LINE_SEARCH_FAILED: _UNMET,
    Status.NOT_FINITE: _UNMET,
    Status.NOT_CONVERGED: _UNMET,
    Status.GOAL_MISSED: _UNMET,
    Status.INFEASIBLE: StatusText("infeasible", "the least-violating plan", "not converged"),
    Status.ERROR: StatusText("error", "no plan", "errors"),
}


def unmet_line(status: Status, message: str, written: str) -> str:
    """``hoc plan``'s line for a plan that did not meet what was asked: ``hoc: <word>: <message>; <kept> <written>``
    (``written``: "was written" or "was not written (-o none)"). A plan whose solver converged but whose
    constraint loop did not (status ``converged``, ``converged: false``) is "not converged".
    """
    text = MESSAGES[Status.NOT_CONVERGED if status is Status.CONVERGED else status]
    return f"hoc: {text.word}: {message}; {text.kept} {written}"
