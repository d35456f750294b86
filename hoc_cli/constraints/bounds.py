"""Joint limits as data: per-joint bounds on q, q̇, q̈, the jerk and u, and their resolution from URDF and task.

Symbols
-------
n joints. Every bound is an (n,) array; ±inf means "no limit". Units: rad or m (position),
rad/s or m/s (velocity), rad/s² or m/s² (acceleration), rad/s³ or m/s³ (jerk), N·m or N (effort).

Conventions (see docs/limits.md): a URDF ``<limit>`` gives position (revolute, prismatic),
velocity and effort; a missing, zero or negative velocity or effort means "no limit" for that
kind; continuous joints have no position limit; acceleration and jerk limits come only from the
task. Scaling factors 0 < s <= 1 multiply the velocity, acceleration, jerk and effort limits (as
MoveIt's velocity and acceleration scaling factors do).

The kinds
---------
``KINDS`` lists every kind in a fixed order: the *kinematic* kinds first, in the order of the
derivative of q_h they bound (``DERIVATIVE``: kind k bounds d^k q_h/dt^k, so the index of a
kinematic kind is its derivative order), then effort, the one kind that is not linear in the
coefficients. Every solver loops over ``range(KINEMATIC)`` for the linear (Bernstein) rows and
treats ``EFFORT`` apart; a new kinematic kind is one more entry here (docs/adding-a-constraint.md).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

DERIVATIVE = {"position": 0, "velocity": 1, "acceleration": 2, "jerk": 3}  # kinematic kinds: the derivative of q_h
KINDS: tuple[str, ...] = (*DERIVATIVE, "effort")
KINEMATIC = len(DERIVATIVE)  # kinds 0 … KINEMATIC−1 have linear (Bernstein) rows
EFFORT = KINDS.index("effort")
RATES: tuple[str, ...] = tuple(KINDS[1:])  # the symmetric kinds: velocity, acceleration, jerk, effort
SCALABLE = RATES


def _positive_or_inf(values: np.ndarray) -> np.ndarray:
    v = np.asarray(values, dtype=float).copy()
    v[~(v > 0)] = np.inf  # missing (nan), zero or negative: no limit
    return v


@dataclass(frozen=True, eq=False)
class JointLimits:
    """Bounds per joint (n,) each; ``lower``/``upper`` for q, symmetric ±bound for q̇, q̈, u.

    Attributes
    ----------
    joints : joint names, in the order of the arrays
    lower, upper : position bounds [rad or m], −inf/+inf where none
    velocity, acceleration, effort : symmetric bounds (> 0) [rad/s, rad/s², N·m], +inf where none
    jerk : symmetric bounds (> 0) [rad/s³ or m/s³], +inf where none
    """

    joints: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    effort: np.ndarray
    jerk: np.ndarray | None = None  # None: no jerk limit on any joint (set to +inf in __post_init__)

    def __post_init__(self) -> None:
        if self.jerk is None:
            object.__setattr__(self, "jerk", np.full(len(self.joints), np.inf))

    @classmethod
    def from_arrays(cls, joints, lower=None, upper=None, velocity=None, acceleration=None,
                    effort=None, jerk=None) -> "JointLimits":
        """Limits from arrays (n,) (None: no limit of that kind); non-positive rates mean no limit."""
        n = len(joints)

        def arr(v, fill):
            return np.full(n, fill) if v is None else np.asarray(v, dtype=float).reshape(n).copy()

        lo, hi = arr(lower, -np.inf), arr(upper, np.inf)
        lo[np.isnan(lo)], hi[np.isnan(hi)] = -np.inf, np.inf
        return cls(tuple(joints), lo, hi, _positive_or_inf(arr(velocity, np.inf)),
                   _positive_or_inf(arr(acceleration, np.inf)), _positive_or_inf(arr(effort, np.inf)),
                   _positive_or_inf(arr(jerk, np.inf)))

    @classmethod
    def from_model(cls, model) -> "JointLimits":
        """The URDF's limits of a loaded model (``hoc_cli.model``): position, velocity, effort."""
        return cls.from_arrays(model.joint_names, model.lower, model.upper, model.velocity_limit, None,
                               model.effort_limit)

    @property
    def n(self) -> int:
        return len(self.joints)

    def bounds(self, kind: str) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) bounds (n,) of a kind; symmetric kinds give (−b, b)."""
        if kind == "position":
            return self.lower, self.upper
        b = getattr(self, kind)
        return -b, b

    def scale_of(self, kind: str) -> np.ndarray:
        """A positive size (n,) of each joint's limit, used to make violations dimensionless.

        position: half the range when both bounds exist, else max(|bound|, 1); others: the bound.
        Joints without a limit of that kind get 1.
        """
        if kind == "position":
            lo, hi = self.lower, self.upper
            both = np.isfinite(lo) & np.isfinite(hi)
            one = np.where(np.isfinite(lo), np.abs(lo), np.where(np.isfinite(hi), np.abs(hi), 1.0))
            s = np.where(both, 0.5 * (hi - lo), np.maximum(one, 1.0))
        else:
            b = getattr(self, kind)
            s = np.where(np.isfinite(b), b, 1.0)
        return np.where(s > 0, s, 1.0)

    def has(self, kind: str) -> np.ndarray:
        """Which joints (n,) bool have a finite limit of this kind."""
        lo, hi = self.bounds(kind)
        return np.isfinite(lo) | np.isfinite(hi)

    @property
    def any(self) -> bool:
        return any(self.has(k).any() for k in KINDS)

    def with_overrides(self, position: Mapping[str, tuple[float, float]] | None = None,
                       velocity: Mapping[str, float] | None = None,
                       acceleration: Mapping[str, float] | None = None,
                       effort: Mapping[str, float] | None = None,
                       scale: Mapping[str, float] | None = None,
                       jerk: Mapping[str, float] | None = None) -> "JointLimits":
        """New limits with per-joint overrides (names must be joints) and scaling factors applied."""
        idx = {name: i for i, name in enumerate(self.joints)}
        lo, hi = self.lower.copy(), self.upper.copy()
        rates = {k: getattr(self, k).copy() for k in SCALABLE}
        for name, (a, b) in (position or {}).items():
            lo[idx[name]], hi[idx[name]] = float(a), float(b)
        for kind, over in (("velocity", velocity), ("acceleration", acceleration), ("jerk", jerk), ("effort", effort)):
            for name, v in (over or {}).items():
                rates[kind][idx[name]] = float(v)
        for kind, s in (scale or {}).items():
            rates[kind] = rates[kind] * float(s)
        return JointLimits(self.joints, lo, hi, _positive_or_inf(rates["velocity"]),
                           _positive_or_inf(rates["acceleration"]), _positive_or_inf(rates["effort"]),
                           _positive_or_inf(rates["jerk"]))

    def as_dict(self) -> dict:
        """JSON-ready per-joint limits (None where there is no limit)."""
        def f(v):
            return float(v) if np.isfinite(v) else None

        return {name: {"position": [f(self.lower[i]), f(self.upper[i])], "velocity": f(self.velocity[i]),
                       "acceleration": f(self.acceleration[i]), "jerk": f(self.jerk[i]), "effort": f(self.effort[i])}
                for i, name in enumerate(self.joints)}
