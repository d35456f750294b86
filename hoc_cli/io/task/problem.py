"""A task file read into one ``OptimalControlProblem`` (``hoc_cli.ocp``) and its ``JointLimits``.

``hoc plan`` and ``hoc batch`` both build their problem here and hand it to ``hoc_cli.solve``. Errors
(an unknown link, a link goal on a link no task joint moves, a limit on a joint that is not a task joint,
a jerk limit on cubic elements) are
``TaskError``s naming the task file and the key.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from hoc_cli.constraints.bounds import JointLimits
from hoc_cli.dynamics import frame_jacobian, link_poses
from hoc_cli.errors import TaskError
from hoc_cli.io.task.checks import Checker
from hoc_cli.io.task.document import Task
from hoc_cli.io.task.goals import LinkGoal
from hoc_cli.io.task.resolve import ResolvedStates, joint_vector
from hoc_cli.io.task.vias import VALUE_TOL
from hoc_cli.ocp.problem import Fixed, Free, OptimalControlProblem
from hoc_cli.system import RobotSystem

if TYPE_CHECKING:
    from hoc_cli.goals.residuals import FrameResidual
    from hoc_cli.goals.terms import GoalPoint


def task_limits(model, overrides) -> JointLimits:
    """The URDF's limits with the task's per-joint overrides and scale factors applied.

    ``overrides`` is the ``LimitOverrides`` of ``resolve`` (arrays in model joint order, NaN where
    the task gives nothing), or None.
    """
    limits = JointLimits.from_model(model)
    if overrides is None:
        return limits
    joints = model.joint_names
    named = {
        "position": {j: (overrides.lower[i], overrides.upper[i]) for i, j in enumerate(joints)
                     if np.isfinite(overrides.lower[i])},
        **{kind: {j: getattr(overrides, kind)[i] for i, j in enumerate(joints) if np.isfinite(getattr(overrides, kind)[i])}
           for kind in ("velocity", "acceleration", "jerk", "effort")},
    }
    scale = {k: getattr(overrides.scale, k) for k in ("velocity", "acceleration", "jerk", "effort")}
    return limits.with_overrides(scale=scale, **named)


def check_jerk_order(task: Task, limits: JointLimits, order: str) -> None:
    """Jerk limits need quintic elements (TaskError, exit 2): a cubic plan's q̈ jumps at every node."""
    if order != "quintic" and limits.has("jerk").any():
        name = limits.joints[int(np.flatnonzero(limits.has("jerk"))[0])]
        raise TaskError(f"a jerk limit needs order: quintic (a cubic plan's acceleration jumps at every node, "
                        f"so its jerk is unbounded there; the order is {order})", file=task.path,
                        key=f"limits.jerk.{name}")


def frame_goal(task: Task, model, link: str, key: str, position, orientation, target=None,
               match: bool = False) -> FrameResidual:
    """A link's pose (or a moving target) as a ``FrameResidual``; TaskError naming ``key`` for an unknown link."""
    if link not in model.link_names:
        raise TaskError(f"unknown link {link[:60]!r} (links: {', '.join(model.link_names)})", file=task.path, key=key)
    if model.link_body[model.link_names.index(link)] < 0:  # carried by the fixed base: no task joint moves it
        locked = f"; locked joints: {', '.join(model.locked)}" if model.locked else ""
        raise TaskError(f"link {link[:60]!r} is not moved by any task joint (its pose depends on none of "
                        f"{', '.join(model.joint_names)}{locked}); expected a link downstream of a task joint",
                        file=task.path, key=key)
    from hoc_cli.goals.residuals import FrameResidual, quaternion_matrix  # the goal modules load with a goal

    R = None if orientation is None else quaternion_matrix(orientation)
    _check_moved(task, model, link, key, None if target is not None else position, R)
    if target is not None:
        return FrameResidual(model, link, np.array(target.position), R, np.array(target.velocity),
                             np.array(target.acceleration), match_velocity=match)
    return FrameResidual(model, link, np.array(position, float), R)


FIXED_SAMPLES = 3  # random configurations at which a link's position (orientation) must not move to be fixed


def _check_moved(task: Task, model, link: str, key: str, position, R) -> None:
    """TaskError when the goal's position (or orientation) of ``link`` is one the task joints cannot change
    (its Jacobian rows vanish at ``FIXED_SAMPLES`` random configurations, e.g. the origin of the link that
    the only task joint turns about) and the goal asks for another one.
    """
    rng = np.random.default_rng(0)
    lo = np.where(np.isfinite(model.lower), model.lower, -np.pi)
    hi = np.where(np.isfinite(model.upper), model.upper, np.pi)
    q = rng.uniform(lo, hi, (FIXED_SAMPLES, len(model.joint_names)))
    J = frame_jacobian(model, q, link)
    pose = link_poses(model, q[0])[link]
    scale = 1.0 + float(np.max(np.abs(pose[:3, 3])))
    if position is not None and np.max(np.abs(J[:, :3])) <= 1e-12 * scale:
        p = pose[:3, 3]
        if np.max(np.abs(p - np.asarray(position, float))) > VALUE_TOL * scale:
            raise TaskError(f"the position of link {link[:60]!r} is not moved by any task joint "
                            f"({', '.join(model.joint_names)}): it stays at {[round(float(v), 9) for v in p]} m "
                            "(expected that position, or a link whose position the task joints move)",
                            file=task.path, key=key.removesuffix(".link") + ".position")
    if R is not None and np.max(np.abs(J[:, 3:])) <= 1e-12:
        from hoc_cli.goals.residuals import rotation_angle

        angle = rotation_angle(pose[:3, :3], R)
        if angle > VALUE_TOL:
            raise TaskError(f"the orientation of link {link[:60]!r} is not turned by any task joint "
                            f"({', '.join(model.joint_names)}): the goal is {angle:.6g} rad from it (expected "
                            "that orientation, or a link the task joints turn)", file=task.path,
                            key=key.removesuffix(".link") + ".orientation")


def task_vias(task: Task, model) -> tuple[GoalPoint, ...]:
    """The task's vias as goal rows at fractions s of T (``t`` gives s = t/T of the task's T)."""
    if not task.via:
        return ()
    from hoc_cli.goals.residuals import JointResidual  # the goal modules load with a via (start-up)
    from hoc_cli.goals.terms import GoalPoint

    c = Checker(task.path)
    joints = tuple(model.joint_names)
    vias = []
    for i, v in enumerate(task.via):
        s = v.s if v.s is not None else v.t / task.T
        if v.q is not None:
            dq = joint_vector(c, v.dq, f"via[{i}].dq", joints)
            vias.append(GoalPoint(s, JointResidual(joint_vector(c, v.q, f"via[{i}].q", joints), dq), f"via[{i}]"))
        else:
            vias.append(GoalPoint(s, frame_goal(task, model, v.link, f"via[{i}].link", v.position, v.orientation),
                                  f"via[{i}]"))
    check_same_instant(task, model, vias)
    return tuple(vias)


def check_same_instant(task: Task, model, vias: list[GoalPoint]) -> None:
    """TaskError when a joint via and a link via name the same instant (``NODE_TOL`` of T apart) and the link's
    pose at the joint via's q is not the link via's (the joint-only pairs: ``hoc_cli.io.task.vias``).
    """
    from hoc_cli.goals.mesh import NODE_TOL
    from hoc_cli.goals.residuals import FrameResidual, JointResidual, rotation_angle

    for a in vias:
        if not isinstance(a.residual, JointResidual):
            continue
        for b in vias:
            if not isinstance(b.residual, FrameResidual) or abs(a.s - b.s) > NODE_TOL:
                continue
            res = b.residual
            P = link_poses(model, a.residual.q)[res.link]
            p = res.target(b.s * task.T)[0]
            tol = VALUE_TOL * max(1.0, float(np.max(np.abs(p))))
            gap = float(np.max(np.abs(P[:3, 3] - p)))
            what = f"{res.link} at {[round(float(v), 9) for v in P[:3, 3]]} m, not {[float(v) for v in p]}"
            if gap <= tol and res.orientation is not None:
                gap = rotation_angle(P[:3, :3], res.orientation)
                what = f"{res.link}'s orientation {gap:.3g} rad from the link via's"
            if gap > tol:
                first, second = sorted((a.label, b.label), key=lambda k: int(k[4:-1]))
                raise TaskError(f"{first} and {second} name the same instant and disagree: the joint via's q puts "
                                f"{what} (expected one pose per instant, or times more than {NODE_TOL:g}·T apart)",
                                file=task.path, key=second)


def problem_from_task(task: Task, model, states: ResolvedStates, limits: JointLimits | None) -> OptimalControlProblem:
    """The task as an ``OptimalControlProblem``; ``limits``: enforced limits (``task_limits``), None in
    report mode. The mesh size N is the task's (None: ``N: auto``).
    """
    free = task.time.free
    if (isinstance(task.x1, LinkGoal) or task.via or free is not None) and task.N is None:
        raise TaskError("goals (a link goal, vias or a free T) need a fixed number of elements "
                        "(expected an integer N >= 1, not auto)", file=task.path, key="N")
    time = Fixed(task.T) if free is None else Free(free.min, free.max, free.weight, free.guess)
    link_goal = None
    final_dq = "zero"
    if isinstance(task.x1, LinkGoal):
        g = task.x1
        link_goal = frame_goal(task, model, g.link, "x1.link", g.position, g.orientation, g.target, g.match_velocity)
        final_dq = g.dq
    return OptimalControlProblem(RobotSystem(model), q0=states.q0, dq0=states.dq0, q1=states.q1, dq1=states.dq1,
                                 time=time, N=task.N, order=task.order, cost=task.cost, limits=limits,
                                 link_goal=link_goal, final_dq=final_dq, vias=task_vias(task, model),
                                 accuracy=task.accuracy)


def task_goals(task: Task, model, states: ResolvedStates):
    """The task's goal rows (``hoc_cli.goals.Goals``), or None for a joint goal in a fixed T."""
    return problem_from_task(task, model, states, None).goals()
