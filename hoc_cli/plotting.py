"""The figure of ``hoc plot``: q, q̇ and u of every joint against t, with the URDF's limits.

matplotlib is an optional dependency (``pip install 'hoc[plot]'``); it is imported here only,
lazily, with the non-interactive Agg canvas (no display, no pyplot global state).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import IO, Mapping

import numpy as np

from hoc_cli.trajectory import Trajectory

FORMATS = ("png", "pdf", "svg")


@dataclass(frozen=True)
class JointLimits:
    """Limits of one joint as the URDF gives them; None where it gives none.

    lower, upper: rad (m for prismatic); velocity: rad/s (m/s); effort: N·m (N).
    """

    lower: float | None = None
    upper: float | None = None
    velocity: float | None = None
    effort: float | None = None
    prismatic: bool | None = None


class MatplotlibMissing(ImportError):
    """matplotlib is not installed."""


def _matplotlib():
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise MatplotlibMissing(str(exc)) from None
    return Figure, FigureCanvasAgg


def _unit(limits: Mapping[str, JointLimits], joints, rotary: str, linear: str) -> str:
    kinds = {limits[j].prismatic if j in limits else None for j in joints}
    if kinds == {False}:
        return rotary
    if kinds == {True}:
        return linear
    return f"{rotary} or {linear}"


def _view(data: np.ndarray, bounds: list[float]) -> tuple[float, float]:
    """Y range: the data, plus every limit within one data span of it (far limits would flatten
    the curves), padded by 5 %.
    """
    lo, hi = float(np.min(data)), float(np.max(data))
    span = max(hi - lo, 1e-3 * max(abs(lo), abs(hi)), 1e-9)
    for b in bounds:
        if lo - span <= b <= hi + span:
            lo, hi = min(lo, b), max(hi, b)
    pad = 0.05 * (hi - lo if hi > lo else span)
    return lo - pad, hi + pad


def plot_trajectory(
    traj: Trajectory,
    out: IO[bytes],
    *,
    fmt: str = "png",
    limits: Mapping[str, JointLimits] | None = None,
    title: str = "",
    dpi: int = 120,
) -> None:
    """Draw q, q̇, u (K, n) against t (K,) [s] in three stacked panels and save the figure to ``out``.

    Each joint has one colour; its limits from ``limits`` (position lower/upper, ±velocity,
    ±effort) are dashed horizontal lines of the same colour. Raises MatplotlibMissing if
    matplotlib is not installed, ValueError for an unknown ``fmt`` (one of FORMATS).
    """
    if fmt not in FORMATS:
        raise ValueError(f"figure format {fmt!r} is not one of {FORMATS}")
    Figure, FigureCanvasAgg = _matplotlib()
    limits = dict(limits or {})
    joints = list(traj.joints)
    t = np.asarray(traj.t, dtype=float)
    panels = (
        ("position $q$", _unit(limits, joints, "rad", "m"), np.asarray(traj.q), lambda L: (L.lower, L.upper)),
        (r"velocity $\dot{q}$", _unit(limits, joints, "rad/s", "m/s"), np.asarray(traj.dq),
         lambda L: (None, None) if L.velocity is None else (-L.velocity, L.velocity)),
        ("effort $u$", _unit(limits, joints, "N·m", "N"), np.asarray(traj.u),
         lambda L: (None, None) if L.effort is None else (-L.effort, L.effort)),
    )
    fig = Figure(figsize=(9.0, 8.0), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(3, 1, sharex=True)
    colours = [f"C{i % 10}" for i in range(len(joints))]
    for ax, (name, unit, data, bounds_of) in zip(axes, panels):
        drawn = []
        for i, joint in enumerate(joints):
            ax.plot(t, data[:, i], color=colours[i], lw=1.4, label=joint)
            if joint in limits:
                for b in bounds_of(limits[joint]):
                    if b is not None and np.isfinite(b):
                        ax.axhline(b, color=colours[i], ls="--", lw=0.9, alpha=0.8)
                        drawn.append(b)
        ax.set_ylim(*_view(data, drawn))
        ax.set_ylabel(f"{name} [{unit}]")
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("t [s]")
    if t[-1] > t[0]:
        axes[-1].set_xlim(t[0], t[-1])
    axes[0].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small",
                   title="joints (dashed: URDF limits)" if limits else "joints", title_fontsize="small")
    if title:
        fig.suptitle(title)
    fig.savefig(out, format=fmt, dpi=dpi, metadata={"Software": "hoc"} if fmt == "png" else None)
