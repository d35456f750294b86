"""``hoc plot FILE… -o fig.png``: q, q̇ and u per joint against t, from plans' CSV or MCAP files.

An MCAP of a plan checked for collisions adds its clearance against t (/collision_clearance) in a panel
under the joints', with the margin of its summary's ``min_clearance``.

One row of panels per joint, each with that joint's limits and units (``--normalized``: every
joint divided by its limits in three panels). Several files are overlaid with a legend naming
each; they must have the same joints. The limits come from ``--robot ROBOT.urdf``, else from the
first MCAP (it carries its URDF); with neither (CSV files alone) the figure says limits are unknown.
The figure is written atomically: on any failure the output path is left untouched.
"""
from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

from hoc_cli.commands.common import EXIT_OK
from hoc_cli.errors import HocError, InputFileError, ModelError, OutputError
from hoc_cli.report.files import OutputTarget, atomic_output, check_output_directory, refuse_inputs

MCAP_MAGIC = b"\x89MCAP"
INSTALL_HINT = "matplotlib is needed for 'hoc plot' (install it with: pip install 'hoc[plot]')"


def run(files: Path | list[Path], output: Path, *, robot: Path | None = None, normalized: bool = False) -> int:
    """Read each file (.csv or .mcap), draw the figure, write ``output`` (.png, .pdf or .svg)."""
    from hoc_cli.plotting import FORMATS, NO_LIMITS_NOTE, MatplotlibMissing, plot_trajectories

    files = [Path(files)] if isinstance(files, (str, Path)) else [Path(f) for f in files]
    fmt = output.suffix.lower().lstrip(".")
    if fmt not in FORMATS:
        raise OutputError(f"unknown figure extension {output.suffix or '(none)'!r} (expected .png, .pdf or .svg)",
                          file=output, key="--output")
    check_output_directory(output)
    refuse_inputs([OutputTarget(output, fmt)], {**{f"the plotted file {i + 1}": f for i, f in enumerate(files)},
                                                "--robot": robot})
    try:
        import matplotlib  # noqa: F401  (checked before reading a possibly large input)
    except ImportError:
        raise HocError(INSTALL_HINT) from None

    runs, limits, clearance, margins = [], None, {}, []
    for f in files:
        traj, found, clear, margin = read_plot_inputs(f)
        if runs and tuple(traj.joints) != tuple(runs[0][1].joints):
            raise InputFileError(f"has joints {list(traj.joints)}; {files[0]} has {list(runs[0][1].joints)} "
                                 "(expected files of the same robot and joints to overlay)", file=f)
        runs.append((_label(f, files), traj))
        if clear is not None:
            clearance[runs[-1][0]] = clear
            margins += [margin] if margin is not None else []
        if limits is None and found:
            limits = found
    if robot is not None:
        limits = robot_limits(robot, runs[0][1].joints)
    note = None if limits else NO_LIMITS_NOTE
    title = " vs ".join(label for label, _ in runs)
    try:
        with atomic_output(output) as fh:
            plot_trajectories(runs, fh, fmt=fmt, limits=limits, limits_note=note, normalized=normalized, title=title,
                              clearance=clearance, margin=max(margins) if margins else None)
    except MatplotlibMissing:
        raise HocError(INSTALL_HINT) from None
    return EXIT_OK


def _label(f: Path, files: list[Path]) -> str:
    """The file's name, or its path when two files share a name."""
    return f.name if sum(g.name == f.name for g in files) == 1 else str(f)


def robot_limits(robot: Path, joints) -> dict:
    """{joint: JointLimits} from a URDF file given with ``--robot``; InputFileError when it names none of ``joints``."""
    from hoc_cli.model import urdf_joint_table
    from hoc_cli.plotting import JointLimits

    rows = urdf_joint_table(robot)
    found = {r["name"]: JointLimits(r["lower"], r["upper"], r["velocity"], r["effort"], r["type"] == "prismatic")
             for r in rows if r["name"] in set(joints)}
    if not found:
        raise InputFileError(f"has none of the plotted joints {list(joints)}", file=robot, key="--robot")
    return found


def read_for_plot(file: Path):
    """(Trajectory, {joint: JointLimits}) from a CSV or an MCAP plan; limits only from an MCAP's URDF."""
    return read_plot_inputs(file)[:2]


def read_plot_inputs(file: Path):
    """(Trajectory, {joint: JointLimits}, clearance (K,) m or None, margin m or None) from a CSV or an MCAP plan;
    limits only from an MCAP's URDF, the clearance from its /collision_clearance and the margin from its summary.
    """
    from hoc_cli.io.csv import read_csv
    from hoc_cli.io.mcap import read_plan

    if not file.is_file():
        raise InputFileError("file not found (expected a CSV or MCAP written by hoc)", file=file)
    with open(file, "rb") as fh:
        head = fh.read(len(MCAP_MAGIC))
    if head == MCAP_MAGIC or file.suffix.lower() == ".mcap":
        plan = read_plan(file)
        limits = with_task_jerk(urdf_limits(plan.urdf_text, plan.joints, source=file), plan.task_text)
        return plan.trajectory, limits, plan.clearance, _summary_margin(plan.metadata)
    return read_csv(file), {}, None, None


def _summary_margin(metadata: dict) -> float | None:
    """The collision margin (m) in an MCAP's summary metadata (``min_clearance.margin``), None without it."""
    import json

    try:
        margin = (json.loads(metadata.get("summary") or "{}").get("min_clearance") or {}).get("margin")
    except (ValueError, AttributeError):
        return None
    return float(margin) if isinstance(margin, (int, float)) else None


def with_task_jerk(limits: dict, task_text: str) -> dict:
    """``limits`` with the jerk limits of the plan's task (``limits.jerk`` times ``limits.scale.jerk``) added."""
    import dataclasses

    from hoc_cli.io.task import load_yaml

    try:
        doc = load_yaml(task_text)
        section = doc.get("limits") or {}
        jerk = section.get("jerk") or {}
        scale = float((section.get("scale") or {}).get("jerk", 1.0))
    except Exception:  # a plan's task was checked when it was planned: an unreadable one only loses the jerk panel
        return limits
    out = dict(limits)
    for joint, value in jerk.items():
        if joint in out and isinstance(value, (int, float)) and value > 0:
            out[joint] = dataclasses.replace(out[joint], jerk=float(value) * scale)
    return out


def urdf_limits(urdf_text: str, joints, source: Path) -> dict:
    """{joint: JointLimits} for ``joints`` from a URDF document; {} (with a warning) if it cannot be parsed."""
    from hoc_cli.model import urdf_joint_table
    from hoc_cli.plotting import JointLimits

    fd, tmp = tempfile.mkstemp(suffix=".urdf")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(urdf_text)
        rows = urdf_joint_table(tmp)
    except ModelError as exc:
        sys.stderr.write(f"hoc: warning: {source}: the attached URDF cannot be read ({exc.detail}); limits not drawn\n")
        return {}
    finally:
        os.unlink(tmp)
    wanted = set(joints)
    return {r["name"]: JointLimits(r["lower"], r["upper"], r["velocity"], r["effort"], r["type"] == "prismatic")
            for r in rows if r["name"] in wanted}
