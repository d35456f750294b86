"""Torque histories for the simulator: u(t) maps times (K,) [s] to joint torques (K, n) [N·m, or N
for prismatic joints]. Constant (free motion when zero), sampled from a plan's CSV (spline or linear
interpolation), or the exact inverse-dynamics torque of a planned Hermite trajectory.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

from hoc_cli.elements import HermiteMesh
from hoc_cli.system import System


class TorqueSource(Protocol):
    """A torque history: ``u(t)`` maps times (K,) [s] to torques (K, n) [N·m or N]."""

    n: int

    def __call__(self, t: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True, eq=False)
class ConstantTorque:
    """u(t) = value for all t; ``value`` shape (n,). ``ConstantTorque(np.zeros(n))`` is free motion."""

    value: np.ndarray

    def __post_init__(self) -> None:
        v = np.asarray(self.value, dtype=float).reshape(-1)
        if not np.all(np.isfinite(v)):
            raise ValueError(f"constant torque must be finite, got {v}")
        object.__setattr__(self, "value", v)

    @property
    def n(self) -> int:
        return self.value.size

    def __call__(self, t: np.ndarray) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, dtype=float))
        return np.broadcast_to(self.value, (t.size, self.n)).copy()


def zero_torque(n: int) -> ConstantTorque:
    """No actuation: u(t) = 0, shape (K, n)."""
    return ConstantTorque(np.zeros(n))


@dataclass(frozen=True, eq=False)
class SampledTorque:
    """Torque interpolated in time from samples (a plan's CSV).

    ``t`` (K,) strictly increasing [s], ``u`` (K, n). ``kind="cubic"`` (default): the C² cubic
    spline with not-a-knot ends through the samples (error O(Δt⁴) for smooth torques; a planned
    torque is only C⁰ with small kinks at element nodes, where the error is locally O(Δt·[u̇])).
    ``kind="linear"``: piecewise linear (O(Δt²), never overshoots). Fewer than 4 samples fall back
    to linear. Outside [t_0, t_K] the end values are held; callers check the time range.
    """

    t: np.ndarray
    u: np.ndarray
    kind: str = "cubic"
    _spline: Callable | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float).reshape(-1)
        u = np.asarray(self.u, dtype=float)
        u = u[:, None] if u.ndim == 1 else u
        if u.ndim != 2 or u.shape[0] != t.size:
            raise ValueError(f"torque samples must have shape ({t.size}, n), got {u.shape}")
        if t.size < 2 or not np.all(np.diff(t) > 0):
            raise ValueError("torque sample times must be at least 2 and strictly increasing")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(u))):
            raise ValueError("torque samples must be finite")
        if self.kind not in ("cubic", "linear"):
            raise ValueError(f"interpolation kind must be 'cubic' or 'linear', got {self.kind!r}")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "u", u)
        if self.kind == "cubic" and t.size >= 4:
            from scipy.interpolate import CubicSpline

            object.__setattr__(self, "_spline", CubicSpline(t, u, axis=0, bc_type="not-a-knot", extrapolate=False))

    @property
    def n(self) -> int:
        return self.u.shape[1]

    def __call__(self, t: np.ndarray) -> np.ndarray:
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), self.t[0], self.t[-1])
        if self._spline is not None:
            return np.asarray(self._spline(t)).reshape(t.size, self.n)
        return np.stack([np.interp(t, self.t, self.u[:, i]) for i in range(self.n)], axis=1)


@dataclass(frozen=True, eq=False)
class PlannedTorque:
    """The exact torque of a Hermite trajectory: u(t) = ID(q_h(t), q̇_h(t), q̈_h(t)); (K, n).

    ``coeffs`` (N+1, m, n) on ``mesh``; times outside [0, T] are clamped to it.
    """

    system: System
    mesh: HermiteMesh
    coeffs: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "coeffs", self.mesh.check_coefficients(np.asarray(self.coeffs, dtype=float)))

    @property
    def n(self) -> int:
        return self.coeffs.shape[2]

    def __call__(self, t: np.ndarray) -> np.ndarray:
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), 0.0, self.mesh.T)
        q, dq, ddq = self.mesh.evaluate_all(self.coeffs, t)
        return self.system.inverse_dynamics(q, dq, ddq)
