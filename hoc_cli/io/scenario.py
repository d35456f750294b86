"""A catch scenario YAML (``hoc catch``) read into the closed loop's parts; errors name the file and the key.

Keys (README, "Catching in real time"):

    task:    a catch task file (path relative to the scenario) or its keys inline: a moving link goal
             (x1.link with x1.target) and a free T
    throw:   {position: [x, y, z] m, velocity: [vx, vy, vz] m/s, gravity: [gx, gy, gz] m/s² (default the task
             target's acceleration), drag: k 1/m (default 0)}
    observe: {rate: Hz (100), noise: σ m (0.005), seed: int (0), latency: s (0),
             prior: {position: σ m, velocity: σ m/s} or null (default 0.05, 0.25)}
    cycle:   {rate: Hz (100), budget: s (0.01), steps: int (2), commit: s (0.01), fix: s (0.1), delay: int (1),
             feedback: s (0: off); budget <= delay/rate and feedback <= 1/rate: an update is done before its plan starts}
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from hoc_cli.errors import TaskError
from hoc_cli.io.task import Task, load_task
from hoc_cli.io.task.document import parse_task, read_yaml_file
from hoc_cli.io.task.goals import LinkGoal
from hoc_cli.realtime.loop import Cycle, Observer, Throw

TOP = ("task", "throw", "observe", "cycle")
THROW = ("position", "velocity", "gravity", "drag")
OBSERVE = ("rate", "noise", "seed", "latency", "prior")
CYCLE = ("rate", "budget", "steps", "commit", "fix", "delay", "feedback")


@dataclass(frozen=True, eq=False)
class Scenario:
    """The parsed scenario: its path and text, the catch ``task`` (a ``Task``), the true ``throw``, the ``observer``
    and the control ``cycle`` (``hoc_cli.realtime.loop``).
    """

    path: Path
    text: str
    task: Task
    throw: Throw
    observer: Observer
    cycle: Cycle


class _Keys:
    """Checks of one scenario file: each failure a ``TaskError`` naming the file and the key."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, key: str, what: str) -> TaskError:
        return TaskError(what, file=self.path, key=key)

    def mapping(self, value: Any, key: str, allowed: tuple[str, ...]) -> dict:
        if not isinstance(value, dict):
            raise self.fail(key, f"expected a mapping with keys {', '.join(allowed)}")
        for k in value:
            if k not in allowed:
                raise self.fail(f"{key}.{k}" if key else str(k), f"unknown key (expected one of {', '.join(allowed)})")
        return value

    def number(self, value: Any, key: str, *, low: float | None = None, strict: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.fail(key, f"expected a finite number, got {value!r}")
        if low is not None and (value <= low if strict else value < low):
            raise self.fail(key, f"expected a number {'>' if strict else '>='} {low:g}, got {value!r}")
        return float(value)

    def integer(self, value: Any, key: str, low: int) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise self.fail(key, f"expected an integer >= {low}, got {value!r}")
        return int(value)

    def vector(self, value: Any, key: str) -> np.ndarray:
        if not isinstance(value, list) or len(value) != 3:
            raise self.fail(key, f"expected a list of 3 numbers, got {value!r}")
        return np.array([self.number(v, f"{key}[{i}]") for i, v in enumerate(value)])


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario file (module docstring); ``TaskError`` (exit 2) naming the file and key."""
    path = Path(path)
    text, doc = read_yaml_file(path, "a catch scenario YAML file")
    c = _Keys(path)
    if doc is None:
        raise TaskError("empty file (expected a mapping with task, throw, observe, cycle)", file=path)
    top = c.mapping(doc, "", TOP)
    for key in ("task", "throw"):
        if key not in top:
            raise c.fail(key, "missing required key")
    task = _task(c, top["task"])
    throw = _throw(c, top["throw"], task)
    observer = _observer(c, top.get("observe", {}) or {})
    cycle = _cycle(c, top.get("cycle", {}) or {})
    return Scenario(path=path, text=text, task=task, throw=throw, observer=observer, cycle=cycle)


def _task(c: _Keys, value: Any) -> Task:
    if isinstance(value, str):
        file = Path(value) if Path(value).is_absolute() else c.path.parent / value
        if not file.is_file():
            raise c.fail("task", f"expected a catch task file or its keys inline; no file {value!r}")
        task = load_task(file, purpose="plan")
    elif isinstance(value, dict):
        try:
            task = parse_task(value, path=c.path, text=yaml.safe_dump(value, sort_keys=False), purpose="plan")
        except TaskError as exc:
            raise c.fail(f"task.{exc.key}" if exc.key else "task", exc.detail) from None
    else:
        raise c.fail("task", f"expected a catch task file or its keys inline, got {type(value).__name__}")
    goal = task.x1
    if not isinstance(goal, LinkGoal) or goal.target is None or not goal.match_velocity:
        raise c.fail("task", "expected a catch task: x1 a link goal with a moving target and match_velocity: true")
    if task.time.free is None:
        raise c.fail("task", "expected a catch task with a free T (T: {free: true, min, max})")
    return task


def _throw(c: _Keys, value: Any, task: Task) -> Throw:
    m = c.mapping(value, "throw", THROW)
    for key in ("position", "velocity"):
        if key not in m:
            raise c.fail(f"throw.{key}", "missing required key")
    gravity = task.x1.target.acceleration
    if "gravity" in m:
        gravity = c.vector(m["gravity"], "throw.gravity")
    drag = c.number(m.get("drag", 0.0), "throw.drag", low=0.0)
    return Throw(position=c.vector(m["position"], "throw.position"), velocity=c.vector(m["velocity"], "throw.velocity"),
                 gravity=np.asarray(gravity, float), drag=drag)


def _observer(c: _Keys, value: Any) -> Observer:
    m = c.mapping(value, "observe", OBSERVE)
    d = Observer()
    prior = d.prior
    if "prior" in m:
        if m["prior"] is None:
            prior = None
        else:
            p = c.mapping(m["prior"], "observe.prior", ("position", "velocity"))
            prior = (c.number(p.get("position", d.prior[0]), "observe.prior.position", low=0.0, strict=True),
                     c.number(p.get("velocity", d.prior[1]), "observe.prior.velocity", low=0.0, strict=True))
    return Observer(rate=c.number(m.get("rate", d.rate), "observe.rate", low=0.0, strict=True),
                    noise=c.number(m.get("noise", d.noise), "observe.noise", low=0.0),
                    seed=c.integer(m.get("seed", d.seed), "observe.seed", 0),
                    latency=c.number(m.get("latency", d.latency), "observe.latency", low=0.0), prior=prior)


def _cycle(c: _Keys, value: Any) -> Cycle:
    m = c.mapping(value, "cycle", CYCLE)
    d = Cycle()
    rate = c.number(m.get("rate", d.rate), "cycle.rate", low=0.0, strict=True)
    delay = c.integer(m.get("delay", d.delay), "cycle.delay", 1)
    budget = c.number(m.get("budget", d.budget), "cycle.budget", low=0.0, strict=True)
    if budget > delay / rate * (1 + 1e-9):
        raise c.fail("cycle.budget", f"expected at most delay/rate = {delay / rate:g} s (an update must be done before "
                                     f"its plan starts), got {budget!r}")
    feedback = c.number(m.get("feedback", d.feedback), "cycle.feedback", low=0.0)
    if feedback > 1.0 / rate * (1 + 1e-9):
        raise c.fail("cycle.feedback", f"expected at most 1/rate = {1.0 / rate:g} s (a correction must be done before the "
                                       f"next one starts), got {feedback!r}")
    return Cycle(rate=rate, budget=budget, steps=c.integer(m.get("steps", d.steps), "cycle.steps", 1),
                 commit=c.number(m.get("commit", d.commit), "cycle.commit", low=0.0),
                 fix=c.number(m.get("fix", d.fix), "cycle.fix", low=0.0), delay=delay, feedback=feedback)
