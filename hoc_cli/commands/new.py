"""``hoc new ROBOT.urdf [-o task.yaml]``: a commented task template for a robot that plans as written.

The template lists the robot's movable joints in model order with their URDF limits as comments,
locks the master of any mimic joint (hoc holds mimic joints fixed, so moving their master would
break the coupling), and sets

- x0: a configuration inside the position limits (10 % of each range away from either end) where
  gravity loads the joints least, relative to their effort limits: each joint in turn takes the
  best of 9 values across its range, starting from 0 (clipped into the range);
- x1: x0 moved by a small step per joint (at most 0.3 rad or 0.05 m, a quarter of the range), towards
  the side with more room, inside the limits too;
- T from the velocity limits (at least 2 s), N = 16, quintic elements, the covariant cost and
  ``limits: {mode: enforce}``.

Default output: ``<robot stem>.yaml`` in the current directory (``-o -``: standard output). An
existing file is never replaced without ``--force``.
"""
from __future__ import annotations

import math
import os
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hoc_cli.commands.common import EXIT_OK
from hoc_cli.errors import HocWarning, OutputError
from hoc_cli.report.console import stderr_console
from hoc_cli.report.files import OutputTarget, atomic_output, check_output_directory, refuse_inputs

MARGIN = 0.1  # of each position range, kept free at either end for x0 and x1
STEP_RAD, STEP_M = 0.3, 0.05  # largest move per joint from x0 to x1
GRID = 9  # values tried per joint when looking for a low-gravity-load x0
UNBOUNDED_RAD, UNBOUNDED_M = math.pi, 0.1  # the range used for a joint without position limits
MIN_T, N_ELEMENTS = 2.0, 16
DIGITS = 3  # decimals written for q values


@dataclass(frozen=True)
class Template:
    """What ``hoc new`` decided: joints, locked masters, x0, x1 (n,), T [s]."""

    joints: tuple[str, ...]
    locked: dict[str, float]
    q0: np.ndarray
    q1: np.ndarray
    T: float
    gravity_load: float  # max |g_i(q0)| / effort_i


def run(urdf: Path, output: str | None = None, *, force: bool = False, quiet: bool = False) -> int:
    from hoc_cli.model import load_robot, urdf_joint_table

    urdf = Path(urdf)
    rows = urdf_joint_table(urdf)  # reads and checks the URDF: a bad file is one line, exit 2
    to_stdout = output == "-"
    path = None if to_stdout else Path(output or f"{urdf.stem}.yaml")
    if path is not None:
        if path.suffix.lower() not in (".yaml", ".yml"):
            raise OutputError(f"unknown extension {path.suffix or '(none)'!r} (expected .yaml, or - for standard output)",
                              file=path, key="--output")
        check_output_directory(path)
        if path.exists() and not force:
            raise OutputError("exists; hoc new never replaces a file (expected --force, or another -o)", file=path,
                              key="--output")
        refuse_inputs([OutputTarget(path, "yaml")], {"the URDF": urdf})
    masters = {r["mimic"] for r in rows if r["mimic"]}
    table = {r["name"]: r for r in rows}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", HocWarning)
        every = load_robot(urdf)
    joints = [j for j in every.joint_names if j not in masters]
    if not joints:
        raise OutputError("has no movable joint to plan (every movable joint is a mimic joint or its master)",
                          file=urdf, key="joints")
    locked = {m: _inside(0.0, table[m]["lower"], table[m]["upper"]) for m in every.joint_names if m in masters}
    model = load_robot(urdf, joints=joints, locked=locked)
    template = choose(model, locked)
    where = Path(".") if path is None else (path.parent if str(path.parent) else Path("."))
    target, here = urdf.resolve(), where.resolve()
    # relative to the task file (as the task format wants), unless the two share nothing but the root
    robot_ref = (Path(os.path.relpath(target, here)).as_posix() if os.path.commonpath([target, here]) != os.sep
                 else target.as_posix())
    text = render(template, model, table, robot_ref, urdf.name, "task.yaml" if path is None else str(path))
    if path is None:
        sys.stdout.write(text)
        sys.stdout.flush()
        return EXIT_OK
    with atomic_output(path) as fh:
        fh.write(text.encode("utf-8"))
    stderr_console(quiet=quiet).print(f"wrote {path}; plan it with: hoc plan {path}   (then edit x1, T and N)",
                                      highlight=False, markup=False, soft_wrap=True)
    return EXIT_OK


def _inside(value: float, lower: float | None, upper: float | None) -> float:
    lo = -math.inf if lower is None else lower
    hi = math.inf if upper is None else upper
    return float(min(max(value, lo), hi))


def safe_ranges(model) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) (n,): each joint's position range shrunk by MARGIN at either end (finite for every joint)."""
    prismatic = model.is_prismatic
    wide = np.where(prismatic, UNBOUNDED_M, UNBOUNDED_RAD)
    lower = np.where(np.isfinite(model.lower), model.lower, -wide)
    upper = np.where(np.isfinite(model.upper), model.upper, wide)
    # one-sided limits: a range of the default width from the given end
    lower = np.where(np.isfinite(model.lower) | ~np.isfinite(model.upper), lower, upper - 2 * wide)
    upper = np.where(np.isfinite(model.upper) | ~np.isfinite(model.lower), upper, lower + 2 * wide)
    span = upper - lower
    return lower + MARGIN * span, upper - MARGIN * span


def gravity_load(system, effort: np.ndarray, q: np.ndarray) -> np.ndarray:
    """max_i |g_i(q)| / effort_i for configurations q (K, n); 0 for joints without an effort limit."""
    zeros = np.zeros_like(q)
    g = np.abs(system.inverse_dynamics(q, zeros, zeros))
    return np.max(np.where(np.isfinite(effort), g / effort, 0.0), axis=1)


def choose(model, locked: dict[str, float]) -> Template:
    """x0 (least gravity load inside the safe ranges, rounded), x1 (a small step from x0) and T."""
    from hoc_cli.system import RobotSystem

    system = RobotSystem(model)
    effort = np.asarray(model.effort_limit, dtype=float)
    lo, hi = safe_ranges(model)
    lo_r, hi_r = np.ceil(lo * 10**DIGITS) / 10**DIGITS, np.floor(hi * 10**DIGITS) / 10**DIGITS
    q = np.clip(np.zeros(model.n), lo_r, hi_r)
    best = gravity_load(system, effort, q[None])[0]
    for _ in range(2):  # coordinate sweeps; ties keep the value nearer 0
        for i in range(model.n):
            trial = np.repeat(q[None], GRID, axis=0)
            trial[:, i] = np.round(np.linspace(lo_r[i], hi_r[i], GRID), DIGITS)
            load = gravity_load(system, effort, trial)
            k = int(np.argmin(load + 1e-9 * np.abs(trial[:, i])))
            if load[k] < best - 1e-12:
                q, best = trial[k], load[k]
    q0 = np.clip(np.round(q, DIGITS), lo_r, hi_r)
    step = np.minimum(np.where(model.is_prismatic, STEP_M, STEP_RAD), 0.25 * (hi_r - lo_r))
    direction = np.where(hi_r - q0 >= q0 - lo_r, 1.0, -1.0)
    q1 = np.clip(np.round(q0 + direction * step, DIGITS), lo_r, hi_r)
    # rest to rest with a quintic profile peaks at 1.875 d / T: stay under half of each velocity limit
    velocity = np.asarray(model.velocity_limit, dtype=float)
    needed = np.max(np.where(np.isfinite(velocity), 2 * 1.875 * np.abs(q1 - q0) / velocity, 0.0), initial=0.0)
    T = max(MIN_T, math.ceil(needed * 2) / 2)
    return Template(tuple(model.joint_names), dict(locked), q0, q1, float(T), float(best))


def _num(x: float | None) -> str:
    if x is None or not math.isfinite(x):
        return "none"
    return f"{x:.6g}"


def render(t: Template, model, table: dict, robot_ref: str, urdf_name: str, task_name: str = "task.yaml") -> str:
    """The commented YAML text of the template."""
    units = {True: ("m", "m/s", "N"), False: ("rad", "rad/s", "N·m")}
    width = max(len(j) for j in (*t.joints, *t.locked, "joint"))
    lines = [
        f"# hoc task for robot {model.name!r} ({urdf_name}), written by `hoc new`. It plans as written:",
        f"#     hoc plan {task_name}",
        "# Then edit x1 (the goal), T and N. Every key is described in hoc's README (Task file).",
        "#",
        "# Joints, in the order of `joints:` (the URDF's limits; `limits:` below can narrow them):",
        f"#   {'joint':<{width}}  type        position [lower, upper]      velocity      effort",
    ]
    for j in t.joints:
        r = table[j]
        u = units[r["type"] == "prismatic"]
        pos = f"[{_num(r['lower'])}, {_num(r['upper'])}] {u[0]}"
        lines.append(f"#   {j:<{width}}  {r['type']:<10}  {pos:<27}  {_num(r['velocity']) + ' ' + u[1]:<13} "
                     f"{_num(r['effort'])} {u[2]}")
    lines += [f"robot: {robot_ref}", f"joints: [{', '.join(t.joints)}]"]
    if t.locked:
        lines.append("# masters of mimic joints: hoc holds mimic joints fixed, so their masters are locked too")
        lines.append("locked: {" + ", ".join(f"{k}: {v:g}" for k, v in t.locked.items()) + "}")
    lines.append(f"gravity: [{', '.join(f'{g:g}' for g in model.gravity)}]   # m/s², in the URDF root frame")
    prismatic = dict(zip(model.joint_names, model.is_prismatic))
    for key, q, note in (
        ("x0", t.q0, "start, at rest (dq: zeros unless given): inside the limits, with a small gravity load"),
        ("x1", t.q1, "goal, at rest: EDIT ME (now a small step from x0)"),
    ):
        lines += [f"{key}:   # {note}", "  q:"]
        for j, v in zip(t.joints, q):
            r = table[j]
            unit = "m" if prismatic[j] else "rad"
            lines.append(f"    {j + ':':<{width + 1}} {v:>8.{DIGITS}f}   # {unit}, limits [{_num(r['lower'])}, {_num(r['upper'])}]")
    lines += [
        f"{'T: ' + format(t.T, 'g'):<23} # s: the duration (a faster move needs more torque)",
        f"{'N: ' + str(N_ELEMENTS):<23} # elements: more is finer and slower",
        "order: quintic          # quintic (C², default) | cubic (C¹)",
        "cost: covariant         # covariant (½ uᵀM⁻¹u) | torque (½ uᵀu)",
        "limits:",
        "  mode: enforce         # enforce: the plan respects every URDF limit | report: violations are only reported",
        "  # velocity: {joint: 1.0}   # per-joint overrides of the URDF's limits; also position, acceleration, effort",
        "  # scale: {velocity: 0.5}   # 0 < s <= 1 on every joint's velocity, acceleration or effort limit",
        "# solver: {method: pr-cg, tol: 1.0e-10, max_iter: 5000}",
        "# output: {rate: 100}   # samples per second in the CSV and MCAP outputs",
    ]
    return "\n".join(lines) + "\n"
