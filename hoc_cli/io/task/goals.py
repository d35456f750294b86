"""The goal keys beyond a joint state: ``x1: {link: ...}``, ``via:`` and ``T: {free: true, ...}``.

Link names are checked against the robot when the task is resolved (``hoc_cli.report.goals``);
everything else is checked here, like every other key (README, Goals; docs/goals.md).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from hoc_cli.io.task.checks import Checker, Values

LINK_GOAL_KEYS = ("link", "position", "orientation", "dq", "target", "match_velocity")
TARGET_KEYS = ("position", "velocity", "acceleration")
VIA_KEYS = ("t", "s", "q", "dq", "link", "position", "orientation")
FREE_TIME_KEYS = ("free", "min", "max", "guess", "weight")
MAX_VIAS = 1000
MIN_T = 1e-9  # s: no motion of a physical arm is shorter; far below it the cost overflows


@dataclass(frozen=True)
class MovingTarget:
    """A target moving with constant acceleration: p(t) = position + velocity·t + ½·acceleration·t² [m]."""

    position: tuple[float, float, float]
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    acceleration: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class LinkGoal:
    """x1 as a link pose: ``position`` [m] (or a moving ``target``), ``orientation`` (w, x, y, z) or None,
    ``dq`` "zero" (rest at T) or "free", ``match_velocity`` (the link's velocity equals the target's).
    """

    link: str
    position: tuple[float, float, float] | None = None
    orientation: tuple[float, float, float, float] | None = None
    dq: str = "zero"
    target: MovingTarget | None = None
    match_velocity: bool = False


@dataclass(frozen=True)
class Via:
    """A via point at time ``t`` [s] or fraction ``s`` of T: a joint state (q, dq) or a link pose."""

    t: float | None = None
    s: float | None = None
    q: Values | None = None
    dq: Values | None = None
    link: str | None = None
    position: tuple[float, float, float] | None = None
    orientation: tuple[float, float, float, float] | None = None


@dataclass(frozen=True)
class FreeTime:
    """T free in [min, max] [s], starting from ``guess``; the objective is J + weight·T."""

    min: float
    max: float
    guess: float | None = None
    weight: float = 0.0


def _vec(c: Checker, value: Any, key: str, size: int, what: str) -> tuple[float, ...]:
    if not isinstance(value, (list, tuple)) or len(value) != size:
        raise c.fail(key, f"a list of {size} numbers ({what})", value)
    return tuple(c.physical(v, f"{key}[{i}]") for i, v in enumerate(value))


def _quaternion(c: Checker, value: Any, key: str) -> tuple[float, float, float, float]:
    w = _vec(c, value, key, 4, "a unit quaternion w, x, y, z")
    norm = math.sqrt(sum(x * x for x in w))
    if abs(norm - 1.0) > 1e-6:
        raise c.error(key, f"expected a unit quaternion (w, x, y, z), got norm {norm:.9g}")
    return w  # type: ignore[return-value]


def _link(c: Checker, value: Any, key: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise c.fail(key, "a link name (string)", value)
    return value


def parse_link_goal(c: Checker, value: dict, key: str) -> LinkGoal:
    """``x1: {link, position | target, orientation?, dq: zero|free, match_velocity?}``."""
    m = c.mapping(value, key, LINK_GOAL_KEYS)
    link = _link(c, m["link"], f"{key}.link")
    if ("position" in m) == ("target" in m):
        raise c.error(key, "expected exactly one of 'position' (a fixed goal) or 'target' (a moving one)")
    position = _vec(c, m["position"], f"{key}.position", 3, "x, y, z in m") if "position" in m else None
    target = None
    if "target" in m:
        t = c.mapping(m["target"], f"{key}.target", TARGET_KEYS)
        if "position" not in t:
            raise c.error(f"{key}.target.position", "missing required key 'position'")
        target = MovingTarget(*(_vec(c, t[k], f"{key}.target.{k}", 3, "x, y, z") if k in t else (0.0, 0.0, 0.0)
                                for k in TARGET_KEYS))
    orientation = _quaternion(c, m["orientation"], f"{key}.orientation") if m.get("orientation") is not None else None
    match = m.get("match_velocity", False)
    if not isinstance(match, bool):
        raise c.fail(f"{key}.match_velocity", "true or false", match)
    dq = c.choice(m.get("dq", "free" if match else "zero"), f"{key}.dq", ("zero", "free"))
    if match and dq == "zero":
        raise c.error(f"{key}.dq", "match_velocity moves the link at T: dq cannot be 'zero' (use free or leave it out)")
    return LinkGoal(link=link, position=position, orientation=orientation, dq=dq, target=target, match_velocity=match)


def parse_free_time(c: Checker, value: dict, key: str = "T") -> FreeTime:
    """``T: {free: true, min, max, guess?, weight?}``."""
    m = c.mapping(value, key, FREE_TIME_KEYS)
    if m.get("free") is not True:
        raise c.fail(f"{key}.free", "true (a fixed T is written as a number: T: 1.5)", m.get("free"))
    for k in ("min", "max"):
        if k not in m:
            raise c.error(f"{key}.{k}", f"missing required key '{k}' (a free T needs its range)")
    lo = c.number(m["min"], f"{key}.min", positive=True, what="a duration > 0 in seconds")
    hi = c.number(m["max"], f"{key}.max", positive=True, what="a duration > 0 in seconds")
    if lo < MIN_T:
        raise c.fail(f"{key}.min", f"a duration > 0 in seconds, at least {MIN_T:g} s (a physical duration)", lo)
    if hi < lo:
        raise c.error(f"{key}.max", f"expected max >= min = {lo:g} s, got {hi:g}")
    guess = None
    if m.get("guess") is not None:
        guess = c.number(m["guess"], f"{key}.guess", positive=True, what="a duration > 0 in seconds")
        if not lo <= guess <= hi:
            raise c.error(f"{key}.guess", f"expected a guess within [min, max] = [{lo:g}, {hi:g}] s, got {guess:g}")
    weight = c.number(m.get("weight", 0.0), f"{key}.weight", what="a price of time >= 0 (cost units per second)")
    if weight < 0:
        raise c.fail(f"{key}.weight", "a price of time >= 0 (cost units per second)", weight)
    return FreeTime(min=lo, max=hi, guess=guess, weight=weight)


def parse_via(c: Checker, top: dict, parsed: dict) -> tuple[Via, ...]:
    """``via``: a list of ``{t | s, q, dq?}`` or ``{t | s, link, position, orientation?}`` (strictly inside (0, T))."""
    vias = top.get("via")
    if vias is None:
        return ()
    if not isinstance(vias, list) or not vias or len(vias) > MAX_VIAS:
        raise c.fail("via", f"a list of 1 to {MAX_VIAS} via points", vias)
    time = parsed["time"]
    out = []
    for i, v in enumerate(vias):
        key = f"via[{i}]"
        m = c.mapping(v, key, VIA_KEYS)
        if ("t" in m) == ("s" in m):
            raise c.error(key, "expected exactly one of 't' (a time in s) or 's' (a fraction of T)")
        t = s = None
        if "t" in m:
            if time.free is not None:
                raise c.error(f"{key}.t", "T is free: give the via time as a fraction s of T")
            t = c.number(m["t"], f"{key}.t")
            if not 0 < t < time.T:
                raise c.error(f"{key}.t", f"expected 0 < t < T = {time.T:g} s, got {t:g}")
        else:
            s = c.number(m["s"], f"{key}.s")
            if not 0 < s < 1:
                raise c.error(f"{key}.s", f"expected a fraction 0 < s < 1 of T, got {s:g}")
        if ("q" in m) == ("link" in m):
            raise c.error(key, "expected exactly one of 'q' (a joint state) or 'link' (a link pose)")
        if "q" in m:
            for k in ("position", "orientation"):
                if k in m:
                    raise c.error(f"{key}.{k}", "belongs to a link via (with 'link'), not to a joint via")
            out.append(Via(t=t, s=s, q=c.values(m["q"], f"{key}.q"),
                           dq=c.values(m["dq"], f"{key}.dq") if m.get("dq") is not None else None))
            continue
        if "dq" in m:
            raise c.error(f"{key}.dq", "a link via fixes the link's pose only (dq is for joint vias)")
        if "position" not in m:
            raise c.error(f"{key}.position", "missing required key 'position' of the link via")
        out.append(Via(t=t, s=s, link=_link(c, m["link"], f"{key}.link"),
                       position=_vec(c, m["position"], f"{key}.position", 3, "x, y, z in m"),
                       orientation=_quaternion(c, m["orientation"], f"{key}.orientation")
                       if m.get("orientation") is not None else None))
    return tuple(out)
