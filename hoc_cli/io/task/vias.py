"""Vias that contradict each other or the boundary, refused before any solve (``TaskError``, exit 2).

The plan's mesh has a node at each via time and merges times closer than ``NODE_TOL`` of T
(``hoc_cli.goals.mesh``): such vias name the same instant. Refused here:

- two joint vias at the same instant whose q (or dq, where both give it) differ;
- two link vias of the same link at the same instant whose position or orientation differ;
- a via at the same instant as t = 0 or t = T (``t: 1.0e-12``): the boundary already fixes that
  instant; a joint via there that differs from x0 (or from a joint goal x1) is named as the contradiction.

What needs the robot's kinematics (a joint via and a link via at the same instant) is checked where
the model is known (``hoc_cli.report.goals``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hoc_cli.io.task.checks import Checker

#: joint values (rad or m, rad/s or m/s) and link positions (m) differing by more than this are different
VALUE_TOL = 1e-9


@dataclass(frozen=True, eq=False)
class ResolvedVia:
    """A via with its time as a fraction ``s`` of T and its joint values in model order (shapes (n,))."""

    index: int
    s: float
    q: np.ndarray | None
    dq: np.ndarray | None

    @property
    def key(self) -> str:
        return f"via[{self.index}]"


def _when(v, T: float | None) -> str:
    return f"s = {v.s:.12g}" if T is None else f"t = {v.s * T:.12g} s"


def _differs(a: np.ndarray, b: np.ndarray, joints: tuple[str, ...]) -> str | None:
    """The first joint where a and b differ by more than ``VALUE_TOL`` (relative to their size), as text."""
    gap = np.abs(a - b)
    bad = np.flatnonzero(gap > VALUE_TOL * np.maximum(1.0, np.maximum(np.abs(a), np.abs(b))))
    if bad.size == 0:
        return None
    i = int(bad[np.argmax(gap[bad])])
    return f"{joints[i]} {float(a[i]):.9g} vs {float(b[i]):.9g}"


def _joint_clash(a: ResolvedVia, b_q, b_dq, joints) -> str | None:
    if a.q is not None and b_q is not None:
        d = _differs(a.q, b_q, joints)
        if d:
            return f"different q ({d})"
    if a.dq is not None and b_dq is not None:
        d = _differs(a.dq, b_dq, joints)
        if d:
            return f"different dq ({d})"
    return None


def check_vias(c: Checker, task, vias: list[ResolvedVia], joints: tuple[str, ...], q0: np.ndarray,
               dq0: np.ndarray, q1: np.ndarray | None, dq1: np.ndarray | None) -> None:
    """TaskError for vias that name the same instant with different values, or the instant of x0 or x1.

    ``task`` gives the link vias (``task.via``) and T (None when T is free: times as fractions).
    """
    if not vias:
        return
    from hoc_cli.goals.mesh import NODE_TOL  # hoc_cli.goals loads only for a task with goals (start-up)

    T = None if task.time.free is not None else task.T
    for v in vias:
        spec = task.via[v.index]
        for s_end, end, eq, edq in ((0.0, "x0", q0, dq0), (1.0, "x1", q1, dq1)):
            if abs(v.s - s_end) > NODE_TOL:
                continue
            at = "t = 0" if s_end == 0.0 else "t = T"
            clash = None if spec.link is not None else _joint_clash(v, eq, edq, joints)
            if clash:
                raise c.error(v.key, f"at {_when(v, T)}, the instant of {end} ({at}), with {clash} from {end} "
                              f"(expected a via strictly between 0 and T, or one that agrees with {end})")
            raise c.error(v.key, f"at {_when(v, T)} is the instant of {end} ({at}), which {end} already fixes "
                          f"(expected a via time more than {NODE_TOL:g}·T from 0 and from T)")
    ordered = sorted(vias, key=lambda v: v.s)
    for a, b in zip(ordered, ordered[1:]):
        if b.s - a.s > NODE_TOL:
            continue
        sa, sb = task.via[a.index], task.via[b.index]
        clash = None
        if sa.link is None and sb.link is None:
            clash = _joint_clash(a, b.q, b.dq, joints)
        elif sa.link is not None and sa.link == sb.link:
            if np.max(np.abs(np.subtract(sa.position, sb.position))) > VALUE_TOL:
                clash = f"different positions of {sa.link} ({list(sa.position)} vs {list(sb.position)} m)"
            elif sa.orientation is not None and sb.orientation is not None and \
                    min(np.max(np.abs(np.subtract(sa.orientation, sb.orientation))),
                        np.max(np.abs(np.add(sa.orientation, sb.orientation)))) > VALUE_TOL:
                clash = f"different orientations of {sa.link}"
        if clash:
            first, second = sorted((a, b), key=lambda v: v.index)
            raise c.error(second.key, f"{first.key} ({_when(first, T)}) and {second.key} ({_when(second, T)}) name "
                          f"the same instant with {clash} (expected one value per instant, or times more than "
                          f"{NODE_TOL:g}·T apart)")
