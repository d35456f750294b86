"""The task as a whole: read the file, run the section parsers in order, assemble a frozen ``Task``."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from hoc_cli.errors import TaskError
from hoc_cli.io.inputs import file_problem
from hoc_cli.io.task.checks import Checker, Values
from hoc_cli.io.task.collision import CollisionSpec, parse_collision
from hoc_cli.io.task.goals import Via, parse_via
from hoc_cli.io.task.limits import LimitsSpec, parse_limits
from hoc_cli.io.task.sections import (
    BoundarySpec,
    OutputSpec,
    RobotSpec,
    SolverSpec,
    State,
    TimeSpec,
    parse_boundary,
    parse_cost,
    parse_output,
    parse_robot,
    parse_solver,
    parse_time,
    parse_torque,
)
from hoc_cli.io.task.yaml12 import load_yaml

MAX_TASK_BYTES = 16 << 20  # a task file is a few kB; a larger one is not a task (read whole, before parsing)


@dataclass(frozen=True)
class Section:
    """A task section: the ``Task`` attribute it fills, the top-level keys it reads, its parser."""

    attr: str
    keys: tuple[str, ...]
    parse: Callable[[Checker, dict, dict], Any]


# Parsed in this order (a later parser may read an earlier section from ``parsed``); the order also
# decides which error a file with several mistakes reports first.
SECTIONS: tuple[Section, ...] = (
    Section("robot_spec", ("robot", "joints", "locked", "gravity"), parse_robot),
    Section("boundary", ("x0", "x1"), parse_boundary),
    Section("time", ("T", "N", "order", "accuracy"), parse_time),
    Section("via", ("via",), parse_via),
    Section("cost", ("cost",), parse_cost),
    Section("solver", ("solver",), parse_solver),
    Section("output", ("output",), parse_output),
    Section("limits", ("limits",), parse_limits),
    Section("torque", ("torque",), parse_torque),
    Section("collision", ("collision",), parse_collision),
)
TOP_KEYS = tuple(key for section in SECTIONS for key in section.keys)


@dataclass(frozen=True)
class Task:
    """A validated task: one frozen dataclass per section, plus flat read-only views of their fields.

    Joint-indexed values (lists in task joint order or name → value mappings) are turned into
    arrays by ``resolve`` once the model's joints are known.
    """

    path: Path
    robot_spec: RobotSpec
    boundary: BoundarySpec
    time: TimeSpec
    cost: str = "covariant"
    solver: SolverSpec = field(default_factory=SolverSpec)
    output: OutputSpec = field(default_factory=OutputSpec)
    limits: LimitsSpec = field(default_factory=LimitsSpec)
    torque: str | Values | None = None
    via: tuple[Via, ...] = ()
    collision: CollisionSpec = field(default_factory=CollisionSpec)
    text: str = field(default="", repr=False)

    @property
    def stem(self) -> str:
        """The task file's name without its suffix (the default output name)."""
        return self.path.stem

    # Flat views of the section fields, as consumers read them (task.T, task.tol...).
    robot = property(lambda self: self.robot_spec.robot, doc="The URDF path.")
    joints = property(lambda self: self.robot_spec.joints, doc="The planned joints, or None for all.")
    locked = property(lambda self: self.robot_spec.locked, doc="Locked joint positions.")
    gravity = property(lambda self: self.robot_spec.gravity, doc="Gravity (m/s²) in the root frame.")
    x0 = property(lambda self: self.boundary.x0, doc="The start state.")
    x1 = property(lambda self: self.boundary.x1, doc="The goal state, or None.")
    T = property(lambda self: self.time.T, doc="The duration (s).")
    N = property(lambda self: self.time.N, doc="The number of elements, or None for N: auto.")
    accuracy = property(lambda self: self.time.accuracy, doc="The target relative error of J (N: auto).")
    order = property(lambda self: self.time.order, doc="quintic or cubic.")
    method = property(lambda self: self.solver.method, doc="pr-cg or newton.")
    tol = property(lambda self: self.solver.tol, doc="The solver tolerance.")
    max_iter = property(lambda self: self.solver.max_iter, doc="The iteration limit.")
    rate = property(lambda self: self.output.rate, doc="The output sample rate (Hz).")


def read_yaml_file(path: str | Path, what: str = "a task YAML file") -> tuple[str, object]:
    """(text, document) of a YAML file; ``TaskError`` naming the file when it is missing or not a regular
    file (checked before it is opened: a FIFO or /dev/zero would block or never end), over
    ``MAX_TASK_BYTES``, not UTF-8 or not YAML. ``what`` completes "expected …" in the messages.
    """
    path = Path(path)
    problem = file_problem(path)
    if problem is not None:
        raise TaskError(f"{problem} (expected {what})", file=path)
    size = path.stat().st_size
    if size > MAX_TASK_BYTES:
        raise TaskError(f"is {size / 2**20:.0f} MiB (expected {what} of at most {MAX_TASK_BYTES >> 20} MiB)", file=path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise TaskError(f"cannot be read as UTF-8 text ({exc.__class__.__name__})", file=path) from None
    try:
        return text, load_yaml(text)
    except yaml.YAMLError as exc:
        raise TaskError(f"invalid YAML{yaml_error_detail(exc)}", file=path) from None


def load_task(path: str | Path, *, purpose: str = "plan") -> Task:
    """Read and validate a task YAML. ``purpose`` is "plan" (x1 required) or "simulate"."""
    path = Path(path)
    text, doc = read_yaml_file(path)
    return parse_task(doc, path=path, text=text, purpose=purpose)


def yaml_error_detail(exc: yaml.YAMLError) -> str:
    """`` at line L, column C: problem`` for a YAML error (position omitted when unknown)."""
    mark = getattr(exc, "problem_mark", None)
    where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
    problem = getattr(exc, "problem", None) or "invalid syntax"
    return f"{where}: {problem}"


def parse_task(doc: Any, *, path: Path, text: str = "", purpose: str = "plan") -> Task:
    """Validate a parsed YAML document (see ``load_task``)."""
    c = Checker(path)
    if doc is None:
        raise TaskError("empty file (expected a mapping with at least robot, x0, x1, T)", file=path)
    if not isinstance(doc, dict):
        raise TaskError(f"expected a mapping of task keys at the top level, got {type(doc).__name__}", file=path)
    top = c.mapping(doc, "", TOP_KEYS)
    required = ["robot", "x0", "T"] + (["x1"] if purpose == "plan" else ["N"])
    for key in required:
        if key not in top:
            raise TaskError("missing required key", file=path, key=key)
    parsed: dict[str, Any] = {}
    for section in SECTIONS:
        parsed[section.attr] = section.parse(c, top, parsed)
    if purpose != "plan" and parsed["time"].N is None:
        raise TaskError("N: auto is for hoc plan only (expected an integer number of elements)", file=path, key="N")
    return Task(path=path, text=text, **parsed)


__all__ = ["SECTIONS", "TOP_KEYS", "Section", "State", "Task", "load_task", "parse_task", "yaml_error_detail"]
