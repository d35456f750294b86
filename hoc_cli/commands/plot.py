"""``hoc plot FILE -o fig.png``: q, q̇ and u per joint against t, from a plan's CSV or MCAP.

The URDF limits are drawn when the file carries the URDF (an MCAP does, a CSV does not).
The figure is written atomically: on any failure the output path is left untouched.
"""
from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

from hoc_cli.commands.common import EXIT_OK, OutputTarget, atomic_output, refuse_inputs
from hoc_cli.errors import HocError, InputFileError, ModelError, OutputError

MCAP_MAGIC = b"\x89MCAP"
INSTALL_HINT = "matplotlib is needed for 'hoc plot' (install it with: pip install 'hoc[plot]')"


def run(file: Path, output: Path) -> int:
    """Read ``file`` (.csv or .mcap), draw the figure, write ``output`` (.png, .pdf or .svg)."""
    from hoc_cli.plotting import FORMATS, MatplotlibMissing, plot_trajectory

    fmt = output.suffix.lower().lstrip(".")
    if fmt not in FORMATS:
        raise OutputError(f"unknown figure extension {output.suffix or '(none)'!r} (expected .png, .pdf or .svg)",
                          file=output, key="--output")
    parent = output.parent if str(output.parent) else Path(".")
    if not parent.is_dir():
        raise OutputError(f"directory {str(parent)!r} does not exist", file=output, key="--output")
    refuse_inputs([OutputTarget(output, fmt)], {"the plotted file": file})
    try:
        import matplotlib  # noqa: F401  (checked before reading a possibly large input)
    except ImportError:
        raise HocError(INSTALL_HINT) from None

    traj, limits = read_for_plot(file)
    try:
        with atomic_output(output) as fh:
            plot_trajectory(traj, fh, fmt=fmt, limits=limits, title=file.name)
    except MatplotlibMissing:
        raise HocError(INSTALL_HINT) from None
    return EXIT_OK


def read_for_plot(file: Path):
    """(Trajectory, {joint: JointLimits}) from a CSV or an MCAP plan; limits only from an MCAP's URDF."""
    from hoc_cli.io.csv import read_csv
    from hoc_cli.io.mcap import read_plan

    if not file.is_file():
        raise InputFileError("file not found (expected a CSV or MCAP written by hoc)", file=file)
    with open(file, "rb") as fh:
        head = fh.read(len(MCAP_MAGIC))
    if head == MCAP_MAGIC or file.suffix.lower() == ".mcap":
        plan = read_plan(file)
        return plan.trajectory, urdf_limits(plan.urdf_text, plan.joints, source=file)
    return read_csv(file), {}


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
