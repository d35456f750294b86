"""The first trial step of a Newton iteration that walks into penalty rows its matrix does not hold yet.

A Newton step d = −P⁻¹g of an augmented-Lagrangian inner problem models only the rows active at the
start (their Gauss-Newton curvature is in P). A row inactive there whose constraint rises along d
becomes a steep quadratic wall within the step: the unit step lands far up it, and the line search
spends several evaluations finding the foot. Along x + α d the model is

    m(α) = s·(α − α²/2) + Σ_r ½ ρ_r max(0, a_r + α b_r)²,

s = gᵀd < 0 (the Newton model, dᵀP d = −s), a_r ≤ 0 the row's PHR argument at the start (λ_r/ρ_r + c_r)
and b_r > 0 its rate along d (linearised), summed over the rows inactive at the start. m′ is
continuous, piecewise linear and increasing, so its root in (0, 1] is exact from the sorted
breakpoints −a_r/b_r.
"""
from __future__ import annotations

import weakref

import numpy as np

from hoc_cli.constraints.bounds import EFFORT


def model_step(slope: float, a: np.ndarray, b: np.ndarray, rho: np.ndarray) -> float:
    """The minimiser α ∈ (0, 1] of m (module docstring) for rows with PHR arguments a + α b (M,) and penalties ρ (M,)
    (rows active at α = 0, a > 0, or not rising, b ≤ 0, are left out); 1 when no row becomes active before α = 1.
    """
    if not slope < 0:
        return 1.0
    with np.errstate(invalid="ignore", divide="ignore"):
        cross = np.where((a <= 0) & (b > 0) & np.isfinite(a), -a / b, np.inf)
    on = cross < 1.0
    if not on.any():
        return 1.0
    order = np.argsort(cross[on])
    t = cross[on][order]
    k = (rho * b * b)[on][order]
    K, A = np.cumsum(k), np.cumsum(k * t)
    dm = slope * (1.0 - t) + K * t - A                # m′ at each breakpoint (after its row joins)
    j = int(np.searchsorted(dm > 0, True))            # the first breakpoint where m′ > 0 (m′(t_0) < 0)
    j = max(j - 1, 0)
    alpha = (A[j] - slope) / (K[j] - slope)
    return float(min(max(alpha, t[j]), 1.0))


def limit_rows(terms, C: np.ndarray, dC: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(a, b, ρ) of ``model_step`` for joint-limit terms (``constraints.penalty.LimitTerms``) along C + α dC: each row's
    λ/ρ_w + g at C, and its rate: the rows applied to dC over σ for the kinematic kinds (g is linear in C), the secant
    g(C + dC) − g(C) for effort.
    """
    at = terms.evaluate(C, grad=False)
    to = terms.evaluate(C + dC, grad=False) if terms.working[EFFORT].any() else None
    loc = terms.rows.mesh.local_coefficients(dC)
    sig = terms.sigma
    a, b, rho = [], [], []
    idle = _idle_rows(terms, at)
    with np.errstate(invalid="ignore"):
        for k in range(len(at.g_lo)):
            if k in idle:  # no joint imposes kind k: its rows the same at every C (a = −∞, b = 0)
                for part, got in zip((a, b, rho), idle[k]):
                    part.extend(got)
                continue
            rw = np.broadcast_to(terms.rho * terms.rows.weight(k), np.shape(at.g_lo[k]))
            if k == EFFORT:
                rates = (None, None) if to is None else (to.g_lo[k] - at.g_lo[k], to.g_hi[k] - at.g_hi[k])
            else:
                dV = terms.rows.apply(k, loc) / sig[k] if terms.working[k].any() else None
                rates = (None, None) if dV is None else (-dV, dV)
            for lam, g0, rate in zip((terms.lam_lo[k], terms.lam_hi[k]), (at.g_lo[k], at.g_hi[k]), rates):
                a.append((lam / rw + g0).ravel())
                b.append(np.zeros(g0.size) if rate is None else np.where(np.isfinite(g0), rate, 0.0).ravel())
                rho.append(rw.ravel())
    return np.concatenate(a), np.concatenate(b), np.concatenate(rho)


_IDLE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # LimitTerms → ``_idle_rows``


def _idle_rows(terms, at) -> dict:
    """{k: ((a_lo, a_hi), (b_lo, b_hi), (ρ_lo, ρ_hi))} of ``limit_rows`` for the kinds no joint of ``terms`` imposes (their
    g = −∞ whatever C: ``at``, the terms' ``PenaltyValue`` at any C), made once per terms.
    """
    got = _IDLE.get(terms)
    if got is None:
        got = {}
        with np.errstate(invalid="ignore"):
            for k in range(len(at.g_lo)):
                if terms.working[k].any():
                    continue
                rw = np.broadcast_to(terms.rho * terms.rows.weight(k), np.shape(at.g_lo[k]))
                sides = [((lam / rw + g0).ravel(), np.zeros(g0.size), rw.ravel())
                         for lam, g0 in zip((terms.lam_lo[k], terms.lam_hi[k]), (at.g_lo[k], at.g_hi[k]))]
                got[k] = tuple(zip(*sides))
        _IDLE[terms] = got
    return got
