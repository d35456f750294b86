"""One parser per task section, each returning a frozen dataclass.

A section parser has the signature ``parse(c, top, parsed)``: ``c`` a ``Checker`` for the file,
``top`` the document's top-level mapping, ``parsed`` the sections parsed before it (by attribute
name) for the checks that span sections. The key checkers (``check_T``, ``check_tol``...) are
shared with ``apply_overrides``, so a value given on the command line is validated exactly like
the same value in the file.

Where the keys that come next slot in: ``T: {free: true, ...}`` is a mapping branch in
``parse_time``; ``x1: {link: ...}`` a branch of ``_goal`` in ``parse_boundary``; ``via:`` a new
section parser beside ``parse_boundary`` (it may read ``parsed["time"]``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hoc_cli.costs import COSTS
from hoc_cli.io.inputs import file_problem
from hoc_cli.io.task.checks import Checker, Values, join, show
from hoc_cli.io.task.goals import MIN_T, FreeTime, LinkGoal, parse_free_time, parse_link_goal

ORDERS = ("quintic", "cubic")
METHODS = ("pr-cg", "newton")
STATE_KEYS = ("q", "dq")
SOLVER_KEYS = ("method", "tol", "max_iter", "starts", "seed")
OUTPUT_KEYS = ("rate",)

MAX_SAMPLES = 1_000_000  # output samples T·rate + 1: beyond this CSV and MCAP reach hundreds of MB
MAX_ELEMENTS = 100_000  # beyond this the quadrature arrays alone exceed a workstation's memory
DEFAULT_TOL = 1e-10
DEFAULT_MAX_ITER = 5000
DEFAULT_RATE = 100.0
DEFAULT_GRAVITY = (0.0, 0.0, -9.81)


# ------------------------------------------------------------------ key checkers (file and CLI)
def check_T(c: Checker, value: Any, key: str, what: str = "a duration T > 0 in seconds") -> float:
    """The duration T (s), > 0 and at least ``MIN_T``."""
    T = c.number(value, key, positive=True, what=what)
    if T < MIN_T:
        raise c.fail(key, f"{what}, at least {MIN_T:g} s (a physical duration)", T)
    return T


def check_N(c: Checker, value: Any, key: str) -> int:
    """The number of elements, 1 ... ``MAX_ELEMENTS``."""
    return c.integer(value, key, 1, MAX_ELEMENTS)


def check_order(c: Checker, value: Any, key: str) -> str:
    """The element order: quintic or cubic."""
    return c.choice(value, key, ORDERS)


def check_cost(c: Checker, value: Any, key: str) -> str:
    """The cost: covariant or torque."""
    return c.choice(value, key, COSTS)


def check_method(c: Checker, value: Any, key: str) -> str:
    """The optimiser: pr-cg or newton."""
    return c.choice(value, key, METHODS)


def check_tol(c: Checker, value: Any, key: str) -> float:
    """The solver tolerance, > 0."""
    return c.number(value, key, positive=True, what="a tolerance > 0")


def check_max_iter(c: Checker, value: Any, key: str) -> int:
    """The iteration limit, >= 1."""
    return c.integer(value, key, 1)


def check_rate(c: Checker, value: Any, key: str) -> float:
    """The output sample rate (Hz), > 0."""
    return c.number(value, key, positive=True, what="a sample rate > 0 in Hz")


def check_samples(c: Checker, T: float, rate: float, key: str) -> None:
    """The output holds at most ``MAX_SAMPLES`` samples (a check across the time and output sections)."""
    if T * rate + 1 > MAX_SAMPLES:
        raise c.error(key, f"T·rate = {T:g} s × {rate:g} Hz gives more than {MAX_SAMPLES} output samples "
                      "(expected a lower output.rate or a shorter T)")


# ------------------------------------------------------------------ robot: robot, joints, locked, gravity
@dataclass(frozen=True)
class RobotSpec:
    """The URDF, the planned joints (None: every non-fixed joint), locked positions and gravity (m/s²)."""

    robot: Path
    joints: tuple[str, ...] | None = None
    locked: dict[str, float] = field(default_factory=dict)
    gravity: tuple[float, float, float] = DEFAULT_GRAVITY


def path_exists(path: Path) -> bool:
    """Whether ``path`` exists; False (not an OSError) for a name the system cannot look up (too long...)."""
    try:
        path.stat()
    except (OSError, ValueError):
        return False
    return True


def parse_robot(c: Checker, top: dict, parsed: dict) -> RobotSpec:
    """``robot`` (relative to the task file), ``joints``, ``locked``, ``gravity``."""
    robot = top["robot"]
    if not isinstance(robot, str) or not robot.strip():
        raise c.fail("robot", "a path to a URDF file (string)", robot)
    robot_path = Path(robot)
    if not robot_path.is_absolute():
        robot_path = c.path.parent / robot_path
    problem = file_problem(robot_path)
    if problem is not None and problem.startswith("file not found"):
        raise c.error("robot", f"URDF file not found: {str(robot_path)[:200]!r}")
    if problem is not None:
        raise c.error("robot", f"{str(robot_path)[:200]!r} {problem} (expected a URDF file)")

    joints = None
    if top.get("joints") is not None:
        j = top["joints"]
        if not isinstance(j, list) or not j or not all(isinstance(x, str) for x in j):
            raise c.fail("joints", "a non-empty list of joint names", j)
        if len(set(j)) != len(j):
            seen: set[str] = set()
            dup = next(x for x in j if x in seen or seen.add(x))  # type: ignore[func-returns-value]
            raise c.error("joints", f"expected distinct joint names, got {show(dup)} twice")
        joints = tuple(j)

    locked: dict[str, float] = {}
    if top.get("locked") is not None:
        lk = c.names(top["locked"], "locked", "a mapping joint -> position")
        for name, v in lk.items():
            if joints is not None and name in joints:
                raise c.error(join("locked", name), "joint is both in 'joints' and 'locked'")
            locked[name] = c.physical(v, join("locked", name))

    gravity = DEFAULT_GRAVITY
    if top.get("gravity") is not None:
        g = top["gravity"]
        if not isinstance(g, list) or len(g) != 3:
            raise c.fail("gravity", "a list of 3 numbers (m/s^2)", g)
        gravity = tuple(c.physical(v, f"gravity[{i}]") for i, v in enumerate(g))  # type: ignore[assignment]
    return RobotSpec(robot=robot_path, joints=joints, locked=locked, gravity=gravity)


# ------------------------------------------------------------------ boundary: x0, x1
@dataclass(frozen=True)
class State:
    """A state given in the task: q and dq as lists (task joint order) or name → value mappings."""

    q: Values
    dq: Values | None


@dataclass(frozen=True)
class BoundarySpec:
    """The start state x0 and the goal x1 (None: no goal, allowed for ``hoc simulate``)."""

    x0: State
    x1: State | LinkGoal | None = None


def _state(c: Checker, value: Any, key: str) -> State:
    m = c.mapping(value, key, STATE_KEYS)
    if "q" not in m:
        raise c.error(f"{key}.q", "missing required key 'q'")
    q = c.values(m["q"], f"{key}.q")
    dq = c.values(m["dq"], f"{key}.dq") if m.get("dq") is not None else None
    return State(q=q, dq=dq)


def _goal(c: Checker, value: Any, key: str) -> State | LinkGoal:
    """The goal x1: a joint state, or a link's pose ``{link: ...}`` (``hoc_cli.io.task.goals``)."""
    if isinstance(value, dict) and "link" in value:
        return parse_link_goal(c, value, key)
    return _state(c, value, key)


def parse_boundary(c: Checker, top: dict, parsed: dict) -> BoundarySpec:
    """``x0`` (required) and ``x1`` (a joint state, or absent)."""
    x0 = _state(c, top["x0"], "x0")
    x1 = _goal(c, top["x1"], "x1") if top.get("x1") is not None else None
    return BoundarySpec(x0=x0, x1=x1)


# ------------------------------------------------------------------ time: T, N, order, accuracy
DEFAULT_ACCURACY = 1e-8  # N: auto refines until the estimated relative error of J is at most this


@dataclass(frozen=True)
class TimeSpec:
    """The duration T (s) and its discretisation: N elements of the given order.

    N is None for ``N: auto`` (also when the task gives no N): the mesh is refined until the
    estimated relative error of J is at most ``accuracy`` (None with a fixed N).
    With ``free`` (``T: {free: true, ...}``) T is the starting duration of the search.
    """

    T: float
    N: int | None
    order: str = "quintic"
    accuracy: float | None = None
    free: FreeTime | None = None


def check_accuracy(c: Checker, value: Any, key: str) -> float:
    """The target relative error of J for ``N: auto``, in (0, 1)."""
    x = c.number(value, key, positive=True, what="a relative accuracy in (0, 1), e.g. 1.0e-8")
    if x >= 1:
        raise c.fail(key, "a relative accuracy in (0, 1), e.g. 1.0e-8", value)
    return x


def _mesh(c: Checker, top: dict) -> tuple[int | None, float | None]:
    """(N, accuracy) from ``N`` (an integer, ``auto`` or absent) and ``accuracy``."""
    N = top.get("N", "auto")
    if N == "auto":
        return None, check_accuracy(c, top.get("accuracy", DEFAULT_ACCURACY), "accuracy")
    N = check_N(c, N, "N")  # the same message as -N's (a string other than auto is refused here)
    if "accuracy" in top:
        raise c.error("accuracy", f"applies to N: auto only (N is {N}; expected N: auto, or no accuracy)")
    return N, None


def parse_time(c: Checker, top: dict, parsed: dict) -> TimeSpec:
    """``T`` (a fixed duration, or ``{free: true, min, max, guess, weight}``), ``N`` (or ``auto``) with
    ``accuracy``, ``order``.
    """
    if isinstance(top["T"], dict):
        free = parse_free_time(c, top["T"], "T")
        T = free.guess if free.guess is not None else (free.min * free.max) ** 0.5
        if top.get("N", "auto") == "auto":
            raise c.error("N", "a free T needs a fixed number of elements (expected an integer N >= 1, not auto)")
        return TimeSpec(T=T, N=check_N(c, top["N"], "N"), order=check_order(c, top.get("order", "quintic"), "order"),
                        free=free)
    T = check_T(c, top["T"], "T")
    N, accuracy = _mesh(c, top)
    order = check_order(c, top.get("order", "quintic"), "order")
    return TimeSpec(T=T, N=N, order=order, accuracy=accuracy)


def parse_cost(c: Checker, top: dict, parsed: dict) -> str:
    """``cost``: covariant (default) or torque."""
    return check_cost(c, top.get("cost", "covariant"), "cost")


# ------------------------------------------------------------------ solver, output
@dataclass(frozen=True)
class SolverSpec:
    """The optimiser, its tolerance and iteration limit; multi-start: ``starts`` solves, perturbations seeded by ``seed``."""

    method: str = "pr-cg"
    tol: float = DEFAULT_TOL
    max_iter: int = DEFAULT_MAX_ITER
    starts: int = 1
    seed: int = 0


def parse_solver(c: Checker, top: dict, parsed: dict) -> SolverSpec:
    """``solver: {method, tol, max_iter, starts, seed}`` (every key optional)."""
    if top.get("solver") is None:
        return SolverSpec()
    s = c.mapping(top["solver"], "solver", SOLVER_KEYS)
    defaults = SolverSpec()
    return SolverSpec(
        method=check_method(c, s.get("method", defaults.method), "solver.method"),
        tol=check_tol(c, s["tol"], "solver.tol") if "tol" in s else defaults.tol,
        max_iter=check_max_iter(c, s["max_iter"], "solver.max_iter") if "max_iter" in s else defaults.max_iter,
        starts=c.integer(s["starts"], "solver.starts", 1) if "starts" in s else defaults.starts,
        seed=c.integer(s["seed"], "solver.seed", 0) if "seed" in s else defaults.seed,
    )


@dataclass(frozen=True)
class OutputSpec:
    """The sample rate (Hz) of the CSV and MCAP outputs."""

    rate: float = DEFAULT_RATE


def parse_output(c: Checker, top: dict, parsed: dict) -> OutputSpec:
    """``output: {rate}``; the number of samples T·rate + 1 is bounded."""
    out = OutputSpec()
    if top.get("output") is not None:
        o = c.mapping(top["output"], "output", OUTPUT_KEYS)
        if "rate" in o:
            out = OutputSpec(rate=check_rate(c, o["rate"], "output.rate"))
    time = parsed["time"]
    check_samples(c, time.T if time.free is None else time.free.max, out.rate, "output.rate")
    return out


def parse_torque(c: Checker, top: dict, parsed: dict) -> str | Values | None:
    """``torque`` (for ``hoc simulate``): 'zero' or constant torques (N·m or N)."""
    tq = top.get("torque")
    if tq is None:
        return None
    if isinstance(tq, str):
        if tq != "zero":
            raise c.fail("torque", "'zero' or a list of constant torques (N·m or N)", tq)
        return "zero"
    return c.values(tq, "torque", physical=False)  # hoc simulate reports the overflow of a huge torque (exit 1)
