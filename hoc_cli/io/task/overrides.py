"""CLI overrides of task keys (``-N``, ``--order``, ``-T``, ``--tol``, ``--max-iter``...), validated by the
same key checkers as the task file; an error names the option instead of the key.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from functools import partial
from typing import Any

from hoc_cli.io.task.checks import Check, Checker
from hoc_cli.io.task.collision import check_collision_mode
from hoc_cli.io.task.document import Task
from hoc_cli.io.task.limits import check_limits_mode
from hoc_cli.io.task.sections import (
    check_cost,
    check_max_iter,
    check_method,
    check_N,
    check_order,
    check_samples,
    check_T,
    check_tol,
)


@dataclass(frozen=True)
class Override:
    """A task field a CLI option may replace: the option named in errors, where the field lives, its checker."""

    option: str
    section: str  # the Task attribute holding the section dataclass, or "" for a field of Task itself
    field: str
    check: Check


OVERRIDES: dict[str, Override] = {
    "N": Override("--elements", "time", "N", check_N),
    "order": Override("--order", "time", "order", check_order),
    "T": Override("--duration", "time", "T", partial(check_T, what="a duration > 0 in seconds")),
    "tol": Override("--tol", "solver", "tol", check_tol),
    "max_iter": Override("--max-iter", "solver", "max_iter", check_max_iter),
    "method": Override("--method", "solver", "method", check_method),
    "cost": Override("--cost", "", "cost", check_cost),
    "limits": Override("--limits", "limits", "mode", check_limits_mode),
    "collision": Override("--collision", "collision", "mode", check_collision_mode),
}


def apply_overrides(task: Task, **overrides: Any) -> Task:
    """Return the task with CLI overrides applied and validated (keys of ``OVERRIDES``).

    ``None`` values are ignored. Errors name the option, e.g. ``--elements``.

    Raises
    ------
    TaskError
        An invalid value, or a combination the task checks refuse (too many output samples).
    ValueError
        An override key that is not in ``OVERRIDES`` (a programming error).
    """
    c = Checker(task.path)
    sections: dict[str, dict[str, Any]] = {}
    for key, value in overrides.items():
        if value is None:
            continue
        if key not in OVERRIDES:
            raise ValueError(f"unknown override {key}")
        o = OVERRIDES[key]
        sections.setdefault(o.section, {})[o.field] = o.check(c, value, o.option)
    changes = sections.pop("", {})
    for name, fields in sections.items():
        changes[name] = replace(getattr(task, name), **fields)
    new = replace(task, **changes)
    if overrides.get("T") is not None and new.time.free is not None:  # --duration fixes a free T
        new = replace(new, time=replace(new.time, free=None))
    if overrides.get("T") is not None:
        check_samples(c, new.T, new.rate, OVERRIDES["T"].option)
    return new
