"""Goals of an ``OptimalControlProblem`` from Python: a link's pose at T, and vias.

Positions are in the URDF root frame [m], orientations unit quaternions (w, x, y, z) as in the task
file, a moving target's velocity [m/s] and acceleration [m/s²] at t = 0 (p̄(t) = p0 + v0 t + ½ a t²).
A via is placed at a fraction s ∈ (0, 1) of the duration (with a fixed T, ``t`` [s] gives s = t/T).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # the goal modules load when a goal is built (``import hoc_cli.ocp`` stays light)
    from hoc_cli.goals.residuals import FrameResidual
    from hoc_cli.goals.terms import GoalPoint


def _vector(values, size: int, what: str) -> np.ndarray:
    a = np.array(values, dtype=float).reshape(-1)
    if a.shape != (size,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{what} must be {size} finite numbers, got {values!r}")
    return a


def link_goal(system, link: str, position, orientation=None, *, velocity=None, acceleration=None,
              match_velocity: bool = False) -> FrameResidual:
    """The pose of ``link`` at T: ``position`` (3,) [m], optional ``orientation`` (w, x, y, z); a moving
    target with ``velocity``/``acceleration`` (3,) and ``match_velocity`` (the link moves with it at T).
    """
    from hoc_cli.goals.residuals import FrameResidual, quaternion_matrix

    model = system.model
    if link not in model.link_names:
        raise ValueError(f"unknown link {link!r} (links: {', '.join(model.link_names)})")
    R = None if orientation is None else quaternion_matrix(_vector(orientation, 4, "orientation"))
    v = None if velocity is None else _vector(velocity, 3, "velocity")
    a = None if acceleration is None else _vector(acceleration, 3, "acceleration")
    return FrameResidual(model, link, _vector(position, 3, "position"), R, v, a, match_velocity=match_velocity)


def _fraction(s: float | None, t: float | None, T: float | None) -> float:
    if (s is None) == (t is None):
        raise ValueError("give a via's place as exactly one of s (a fraction of T) or t [s] with T")
    if t is not None:
        if T is None:
            raise ValueError("a via at t [s] needs the fixed duration T (or give s)")
        s = t / T
    if not 0.0 < s < 1.0:
        raise ValueError(f"a via lies strictly inside the move: 0 < s < 1, got s = {s!r}")
    return float(s)


def joint_via(q, dq=None, *, s: float | None = None, t: float | None = None, T: float | None = None,
              label: str = "via") -> GoalPoint:
    """A joint state to pass: q (n,) [rad or m] and optionally q̇ (n,) at s·T (or at t [s] of a fixed T)."""
    from hoc_cli.goals.residuals import JointResidual
    from hoc_cli.goals.terms import GoalPoint

    q = np.array(q, dtype=float).reshape(-1)
    dq = None if dq is None else _vector(dq, q.size, "dq")
    return GoalPoint(_fraction(s, t, T), JointResidual(_vector(q, q.size, "q"), dq), label)


def link_via(system, link: str, position, orientation=None, *, s: float | None = None, t: float | None = None,
             T: float | None = None, label: str = "via") -> GoalPoint:
    """A link pose to pass at s·T (or at t [s] of a fixed T): ``position`` (3,) [m], optional (w, x, y, z)."""
    from hoc_cli.goals.terms import GoalPoint

    return GoalPoint(_fraction(s, t, T), link_goal(system, link, position, orientation), label)
