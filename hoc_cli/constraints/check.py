"""The limit check of a plan: exact extrema of q_h, q̇_h, q̈_h and the jerk per element, u at 32 points per element.

Symbols
-------
N elements, n joints, kinds k = position, velocity, acceleration, jerk, effort (``KINDS``, K of them). ``excess`` is how far a
value lies beyond its bound (> 0: violated) in the bound's units. A bound b counts as violated
when its excess exceeds ``tolerance(b) = 1e-9 · max(|b|, 1e-3 σ)`` (σ: the limit's size, see
``JointLimits.scale_of``), i.e. never looser than 1e-9 × the limit unless the limit is (near) 0.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hoc_cli.constraints.bounds import DERIVATIVE, EFFORT, KINDS, KINEMATIC, JointLimits
from hoc_cli.constraints.extrema import extrema
from hoc_cli.constraints.points import PointSet
from hoc_cli.elements import HermiteMesh

CHECK_POINTS_PER_ELEMENT = 32
RELATIVE_TOLERANCE = 1e-9


@dataclass(frozen=True, eq=False)
class LimitCheck:
    """Per kind, element and joint: the worst value on each side and where it is.

    hi_value, lo_value, hi_s, lo_s : (K, N, n) extreme values and local coordinates (0 for a kind
    with no bound on any joint: not computed);
    hi_excess, lo_excess : (K, N, n) value − hi and lo − value (−inf where no bound).
    """

    mesh: HermiteMesh
    limits: JointLimits
    hi_value: np.ndarray
    hi_s: np.ndarray
    lo_value: np.ndarray
    lo_s: np.ndarray
    hi_excess: np.ndarray
    lo_excess: np.ndarray

    def tolerance(self) -> tuple[np.ndarray, np.ndarray]:
        """Tolerances (K, n) for the lower and the upper bounds."""
        out = []
        for side in (0, 1):
            rows = []
            for k in KINDS:
                b = self.limits.bounds(k)[side]
                size = np.where(np.isfinite(b), np.abs(b), 0.0)
                rows.append(RELATIVE_TOLERANCE * np.maximum(size, 1e-3 * self.limits.scale_of(k)))
            out.append(np.stack(rows))
        return out[0], out[1]

    def relative_excess(self) -> np.ndarray:
        """The worst excess of every (kind, joint) over its limit size σ, (K, n) (−inf: no bound)."""
        sig = np.stack([self.limits.scale_of(k) for k in KINDS])
        worst = np.maximum(self.hi_excess.max(axis=1), self.lo_excess.max(axis=1))
        return worst / sig

    def violations(self) -> list[dict]:
        """Limits exceeded beyond tolerance: joint, kind, worst value, time [s] and limit, worst first per kind."""
        tol_lo, tol_hi = self.tolerance()
        out = []
        for k, kind in enumerate(KINDS):
            for j, name in enumerate(self.limits.joints):
                cands = []
                e = int(np.argmax(self.hi_excess[k, :, j]))
                if self.hi_excess[k, e, j] > tol_hi[k, j]:
                    cands.append((self.hi_excess[k, e, j], self.hi_value[k, e, j], self.mesh.time_of(e, self.hi_s[k, e, j])))
                e = int(np.argmax(self.lo_excess[k, :, j]))
                if self.lo_excess[k, e, j] > tol_lo[k, j]:
                    cands.append((self.lo_excess[k, e, j], self.lo_value[k, e, j], self.mesh.time_of(e, self.lo_s[k, e, j])))
                if cands:
                    _, worst, t = max(cands)
                    lo, hi = self.limits.bounds(kind)
                    limit = [_num(lo[j]), _num(hi[j])] if kind == "position" else _num(hi[j])
                    out.append({"joint": name, "kind": kind, "worst": float(worst), "t": float(t), "limit": limit})
        return out

    @property
    def feasible(self) -> bool:
        """Whether no bound is exceeded beyond its tolerance (``violations()`` empty, without building it)."""
        tol_lo, tol_hi = self.tolerance()
        return not (np.any(self.hi_excess > tol_hi[:, None, :]) or np.any(self.lo_excess > tol_lo[:, None, :]))


def _num(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None


def check_limits(system, limits: JointLimits, mesh: HermiteMesh, C: np.ndarray,
                 per_element: int = CHECK_POINTS_PER_ELEMENT) -> LimitCheck:
    """Check coefficients C (N+1, m, n) against ``limits`` (exact extrema; u at ``per_element`` points + nodes)."""
    N, n = mesh.N, limits.n
    hv, hs, lv, ls = (np.full((len(KINDS), N, n), np.nan) for _ in range(4))
    for k, kind in enumerate(KINDS[:KINEMATIC]):
        if not limits.has(kind).any():  # nothing to check (e.g. no acceleration limit): no extrema
            hv[k] = lv[k] = hs[k] = ls[k] = 0.0
            continue
        ex = extrema(mesh, C, DERIVATIVE[kind])
        hv[k], hs[k], lv[k], ls[k] = ex.max, ex.s_max, ex.min, ex.s_min
    k = EFFORT
    if np.isfinite(limits.effort).any():
        pts = PointSet.build(mesh, np.repeat(np.arange(N), per_element + 1),
                             np.tile(np.linspace(0.0, 1.0, per_element + 1), N), np.ones(N * (per_element + 1)))
        X = pts.apply(C)
        u = system.inverse_dynamics(X[0], X[1], X[2]).reshape(N, per_element + 1, n)
        s = np.linspace(0.0, 1.0, per_element + 1)
        imax, imin = u.argmax(axis=1), u.argmin(axis=1)
        hv[k], lv[k] = u.max(axis=1), u.min(axis=1)
        hs[k], ls[k] = s[imax], s[imin]
    else:
        hv[k] = lv[k] = 0.0
        hs[k] = ls[k] = 0.0
    lo = np.stack([limits.bounds(kk)[0] for kk in KINDS])[:, None, :]
    hi = np.stack([limits.bounds(kk)[1] for kk in KINDS])[:, None, :]
    with np.errstate(invalid="ignore"):
        he = np.where(np.isfinite(hi), hv - hi, -np.inf)
        le = np.where(np.isfinite(lo), lo - lv, -np.inf)
    return LimitCheck(mesh, limits, hv, hs, lv, ls, he, le)
