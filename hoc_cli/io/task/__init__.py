"""The YAML task file: load, validate and resolve against a robot's joints.

Validation happens once, here, at the boundary. Every failure is a ``TaskError`` that names the
file, the key path (``x0.q[1]``, ``solver.tol``) and what was expected; see the README's task-file
reference for every key. The modules:

- ``yaml12``: the YAML 1.2 core-schema reader, bounded against alias bombs and deep nesting;
- ``checks``: the value checkers shared by the sections and the CLI overrides;
- ``sections``: one parser per section (robot, boundary, time, cost, solver, output, torque);
- ``limits``: the ``limits:`` section;
- ``document``: the ``Task`` and ``load_task``/``parse_task``;
- ``overrides``: ``apply_overrides`` for the CLI options;
- ``resolve``: joint-indexed values as arrays in a model's joint order.
"""
from hoc_cli.io.task.checks import Checker, Values
from hoc_cli.io.task.document import (
    SECTIONS,
    TOP_KEYS,
    Task,
    load_task,
    parse_task,
    yaml_error_detail,
)
from hoc_cli.io.task.limits import LIMIT_MODES, LimitOverrides, LimitScale, LimitsSpec
from hoc_cli.io.task.overrides import OVERRIDES, apply_overrides
from hoc_cli.io.task.resolve import ResolvedStates, resolve
from hoc_cli.io.task.sections import (
    COSTS,
    DEFAULT_MAX_ITER,
    DEFAULT_RATE,
    DEFAULT_TOL,
    MAX_ELEMENTS,
    MAX_SAMPLES,
    METHODS,
    ORDERS,
    BoundarySpec,
    OutputSpec,
    RobotSpec,
    SolverSpec,
    State,
    TimeSpec,
)
from hoc_cli.io.task.yaml12 import Yaml12Loader, load_yaml

__all__ = [
    "COSTS", "DEFAULT_MAX_ITER", "DEFAULT_RATE", "DEFAULT_TOL", "LIMIT_MODES", "MAX_ELEMENTS", "MAX_SAMPLES",
    "METHODS", "ORDERS", "OVERRIDES", "SECTIONS", "TOP_KEYS", "BoundarySpec", "Checker", "LimitOverrides",
    "LimitScale", "LimitsSpec", "OutputSpec", "ResolvedStates", "RobotSpec", "SolverSpec", "State", "Task",
    "TimeSpec", "Values", "Yaml12Loader", "apply_overrides", "load_task", "load_yaml", "parse_task", "resolve",
    "yaml_error_detail",
]
