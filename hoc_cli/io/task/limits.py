"""The ``limits:`` section: how joint limits are treated, and per-joint overrides of the URDF's.

.. code-block:: yaml

    limits:
      mode: enforce                         # enforce (default) | report
      position: {joint_a: [-1.0, 1.0]}      # rad (m for a prismatic joint), lower < upper
      velocity: {joint_a: 1.5}              # rad/s (m/s), > 0
      acceleration: {joint_a: 10.0}         # rad/s² (m/s²), > 0; the URDF has none
      jerk: {joint_a: 200.0}                # rad/s³ (m/s³), > 0; the URDF has none; quintic elements only
      effort: {joint_a: 50.0}               # N·m (N), > 0
      scale: {velocity: 0.9, acceleration: 1.0, jerk: 1.0, effort: 0.8}   # 0 < s <= 1, default 1

Every key is optional. The values here replace or add to the URDF's ``<limit>`` for the joints
named; the scale factors multiply the velocity, acceleration, jerk and effort limits of every joint.
A joint named must be one of the task's joints: checked at parse time when ``joints:`` is given,
otherwise by ``resolve_limits`` against the model's joints.

The limit checks in ``hoc_cli.limits`` (URDF violations reported in the summary) do not read this
section yet; the constrained planner (enforce mode) will.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np

from hoc_cli.io.task.checks import Checker, join, show

LIMIT_MODES = ("enforce", "report")
LIMIT_KINDS = ("position", "velocity", "acceleration", "jerk", "effort")
SCALE_KEYS = ("velocity", "acceleration", "jerk", "effort")
LIMITS_KEYS = ("mode",) + LIMIT_KINDS + ("scale",)
UNITS = {"velocity": "rad/s or m/s", "acceleration": "rad/s² or m/s²", "jerk": "rad/s³ or m/s³", "effort": "N·m or N"}


def _frozen(mapping: dict | None = None) -> Mapping:
    return MappingProxyType(dict(mapping or {}))


@dataclass(frozen=True)
class LimitScale:
    """Factors 0 < s <= 1 on every joint's velocity, acceleration, jerk and effort limits (MoveIt's scaling)."""

    velocity: float = 1.0
    acceleration: float = 1.0
    effort: float = 1.0
    jerk: float = 1.0


@dataclass(frozen=True)
class LimitsSpec:
    """The validated ``limits:`` section. Mappings are read-only, joint name → value.

    Attributes
    ----------
    mode : str
        ``enforce`` (the plan must respect the limits) or ``report`` (violations are reported).
    position : Mapping[str, tuple[float, float]]
        (lower, upper), rad or m, lower < upper.
    velocity, acceleration, jerk, effort : Mapping[str, float]
        Magnitude limits > 0: rad/s (m/s), rad/s² (m/s²), rad/s³ (m/s³), N·m (N).
    scale : LimitScale
        Factors on the velocity, acceleration, jerk and effort limits.
    """

    mode: str = "enforce"
    position: Mapping[str, tuple[float, float]] = field(default_factory=_frozen)
    velocity: Mapping[str, float] = field(default_factory=_frozen)
    acceleration: Mapping[str, float] = field(default_factory=_frozen)
    jerk: Mapping[str, float] = field(default_factory=_frozen)
    effort: Mapping[str, float] = field(default_factory=_frozen)
    scale: LimitScale = field(default_factory=LimitScale)

    def named(self) -> list[tuple[str, str]]:
        """Every (kind, joint) override, in the order written."""
        return [(kind, name) for kind in LIMIT_KINDS for name in getattr(self, kind)]


def check_limits_mode(c: Checker, value: Any, key: str) -> str:
    """``enforce`` or ``report``."""
    return c.choice(value, key, LIMIT_MODES)


def _range(c: Checker, value: Any, key: str) -> tuple[float, float]:
    what = "a range [lower, upper] of finite numbers with lower < upper (rad or m)"
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise c.fail(key, what, value)
    lo, hi = (c.number(v, f"{key}[{i}]") for i, v in enumerate(value))
    if not lo < hi:
        raise c.fail(key, what, value)
    return lo, hi


def _magnitude(c: Checker, value: Any, key: str, kind: str) -> float:
    return c.number(value, key, positive=True, what=f"a finite {kind} limit > 0 ({UNITS[kind]})")


def _scale(c: Checker, value: Any, key: str) -> float:
    s = c.number(value, key, what="a scale factor 0 < s <= 1")
    if not 0.0 < s <= 1.0:
        raise c.fail(key, "a scale factor 0 < s <= 1", value)
    return s


def unknown_joint(c: Checker, kind: str, name: str, joints: tuple[str, ...], locked: Mapping[str, float]):
    """The TaskError for a limit on a joint that is not one of the task's joints."""
    why = "is locked, not a task joint" if name in locked else "is not a task joint"
    return c.error(join(f"limits.{kind}", name), f"joint {show(name)} {why} (task joints: {', '.join(joints)})")


def parse_limits(c: Checker, top: dict, parsed: dict) -> LimitsSpec:
    """``limits:`` (optional; default: enforce the URDF's limits unscaled)."""
    if top.get("limits") is None:
        return LimitsSpec()
    m = c.mapping(top["limits"], "limits", LIMITS_KEYS)
    mode = check_limits_mode(c, m.get("mode", "enforce"), "limits.mode")
    kinds: dict[str, Mapping] = {}
    for kind in LIMIT_KINDS:
        if m.get(kind) is None:
            kinds[kind] = _frozen()
            continue
        key = f"limits.{kind}"
        per_joint = c.names(m[kind], key, f"a mapping joint -> {'[lower, upper]' if kind == 'position' else 'limit'}")
        if kind == "position":
            kinds[kind] = _frozen({j: _range(c, v, join(key, j)) for j, v in per_joint.items()})
        else:
            kinds[kind] = _frozen({j: _magnitude(c, v, join(key, j), kind) for j, v in per_joint.items()})
    scale = LimitScale()
    if m.get("scale") is not None:
        s = c.mapping(m["scale"], "limits.scale", SCALE_KEYS)
        scale = LimitScale(**{k: _scale(c, s[k], f"limits.scale.{k}") for k in SCALE_KEYS if k in s})
    spec = LimitsSpec(mode=mode, scale=scale, **kinds)
    robot = parsed["robot_spec"]
    if robot.joints is not None:
        for kind, name in spec.named():
            if name not in robot.joints:
                raise unknown_joint(c, kind, name, robot.joints, robot.locked)
    return spec


@dataclass(frozen=True, eq=False)
class LimitOverrides:
    """The task's limit overrides as arrays in a joint order; shapes (n,), NaN where none is given.

    Units: rad or m (lower, upper), rad/s or m/s (velocity), rad/s² or m/s² (acceleration), rad/s³ or
    m/s³ (jerk), N·m or N (effort).
    """

    mode: str
    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    effort: np.ndarray
    scale: LimitScale
    jerk: np.ndarray


def resolve_limits(c: Checker, spec: LimitsSpec, joints: tuple[str, ...],
                   locked: Mapping[str, float]) -> LimitOverrides:
    """Map ``spec``'s per-joint values to arrays in ``joints`` order; an unknown joint is a TaskError."""
    index = {name: i for i, name in enumerate(joints)}
    for kind, name in spec.named():
        if name not in index:
            raise unknown_joint(c, kind, name, joints, locked)

    def column(values: Mapping[str, float]) -> np.ndarray:
        out = np.full(len(joints), math.nan)
        for name, v in values.items():
            out[index[name]] = v
        return out

    lower = column({j: lo for j, (lo, _) in spec.position.items()})
    upper = column({j: hi for j, (_, hi) in spec.position.items()})
    return LimitOverrides(mode=spec.mode, lower=lower, upper=upper, velocity=column(spec.velocity),
                          acceleration=column(spec.acceleration), effort=column(spec.effort), scale=spec.scale,
                          jerk=column(spec.jerk))
