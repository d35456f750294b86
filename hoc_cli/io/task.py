"""The YAML task file: load, validate and resolve against a robot's joints.

Validation happens once, here, at the boundary. Every failure is a ``TaskError`` that
names the file, the key path (``x0.q[1]``, ``solver.tol``) and what was expected.
See SPEC.md "Task file" and the README's task-file reference for every key.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from hoc_cli.costs import COSTS
from hoc_cli.errors import TaskError

ORDERS = ("quintic", "cubic")
METHODS = ("pr-cg", "newton")
TOP_KEYS = ("robot", "joints", "locked", "gravity", "x0", "x1", "T", "N", "order", "cost", "solver", "output", "torque")
STATE_KEYS = ("q", "dq")
SOLVER_KEYS = ("method", "tol", "max_iter")
OUTPUT_KEYS = ("rate",)

MAX_SAMPLES = 1_000_000  # output samples T·rate + 1: beyond this CSV and MCAP reach hundreds of MB
MAX_ELEMENTS = 100_000  # beyond this the quadrature arrays alone exceed a workstation's memory
DEFAULT_TOL = 1e-10
DEFAULT_MAX_ITER = 5000
DEFAULT_RATE = 100.0

Values = list[float] | dict[str, float]


class _Loader(yaml.SafeLoader):
    """YAML 1.1 safe loader that also reads YAML 1.2 floats such as ``1e-10`` (PyYAML reads them as strings)."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def _mapping_without_duplicates(loader: yaml.SafeLoader, node: yaml.MappingNode, deep: bool = False) -> dict:
    seen: set = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        try:
            duplicate = key in seen
            seen.add(key)
        except TypeError:  # unhashable key: let the default constructor report it
            duplicate = False
        if duplicate:
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key {key!r} (a later value would silently replace the earlier)",
                key_node.start_mark)
    return yaml.SafeLoader.construct_mapping(loader, node, deep=deep)


_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _mapping_without_duplicates)


def load_yaml(text: str):
    """Parse YAML text safely (no object construction), with YAML 1.2 exponent floats."""
    return yaml.load(text, Loader=_Loader)  # noqa: S506 - a SafeLoader subclass


@dataclass(frozen=True)
class State:
    """A state given in the task: q and dq as lists (task joint order) or name → value mappings."""

    q: Values
    dq: Values | None


@dataclass(frozen=True)
class Task:
    """A validated task. Joint-indexed values are resolved by ``resolve``."""

    path: Path
    robot: Path
    joints: tuple[str, ...] | None
    locked: dict[str, float]
    gravity: tuple[float, float, float]
    x0: State
    x1: State | None
    T: float
    N: int
    order: str = "quintic"
    cost: str = "covariant"
    method: str = "pr-cg"
    tol: float = DEFAULT_TOL
    max_iter: int = DEFAULT_MAX_ITER
    rate: float = DEFAULT_RATE
    torque: str | Values | None = None
    text: str = field(default="", repr=False)

    @property
    def stem(self) -> str:
        return self.path.stem


@dataclass(frozen=True, eq=False)
class ResolvedStates:
    """x0, x1 (and a constant torque) as arrays in the model's joint order; shapes (n,)."""

    q0: np.ndarray
    dq0: np.ndarray
    q1: np.ndarray | None
    dq1: np.ndarray | None
    torque: np.ndarray | None


class _Checker:
    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, key: str, expected: str, got: Any = None, show_got: bool = True) -> TaskError:
        msg = f"expected {expected}"
        if show_got:
            msg += f", got {_show(got)}"
        return TaskError(msg, file=self.path, key=key)

    def number(self, value: Any, key: str, *, positive: bool = False, what: str = "a finite number") -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(key, what, value)
        try:
            x = float(value)
        except OverflowError:  # an integer beyond the range of a double
            raise self.fail(key, what, value) from None
        if not math.isfinite(x):
            raise self.fail(key, what, value)
        if positive and x <= 0:
            raise self.fail(key, what, value)
        return x

    def integer(self, value: Any, key: str, minimum: int, maximum: int | None = None) -> int:
        what = f"an integer >= {minimum}" if maximum is None else f"an integer >= {minimum} and <= {maximum}"
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer() and math.isfinite(value):
                value = int(value)
            else:
                raise self.fail(key, what, value)
        if value < minimum or (maximum is not None and value > maximum):
            raise self.fail(key, what, value)
        return int(value)

    def choice(self, value: Any, key: str, choices: tuple[str, ...]) -> str:
        if not isinstance(value, str) or value not in choices:
            raise self.fail(key, "one of " + ", ".join(choices), value)
        return value

    def mapping(self, value: Any, key: str, allowed: tuple[str, ...]) -> dict:
        if not isinstance(value, dict):
            raise self.fail(key, f"a mapping with keys {', '.join(allowed)}", value)
        for k in value:
            if k not in allowed:
                raise TaskError(
                    f"unknown key {k!r} (expected one of: {', '.join(allowed)})", file=self.path, key=_join(key, str(k))
                )
        return value

    def values(self, value: Any, key: str) -> Values:
        if isinstance(value, dict):
            out: dict[str, float] = {}
            for name, v in value.items():
                if not isinstance(name, str):
                    raise self.fail(key, "joint names (strings) as keys", name)
                out[name] = self.number(v, f"{key}.{name}")
            return out
        if isinstance(value, (list, tuple)):
            return [self.number(v, f"{key}[{i}]") for i, v in enumerate(value)]
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return [self.number(value, key)]
        raise self.fail(key, "a list of numbers or a mapping joint -> number", value)

    def state(self, value: Any, key: str) -> State:
        m = self.mapping(value, key, STATE_KEYS)
        if "q" not in m:
            raise TaskError("missing required key 'q'", file=self.path, key=f"{key}.q")
        q = self.values(m["q"], f"{key}.q")
        dq = self.values(m["dq"], f"{key}.dq") if m.get("dq") is not None else None
        return State(q=q, dq=dq)


def _join(prefix: str, key: str) -> str:
    return f"{prefix}.{key}" if prefix else key


def _show(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _stat_ok(path: Path) -> bool:
    """Whether ``path`` exists; False (not an OSError) for a name the system cannot look up (too long...)."""
    try:
        path.stat()
    except (OSError, ValueError):
        return False
    return True


def load_task(path: str | Path, *, purpose: str = "plan") -> Task:
    """Read and validate a task YAML. ``purpose`` is "plan" (x1 required) or "simulate"."""
    path = Path(path)
    if not _stat_ok(path):
        raise TaskError("file not found (expected a task YAML file)", file=path)
    if path.is_dir():
        raise TaskError("is a directory (expected a task YAML file)", file=path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise TaskError(f"cannot be read as UTF-8 text ({exc.__class__.__name__})", file=path) from None
    try:
        doc = load_yaml(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or "invalid syntax"
        raise TaskError(f"invalid YAML{where}: {problem}", file=path) from None
    return parse_task(doc, path=path, text=text, purpose=purpose)


def parse_task(doc: Any, *, path: Path, text: str = "", purpose: str = "plan") -> Task:
    """Validate a parsed YAML document (see ``load_task``)."""
    c = _Checker(path)
    if doc is None:
        raise TaskError("empty file (expected a mapping with at least robot, x0, x1, T, N)", file=path)
    top = c.mapping(doc, "", TOP_KEYS) if isinstance(doc, dict) else None
    if top is None:
        raise TaskError(f"expected a mapping of task keys at the top level, got {type(doc).__name__}", file=path)
    required = ["robot", "x0", "T", "N"] + (["x1"] if purpose == "plan" else [])
    for key in required:
        if key not in top:
            raise TaskError("missing required key", file=path, key=key)

    robot = top["robot"]
    if not isinstance(robot, str) or not robot.strip():
        raise c.fail("robot", "a path to a URDF file (string)", robot)
    robot_path = Path(robot)
    if not robot_path.is_absolute():
        robot_path = path.parent / robot_path
    if not _stat_ok(robot_path) or not robot_path.is_file():
        raise TaskError(f"URDF file not found: {str(robot_path)!r}", file=path, key="robot")

    joints = None
    if top.get("joints") is not None:
        j = top["joints"]
        if not isinstance(j, list) or not j or not all(isinstance(x, str) for x in j):
            raise c.fail("joints", "a non-empty list of joint names", j)
        if len(set(j)) != len(j):
            dup = next(x for x in j if j.count(x) > 1)
            raise c.fail("joints", "distinct joint names", f"{dup!r} twice", show_got=True)
        joints = tuple(j)

    locked: dict[str, float] = {}
    if top.get("locked") is not None:
        lk = top["locked"]
        if not isinstance(lk, dict):
            raise c.fail("locked", "a mapping joint -> position", lk)
        for name, v in lk.items():
            if not isinstance(name, str):
                raise c.fail("locked", "joint names (strings) as keys", name)
            if joints is not None and name in joints:
                raise TaskError("joint is both in 'joints' and 'locked'", file=path, key=f"locked.{name}")
            locked[name] = c.number(v, f"locked.{name}")

    gravity = (0.0, 0.0, -9.81)
    if top.get("gravity") is not None:
        g = top["gravity"]
        if not isinstance(g, list) or len(g) != 3:
            raise c.fail("gravity", "a list of 3 numbers (m/s^2)", g)
        gravity = tuple(c.number(v, f"gravity[{i}]") for i, v in enumerate(g))  # type: ignore[assignment]

    x0 = c.state(top["x0"], "x0")
    x1 = c.state(top["x1"], "x1") if top.get("x1") is not None else None
    T = c.number(top["T"], "T", positive=True, what="a duration T > 0 in seconds")
    N = c.integer(top["N"], "N", 1, MAX_ELEMENTS)
    order = c.choice(top.get("order", "quintic"), "order", ORDERS)
    cost = c.choice(top.get("cost", "covariant"), "cost", COSTS)

    method, tol, max_iter = "pr-cg", DEFAULT_TOL, DEFAULT_MAX_ITER
    if top.get("solver") is not None:
        s = c.mapping(top["solver"], "solver", SOLVER_KEYS)
        method = c.choice(s.get("method", method), "solver.method", METHODS)
        if "tol" in s:
            tol = c.number(s["tol"], "solver.tol", positive=True, what="a tolerance > 0")
        if "max_iter" in s:
            max_iter = c.integer(s["max_iter"], "solver.max_iter", 1)

    rate = DEFAULT_RATE
    if top.get("output") is not None:
        o = c.mapping(top["output"], "output", OUTPUT_KEYS)
        if "rate" in o:
            rate = c.number(o["rate"], "output.rate", positive=True, what="a sample rate > 0 in Hz")

    _check_samples(c, T, rate, "output.rate")

    torque: str | Values | None = None
    if top.get("torque") is not None:
        tq = top["torque"]
        if isinstance(tq, str):
            if tq != "zero":
                raise c.fail("torque", "'zero' or a list of constant torques (N·m or N)", tq)
            torque = "zero"
        else:
            torque = c.values(tq, "torque")

    return Task(
        path=path, robot=robot_path, joints=joints, locked=locked, gravity=gravity, x0=x0, x1=x1,
        T=T, N=N, order=order, cost=cost, method=method, tol=tol, max_iter=max_iter, rate=rate,
        torque=torque, text=text,
    )


def apply_overrides(task: Task, **overrides: Any) -> Task:
    """Return the task with CLI overrides (N, order, T, tol, max_iter, method) applied and validated.

    ``None`` values are ignored. Errors name the option, e.g. ``--elements``.
    """
    c = _Checker(task.path)
    names = {"N": "--elements", "order": "--order", "T": "--duration", "tol": "--tol", "max_iter": "--max-iter",
             "method": "--method", "cost": "--cost"}
    changes: dict[str, Any] = {}
    for key, value in overrides.items():
        if value is None:
            continue
        opt = names.get(key, key)
        if key == "N":
            changes[key] = c.integer(value, opt, 1, MAX_ELEMENTS)
        elif key == "T":
            changes[key] = c.number(value, opt, positive=True, what="a duration > 0 in seconds")
        elif key == "tol":
            changes[key] = c.number(value, opt, positive=True, what="a tolerance > 0")
        elif key == "max_iter":
            changes[key] = c.integer(value, opt, 1)
        elif key == "order":
            changes[key] = c.choice(value, opt, ORDERS)
        elif key == "method":
            changes[key] = c.choice(value, opt, METHODS)
        elif key == "cost":
            changes[key] = c.choice(value, opt, COSTS)
        else:
            raise ValueError(f"unknown override {key}")
    new = replace(task, **changes)
    if "T" in changes:
        _check_samples(c, new.T, new.rate, "--duration")
    return new


def _check_samples(c: _Checker, T: float, rate: float, key: str) -> None:
    if T * rate + 1 > MAX_SAMPLES:
        raise TaskError(f"T·rate = {T:g} s × {rate:g} Hz gives more than {MAX_SAMPLES} output samples "
                        f"(expected a lower output.rate or a shorter T)", file=c.path, key=key)


def _vector(c: _Checker, values: Values | None, key: str, joints: tuple[str, ...]) -> np.ndarray | None:
    n = len(joints)
    if values is None:
        return None
    if isinstance(values, dict):
        out = np.zeros(n)
        missing = [j for j in joints if j not in values]
        for name in values:
            if name not in joints:
                raise TaskError(
                    f"unknown joint {name!r} (task joints: {', '.join(joints)})", file=c.path, key=f"{key}.{name}"
                )
        if missing:
            raise TaskError(f"missing value for joint(s) {', '.join(missing)}", file=c.path, key=key)
        for i, j in enumerate(joints):
            out[i] = values[j]
        return out
    if len(values) != n:
        raise TaskError(
            f"expected {n} values (one per joint: {', '.join(joints)}), got {len(values)}", file=c.path, key=key
        )
    return np.asarray(values, dtype=float)


def resolve(task: Task, joints: tuple[str, ...] | list[str]) -> ResolvedStates:
    """Map the task's states (lists or joint mappings) to arrays in the given joint order."""
    joints = tuple(joints)
    c = _Checker(task.path)
    zeros = np.zeros(len(joints))
    q0 = _vector(c, task.x0.q, "x0.q", joints)
    dq0 = _vector(c, task.x0.dq, "x0.dq", joints)
    q1 = dq1 = None
    if task.x1 is not None:
        q1 = _vector(c, task.x1.q, "x1.q", joints)
        dq1 = _vector(c, task.x1.dq, "x1.dq", joints)
        dq1 = zeros.copy() if dq1 is None else dq1
    torque = None
    if task.torque == "zero":
        torque = zeros.copy()
    elif task.torque is not None:
        torque = _vector(c, task.torque, "torque", joints)  # type: ignore[arg-type]
    return ResolvedStates(q0=q0, dq0=zeros.copy() if dq0 is None else dq0, q1=q1, dq1=dq1, torque=torque)
