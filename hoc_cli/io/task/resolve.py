"""Joint-indexed task values (lists in task joint order, or name → value mappings) as arrays in a model's
joint order.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hoc_cli.io.task.checks import Checker, Values, join, show
from hoc_cli.io.task.document import Task
from hoc_cli.io.task.goals import LinkGoal
from hoc_cli.io.task.limits import LimitOverrides, resolve_limits
from hoc_cli.io.task.vias import ResolvedVia, check_vias


@dataclass(frozen=True, eq=False)
class ResolvedStates:
    """x0, x1 (and a constant torque) as arrays in the model's joint order; shapes (n,).

    ``limits`` holds the task's limit overrides in the same order (NaN where none is given); ``vias``
    the task's vias with their time as a fraction of T and their joint values (None for a link via).
    """

    q0: np.ndarray
    dq0: np.ndarray
    q1: np.ndarray | None
    dq1: np.ndarray | None
    torque: np.ndarray | None
    limits: LimitOverrides | None = None
    vias: tuple[ResolvedVia, ...] = ()


def joint_vector(c: Checker, values: Values | None, key: str, joints: tuple[str, ...]) -> np.ndarray | None:
    n = len(joints)
    if values is None:
        return None
    if isinstance(values, dict):
        for name in values:
            if name not in joints:
                raise c.error(join(key, name), f"unknown joint {show(name)} (task joints: {', '.join(joints)})")
        missing = [j for j in joints if j not in values]
        if missing:
            raise c.error(key, f"missing value for joint(s) {', '.join(missing)}")
        return np.array([values[j] for j in joints], dtype=float)
    if len(values) != n:
        raise c.error(key, f"expected {n} values (one per joint: {', '.join(joints)}), got {len(values)}")
    return np.asarray(values, dtype=float)


def resolve(task: Task, joints: tuple[str, ...] | list[str]) -> ResolvedStates:
    """Map the task's states, torque and limit overrides to arrays in the given joint order.

    Raises
    ------
    TaskError
        A joint name that is not in ``joints``, a missing joint, a list of the wrong length, or vias
        that contradict each other or the boundary (``hoc_cli.io.task.vias``).
    """
    joints = tuple(joints)
    c = Checker(task.path)
    zeros = np.zeros(len(joints))
    q0 = joint_vector(c, task.x0.q, "x0.q", joints)
    dq0 = joint_vector(c, task.x0.dq, "x0.dq", joints)
    q1 = dq1 = None
    if task.x1 is not None and not isinstance(task.x1, LinkGoal):  # a link goal leaves the final state free
        q1 = joint_vector(c, task.x1.q, "x1.q", joints)
        dq1 = joint_vector(c, task.x1.dq, "x1.dq", joints)
        dq1 = zeros.copy() if dq1 is None else dq1
    torque = None
    if task.torque == "zero":
        torque = zeros.copy()
    elif task.torque is not None:
        torque = joint_vector(c, task.torque, "torque", joints)  # type: ignore[arg-type]
    limits = resolve_limits(c, task.limits, joints, task.locked)
    dq0 = zeros.copy() if dq0 is None else dq0
    vias = tuple(ResolvedVia(i, v.s if v.s is not None else v.t / task.T, joint_vector(c, v.q, f"via[{i}].q", joints),
                             joint_vector(c, v.dq, f"via[{i}].dq", joints)) for i, v in enumerate(task.via))
    check_vias(c, task, list(vias), joints, q0, dq0, q1, dq1)
    return ResolvedStates(q0=q0, dq0=dq0, q1=q1, dq1=dq1, torque=torque, limits=limits, vias=vias)
