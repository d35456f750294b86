"""Line search satisfying the strong Wolfe conditions.

Bracketing and zoom with safeguarded cubic interpolation, after Nocedal & Wright,
*Numerical Optimization* (2nd ed.), Algorithms 3.5 and 3.6. For a step α along d:

  sufficient decrease   φ(α) <= φ(0) + c1 α φ'(0)
  curvature (strong)    |φ'(α)| <= c2 |φ'(0)|

with 0 < c1 < c2 < 1 (c2 = 0.1 suits conjugate gradient).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

Phi = Callable[[float], tuple[float, float, Any]]  # α -> (φ(α), φ'(α), payload)


@dataclass(frozen=True)
class LineSearchResult:
    """Accepted step (or the best one tried when ``ok`` is False) and its evaluation payload."""

    ok: bool
    alpha: float
    phi: float
    dphi: float
    payload: Any
    n_evals: int
    message: str = ""


class _Trials:
    """φ counting its calls and keeping the best finite trial (returned when no step satisfies Wolfe)."""

    def __init__(self, phi: Phi, phi0: float, dphi0: float) -> None:
        self.phi = phi
        self.n_evals = 0
        self.best: tuple[float, float, float, Any] = (0.0, phi0, dphi0, None)

    def __call__(self, a: float) -> tuple[float, float, Any]:
        self.n_evals += 1
        f, d, payload = self.phi(a)
        if math.isfinite(f) and f < self.best[1]:
            self.best = (a, f, d, payload)
        return f, d, payload

    def failed(self, message: str) -> LineSearchResult:
        a, f, d, payload = self.best
        return LineSearchResult(False, a, f, d, payload, self.n_evals, message)


def check_parameters(c1: float, c2: float) -> None:
    if not (0.0 < c1 < c2 < 1.0):
        raise ValueError(f"strong Wolfe parameters need 0 < c1 < c2 < 1, got c1={c1}, c2={c2}")


def _cubic_min(a: float, fa: float, da: float, b: float, fb: float, db: float) -> float | None:
    """Minimiser of the cubic interpolating (a, fa, da), (b, fb, db), or None if it has none."""
    if a == b:
        return None
    d1 = da + db - 3.0 * (fa - fb) / (a - b)
    disc = d1 * d1 - da * db
    if disc < 0 or not math.isfinite(disc):
        return None
    d2 = math.copysign(math.sqrt(disc), b - a)
    denom = db - da + 2.0 * d2
    if denom == 0:
        return None
    return b - (b - a) * (db + d2 - d1) / denom


def strong_wolfe(phi: Phi, phi0: float, dphi0: float, alpha0: float = 1.0, *, c1: float = 1e-4, c2: float = 0.1,
                 alpha_max: float = 1e8, max_evals: int = 40) -> LineSearchResult:
    """Find α > 0 satisfying the strong Wolfe conditions for φ with φ(0) = phi0, φ'(0) = dphi0 < 0.

    Starts at ``alpha0``, multiplies by 4 while φ keeps decreasing (up to ``alpha_max``), then zooms;
    at most ``max_evals`` calls of φ. When no step satisfies the conditions the result has
    ok = False and the best (lowest finite φ) step tried, or α = 0 and payload None.
    """
    check_parameters(c1, c2)
    if not dphi0 < 0:
        return LineSearchResult(False, 0.0, phi0, dphi0, None, 0, "not a descent direction")
    call = _Trials(phi, phi0, dphi0)

    def zoom(lo: float, flo: float, dlo: float, hi: float, fhi: float, dhi: float) -> LineSearchResult:
        while call.n_evals < max_evals:
            width = hi - lo
            if width == 0:
                break
            trial = _cubic_min(lo, flo, dlo, hi, fhi, dhi) if math.isfinite(fhi) else None
            low, high = min(lo, hi), max(lo, hi)
            margin = 0.1 * abs(width)
            if trial is None or not (low + margin <= trial <= high - margin):
                trial = lo + 0.5 * width
            if abs(width) <= 1e-16 * max(abs(lo), 1e-300):
                break
            f, d, payload = call(trial)
            if not math.isfinite(f) or f > phi0 + c1 * trial * dphi0 or f >= flo:
                hi, fhi, dhi = trial, f, d
            else:
                if abs(d) <= -c2 * dphi0:
                    return LineSearchResult(True, trial, f, d, payload, call.n_evals)
                if d * (hi - lo) >= 0:
                    hi, fhi, dhi = lo, flo, dlo
                lo, flo, dlo = trial, f, d
        return call.failed("zoom did not satisfy the Wolfe conditions")

    prev, fprev, dprev = 0.0, phi0, dphi0
    alpha = alpha0
    first = True
    while call.n_evals < max_evals:
        f, d, payload = call(alpha)
        if not math.isfinite(f):
            # overshoot into a region where the model is undefined: shrink
            return zoom(prev, fprev, dprev, alpha, math.inf, math.nan)
        if f > phi0 + c1 * alpha * dphi0 or (not first and f >= fprev):
            return zoom(prev, fprev, dprev, alpha, f, d)
        if abs(d) <= -c2 * dphi0:
            return LineSearchResult(True, alpha, f, d, payload, call.n_evals)
        if d >= 0:
            return zoom(alpha, f, d, prev, fprev, dprev)
        prev, fprev, dprev = alpha, f, d
        alpha = min(4.0 * alpha, alpha_max)
        first = False
        if alpha >= alpha_max:
            break
    return call.failed("no step satisfied the Wolfe conditions")
