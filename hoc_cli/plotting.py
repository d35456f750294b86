"""The figure of ``hoc plot``: q, q̇ and u of every joint against t, with the URDF's limits.

Two layouts:

- per joint (default): one row of three panels (q, q̇, u) per joint (four, with the jerk q⃛, when a
  jerk limit is known and the trajectory carries its quintic Hermite coefficients), each in that joint's units
  (rad, rad/s, N·m; m, m/s, N for a prismatic joint) with that joint's limits only, as red dashed
  lines. A limit within the view (the data's span either side of it) is drawn; one farther out is
  named in the panel's corner ("limits ±320 N·m off scale") instead of flattening the curve.
- normalised (``normalized=True``): three panels, each joint's value divided by its limit, so
  ±1 (dashed) is every limit: q as 2(q − mid)/(upper − lower), q̇ / velocity limit, u / effort
  limit. Joints without that limit are left out of that panel, and the panel says which.

A plan checked for collisions (an MCAP with /collision_clearance) adds a bottom panel across the figure:
the smallest signed distance of any checked pair against t [m], with the task's margin (black, dashed)
and the region below zero shaded.

Several trajectories (e.g. two plans of the same task) are overlaid, one colour (per-joint layout)
or line style (normalised layout) per trajectory, with a legend naming each. When no limits are
known (a CSV carries no URDF) the figure says so.

matplotlib is an optional dependency (``pip install 'hoc[plot]'``); it is imported here only,
lazily, with the non-interactive Agg canvas (no display, no pyplot global state).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import IO, Mapping, Sequence

import numpy as np

from hoc_cli.trajectory import Trajectory

FORMATS = ("png", "pdf", "svg")
LIMIT_STYLE = dict(color="tab:red", ls="--", lw=1.0, alpha=0.9)
FILE_STYLES = ("-", "--", ":", "-.")
#: one colour per overlaid file in the per-joint layout: matplotlib's cycle without red (the limits' colour)
FILE_COLOURS = ("C0", "C1", "C2", "C4", "C5", "C6", "C8", "C9")
CLEARANCE_HEIGHT = 2.2  # inches of the clearance panel

NO_LIMITS_NOTE = "limits unknown: a CSV carries no URDF (give --robot ROBOT.urdf to draw them)"


@dataclass(frozen=True)
class JointLimits:
    """Limits of one joint as the URDF gives them; None where it gives none.

    lower, upper: rad (m for prismatic); velocity: rad/s (m/s); effort: N·m (N); jerk: rad/s³ (m/s³),
    from the task's ``limits.jerk`` (a URDF has none).
    """

    lower: float | None = None
    upper: float | None = None
    velocity: float | None = None
    effort: float | None = None
    prismatic: bool | None = None
    jerk: float | None = None


class MatplotlibMissing(ImportError):
    """matplotlib is not installed."""


def _matplotlib():
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise MatplotlibMissing(str(exc)) from None
    return Figure, FigureCanvasAgg


QUANTITIES = (  # (attribute, panel title, units (revolute, prismatic))
    ("q", "position $q$", ("rad", "m")),
    ("dq", r"velocity $\dot{q}$", ("rad/s", "m/s")),
    ("u", "effort $u$", ("N·m", "N")),
)
JERK = ("jerk", r"jerk $\dddot{q}$", ("rad/s³", "m/s³"))  # a fourth panel where a jerk limit is known


def values(traj: Trajectory, quantity: str, joint: int) -> np.ndarray | None:
    """The joint's samples (K,) of ``quantity``; the jerk from the exact quintic coefficients (None without them)."""
    if quantity != "jerk":
        return np.asarray(getattr(traj, quantity), dtype=float)[:, joint]
    if traj.mesh is None or traj.coeffs is None or traj.mesh.order != "quintic":
        return None
    return traj.mesh.evaluate(traj.coeffs, np.asarray(traj.t, dtype=float), 3)[:, joint]


def quantities(runs, limits: Mapping[str, JointLimits]) -> tuple:
    """The panels' quantities: q, q̇, u, and the jerk when some joint has a jerk limit and a run its coefficients."""
    jerk = any(L is not None and L.jerk is not None for L in limits.values()) and any(
        values(traj, "jerk", 0) is not None for _, traj in runs)
    return QUANTITIES + ((JERK,) if jerk else ())


def bounds(L: JointLimits | None, quantity: str) -> tuple[float | None, float | None]:
    """(lower, upper) limit of ``quantity`` ("q" | "dq" | "u") for a joint; None where unknown or infinite."""
    if L is None:
        return None, None
    lo, hi = {"q": (L.lower, L.upper),
              "dq": (None if L.velocity is None else -L.velocity, L.velocity),
              "u": (None if L.effort is None else -L.effort, L.effort),
              "jerk": (None if L.jerk is None else -L.jerk, L.jerk)}[quantity]
    finite = lambda x: x if x is not None and np.isfinite(x) else None
    return finite(lo), finite(hi)


def _view(data: np.ndarray, limits: Sequence[float]) -> tuple[tuple[float, float], list[float], list[float]]:
    """Y range, the limits drawn (within one data span of the data) and those left off scale."""
    lo, hi = float(np.min(data)), float(np.max(data))
    span = max(hi - lo, 1e-3 * max(abs(lo), abs(hi)), 1e-9)
    shown, off = [], []
    for b in limits:
        (shown if lo - span <= b <= hi + span else off).append(b)
    for b in shown:
        lo, hi = min(lo, b), max(hi, b)
    pad = 0.06 * (hi - lo if hi > lo else span)
    return (lo - pad, hi + pad), shown, off


def off_scale_note(off: list[float], shown: list[float], data: np.ndarray, unit: str) -> str:
    """What a panel says about limits too far from its data to draw, e.g. "limits ±320 N·m off scale (peak 23 %)"."""
    if len(off) == 2 and off[0] == -off[1]:
        peak = float(np.max(np.abs(data))) / abs(off[0])
        return f"limits ±{abs(off[0]):.4g} {unit} off scale (peak {100 * peak:.0f} %)"
    if len(off) == 2:
        return f"limits [{min(off):.4g}, {max(off):.4g}] {unit} off scale"
    return f"limit {off[0]:.4g} {unit} off scale"


def normalise(traj: Trajectory, quantity: str, joint: int, L: JointLimits | None) -> np.ndarray | None:
    """The joint's ``quantity`` divided by its limit (±1 at the limits), or None without that limit."""
    x = values(traj, quantity, joint)
    lo, hi = bounds(L, quantity)
    if x is None or lo is None or hi is None or hi <= lo:
        return None
    return (2.0 * x - (lo + hi)) / (hi - lo)


def plot_trajectories(
    runs: Sequence[tuple[str, Trajectory]],
    out: IO[bytes],
    *,
    fmt: str = "png",
    limits: Mapping[str, JointLimits] | None = None,
    limits_note: str | None = None,
    normalized: bool = False,
    title: str = "",
    dpi: int = 110,
    clearance: Mapping[str, np.ndarray] | None = None,
    margin: float | None = None,
) -> None:
    """Draw one or more trajectories (label, Trajectory with t (K,) s; q, dq, u (K, n)) and save to ``out``.

    Every trajectory must have the same joints. ``limits`` maps joint → JointLimits (missing:
    unknown). ``limits_note`` is written under the title (e.g. why no limits are drawn).
    ``clearance`` maps a run's label to its smallest pair distance (K,) m at its samples: a panel of
    those runs under the others, with ``margin`` (m) drawn when given. Raises
    MatplotlibMissing if matplotlib is not installed, ValueError for an unknown ``fmt`` or
    trajectories whose joints differ.
    """
    if fmt not in FORMATS:
        raise ValueError(f"figure format {fmt!r} is not one of {FORMATS}")
    if not runs:
        raise ValueError("nothing to plot")
    joints = list(runs[0][1].joints)
    for label, traj in runs[1:]:
        if list(traj.joints) != joints:
            raise ValueError(f"{label} has joints {list(traj.joints)}, the first file {joints}")
    Figure, FigureCanvasAgg = _matplotlib()
    limits = dict(limits or {})
    clearance = {label: np.asarray(d, dtype=float) for label, d in (clearance or {}).items()}
    draw = _draw_normalised if normalized else _draw_per_joint
    fig = draw(Figure, runs, joints, limits, extra=bool(clearance))
    if clearance:
        _draw_clearance(fig.axes[-1], runs, clearance, margin)  # the extra axis is the last one made
    FigureCanvasAgg(fig)
    heading = title
    if limits_note:
        heading = f"{title}\n{limits_note}" if title else limits_note
    if heading:
        fig.suptitle(heading, fontsize="medium")
    t_all = np.concatenate([np.asarray(tr.t, dtype=float) for _, tr in runs])
    for ax in fig.axes:
        if t_all.max() > t_all.min():
            ax.set_xlim(t_all.min(), t_all.max())
    fig.savefig(out, format=fmt, dpi=dpi, metadata={"Software": "hoc"} if fmt == "png" else None)


def _grid(fig, rows: int, cols: int, heights: list[float], extra: bool):
    """Axes (rows, cols) sharing x, and (``extra``) one more axis across the bottom (else None)."""
    grid = fig.add_gridspec(rows + extra, cols, height_ratios=heights + ([CLEARANCE_HEIGHT] if extra else []))
    axes = np.empty((rows, cols), dtype=object)
    for i in range(rows):
        for c in range(cols):
            axes[i, c] = fig.add_subplot(grid[i, c], sharex=axes[0, 0] if (i or c) else None)
    below = fig.add_subplot(grid[rows, :], sharex=axes[0, 0]) if extra else None
    for ax in axes[:-1].ravel():
        ax.tick_params(labelbottom=False)
    return axes, below


def _draw_clearance(ax, runs, clearance: Mapping[str, np.ndarray], margin: float | None) -> None:
    """The clearance panel: each run's smallest pair distance [m] against t, the margin, the region below 0."""
    shown = []
    for r, (label, traj) in enumerate(runs):
        if label in clearance:
            d = clearance[label]
            ax.plot(traj.t, d, color=FILE_COLOURS[r % len(FILE_COLOURS)], lw=1.3, label=label)
            shown.append(d)
    d = np.concatenate(shown)
    lo, hi = min(0.0, float(d.min())), max(float(d.max()), margin or 0.0)
    if margin is not None:
        ax.axhline(margin, color="k", ls="--", lw=0.9, label=f"margin {margin:g} m")
    ax.axhspan(-1.0e3, 0.0, color="tab:red", alpha=0.08, lw=0)  # in collision (clipped by the view below)
    pad = 0.05 * (hi - lo or 1.0)
    ax.set_ylim(lo - pad, hi + pad)
    ax.set_ylabel("[m]", fontsize="x-small")
    ax.set_title("clearance: smallest signed distance of any checked pair", fontsize="medium")
    ax.set_xlabel("t [s]")
    ax.grid(True, alpha=0.3)
    ax.tick_params(labelsize="x-small")
    if margin is not None:
        ax.legend(handles=[ax.lines[-1]], loc="upper right", fontsize="x-small")


def _draw_per_joint(Figure, runs, joints, limits, extra: bool = False):
    n = len(joints)
    panels = quantities(runs, limits)
    height = max(5.5, 1.2 + 1.5 * n)
    fig = Figure(figsize=(4.0 * len(panels), height + (CLEARANCE_HEIGHT if extra else 0.0)), layout="constrained")
    axes, _ = _grid(fig, n, len(panels), [1.0] * n, extra)
    many = len(runs) > 1
    for i, joint in enumerate(joints):
        L = limits.get(joint)
        known = L is not None and L.prismatic is not None
        for c, (quantity, name, units) in enumerate(panels):
            ax = axes[i, c]
            data = []
            for r, (label, traj) in enumerate(runs):
                y = values(traj, quantity, i)
                if y is None:  # no coefficients in this run: no jerk
                    continue
                ax.plot(traj.t, y, color=FILE_COLOURS[r % len(FILE_COLOURS)], lw=1.3, label=label)
                data.append(y)
            unit = units[bool(L.prismatic)] if known else f"{units[0]} or {units[1]}"
            lo, hi = bounds(L, quantity)
            (y0, y1), shown, off = _view(np.concatenate(data), [b for b in (lo, hi) if b is not None])
            for b in shown:
                ax.axhline(b, **LIMIT_STYLE)
            if off:
                ax.text(0.99, 0.96, off_scale_note(off, shown, np.concatenate(data), unit),
                        transform=ax.transAxes, ha="right", va="top", fontsize="x-small", color="tab:red",
                        zorder=1.5)  # under the curves (zorder 2): neither hides the other
            ax.set_ylim(y0, y1)
            ax.grid(True, alpha=0.3)
            ax.tick_params(labelsize="x-small")
            ax.set_ylabel(f"[{unit}]", fontsize="x-small")
            if i == 0:
                ax.set_title(name, fontsize="medium")
        axes[i, 0].annotate(joint, xy=(0, 0.5), xycoords="axes fraction", xytext=(-42, 0), textcoords="offset points",
                            ha="right", va="center", rotation=90, fontsize="small", fontweight="bold")
    for ax in axes[-1]:
        ax.set_xlabel("t [s]")
    handles = [axes[0, 0].lines[r] for r in range(len(runs))] if many else []
    labels = [label for label, _ in runs] if many else []
    if any(bounds(limits.get(j), q) != (None, None) for j in joints for q, _, _ in QUANTITIES):
        from matplotlib.lines import Line2D

        handles.append(Line2D([], [], **LIMIT_STYLE))
        labels.append("URDF limit" if len(panels) == len(QUANTITIES) else "URDF limit (jerk: the task's)")
    if handles:
        fig.legend(handles, labels, loc="outside lower center", ncol=min(len(handles), 4), fontsize="small")
    return fig


def _draw_normalised(Figure, runs, joints, limits, extra: bool = False):
    panels = quantities(runs, limits)
    fig = Figure(figsize=(11.0, 3.0 * len(panels) + (CLEARANCE_HEIGHT if extra else 0.0)), layout="constrained")
    grid, _ = _grid(fig, len(panels), 1, [3.0] * len(panels), extra)
    axes = grid[:, 0]
    for ax, (quantity, name, _) in zip(axes, panels):
        missing = []
        for i, joint in enumerate(joints):
            for r, (label, traj) in enumerate(runs):
                y = normalise(traj, quantity, i, limits.get(joint))
                if y is None:
                    if r == 0:
                        missing.append(joint)
                    continue
                ax.plot(traj.t, y, color=f"C{i % 10}", ls=FILE_STYLES[r % len(FILE_STYLES)], lw=1.3,
                        label=joint if r == 0 else None)
        for b in (-1.0, 1.0):  # black, and the region beyond shaded: no joint colour or file style is like it
            ax.axhline(b, color="k", lw=1.2)
            ax.axhspan(b, 50.0 * b, color="tab:red", alpha=0.08, lw=0)
        what = "(q − mid) / half range" if quantity == "q" else "/ limit"
        ax.set_ylabel(f"{name} {what}", fontsize="small")
        ax.grid(True, alpha=0.3)
        if missing:
            ax.text(0.01, 0.04, "no limit, not shown: " + ", ".join(missing), transform=ax.transAxes,
                    fontsize="x-small", color="0.3")
        data = [line.get_ydata() for line in ax.lines if len(line.get_ydata()) > 2]
        lo = min([-1.0, *(float(np.min(d)) for d in data)])
        hi = max([1.0, *(float(np.max(d)) for d in data)])
        ax.set_ylim(lo - 0.1, hi + 0.1)
    axes[-1].set_xlabel("t [s]")
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles, labels = axes[0].get_legend_handles_labels()
    handles += [Line2D([], [], color="k", lw=1.2), Patch(color="tab:red", alpha=0.15)]
    labels += ["limit (±1)", "beyond the limit"]
    axes[0].legend(handles, labels, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small", title="joints",
                   title_fontsize="small")
    if len(runs) > 1:
        handles = [Line2D([], [], color="0.2", ls=FILE_STYLES[r % len(FILE_STYLES)]) for r in range(len(runs))]
        axes[1].legend(handles, [label for label, _ in runs], loc="upper left", bbox_to_anchor=(1.01, 1.0),
                       fontsize="small", title="files", title_fontsize="small")
    return fig


def plot_trajectory(traj: Trajectory, out: IO[bytes], *, fmt: str = "png",
                    limits: Mapping[str, JointLimits] | None = None, title: str = "", **kw) -> None:
    """One trajectory: :func:`plot_trajectories` with a single run."""
    plot_trajectories([(title or "trajectory", traj)], out, fmt=fmt, limits=limits, title=title, **kw)
