"""The QP's two exact sub-steps (``hoc_cli.constraints.qp``): the minimum of its piecewise-quadratic
model along a step, and the multipliers that put the active rows on their bounds.

Symbols as in ``hoc_cli.constraints.qp``: rows g (count,), multipliers λ, per-row penalties ρ_i,
K = UᵀU a factored banded Newton matrix (``BandedSPD``), A_W the active rows.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import cho_factor, cho_solve, qr
from scipy.linalg.lapack import dtbtrs

RANK_TOL = 1e-10  # active rows whose pivoted-QR diagonal falls below this (relative) are dependent


def pseudo_solve(K, AT: np.ndarray, gW: np.ndarray,
                 groups: np.ndarray | None = None) -> tuple[np.ndarray | None, np.ndarray]:
    """δ = S⁺ g_W with S = A_W K⁻¹ A_Wᵀ, and K⁻¹A_Wᵀδ (on the free coefficients).

    ``groups`` (count,) labels the rows (columns of AT) so that rows of different groups touch
    disjoint coefficients (the rows of one joint); None: one group.

    Active rows are often linearly dependent (a limit active along a whole element makes its
    Bernstein rows dependent; the rows at a shared node repeat), so S is singular. Per group, a
    QR factorisation with column pivoting of A_gᵀ (rows scaled to unit norm; rank: |R_ii| above
    ``RANK_TOL`` × the largest) picks a basis B of the rows. The system is solved on B alone:
    K = UᵀU (``K.factor``, upper banded), Y_B = U⁻ᵀA_Bᵀ by one banded triangular solve,
    S_B = Y_BᵀY_B (nonsingular) by Cholesky, δ_B = S_B⁻¹g_B; the dependent rows' targets are
    consistent, so they are met too. S δ = g_W then holds for δ = δ_B on B (0 elsewhere), and for
    every δ + z with A_Wᵀz = 0; the pseudo-inverse solution is the one in range(A_W) (S's range),
    i.e. the orthogonal projection of that δ onto range(A_W), computed per group from the same R.
    K⁻¹A_Wᵀδ = K⁻¹A_Bᵀδ_B = U⁻¹(Y_Bδ_B), one more triangular solve of a vector. When S_B is not
    numerically positive definite its pseudo-inverse (eigenvalues below 1e-12 × the largest count as
    zero) is used. Returns (None, ·) when a triangular solve fails.
    """
    count = AT.shape[1]
    groups = np.zeros(count, int) if groups is None else np.asarray(groups)
    basis = np.zeros(count, bool)
    projections = []  # (rows of the group in pivot order, orthonormal basis of range(A_g) in that order)
    for label in np.unique(groups):
        idx = np.flatnonzero(groups == label)
        Ag = AT[:, idx]
        Ag = Ag[np.any(Ag != 0.0, axis=1)]  # (coefficients the group touches, rows of the group)
        norms = np.linalg.norm(Ag, axis=0)
        norms = np.where(norms > 0, norms, 1.0)
        R, piv = qr(Ag / norms, mode="r", pivoting=True)
        diag = np.abs(np.diag(R))
        rank = int(np.sum(diag > RANK_TOL * max(float(diag[0]) if diag.size else 0.0, 1e-300)))
        basis[idx[piv[:rank]]] = True
        if rank < idx.size:  # A_g[piv] = D_piv R̂ᵀ Q̂ᵀ: range(A_g[piv]) = range(D_piv R̂[:rank]ᵀ)
            Q, _ = np.linalg.qr(norms[piv][:, None] * R[:rank].T)
            projections.append((idx[piv], Q))
    Y, info = dtbtrs(K.factor, AT[:, basis], uplo="U", trans="T")
    if info != 0:
        return None, np.zeros(int(K.free.sum()))
    S = Y.T @ Y
    gB = gW[basis]
    try:
        dB = cho_solve(cho_factor(S), gB)
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(S)
        keep = w > 1e-12 * max(float(w.max()), 1e-300)
        dB = V[:, keep] @ ((V[:, keep].T @ gB) / w[keep])
    delta = np.zeros(count)
    delta[basis] = dB
    for rows, Q in projections:
        delta[rows] = Q @ (Q.T @ delta[rows])
    x, info = dtbtrs(K.factor, (Y @ dB)[:, None], uplo="U", trans="N")
    return delta, x[:, 0][K.free]


def line_minimum(slope: float, curvature: float, lam: np.ndarray, rw: np.ndarray, g0: np.ndarray,
                 g1: np.ndarray) -> float:
    """The minimiser a > 0 of q(d + a s): the root of the increasing piecewise-linear q'(a).

    slope = ∇q(d)ᵀs, curvature = sᵀHs; g0, g1 the rows at d and d + s (g is linear in a).
    q'(a) = slope + a·curvature + Σ_i Δg_i (max(0, c_i + a ρ_i Δg_i) − max(0, c_i)), c_i = λ_i + ρ_i g_i.
    """
    dg = g1 - g0
    c0, c1 = lam + rw * g0, rw * dg
    on = (c0 > 0) | (c1 > 0)  # the others are inactive for every a >= 0
    dg, c0, c1 = dg[on], c0[on], c1[on]
    if c0.size == 0:
        return -slope / curvature
    base = slope - float(dg @ np.maximum(c0, 0.0))  # q'(a) = base + a·curvature + Σ dg max(0, c0 + a c1)
    with np.errstate(divide="ignore", invalid="ignore"):
        b = np.where(c1 != 0, -c0 / c1, -1.0)
    cross = b > 0
    bc = b[cross]
    jc = np.where(c1[cross] > 0, 1.0, -1.0) * (dg[cross] * c1[cross])  # slope change at each breakpoint
    act0 = (c0 > 0) | ((c0 == 0) & (c1 > 0))
    S0 = curvature + float(np.sum((dg * c1)[act0]))
    v0 = base + float(np.sum((dg * c0)[act0]))  # q'(0+)
    n = bc.size
    if n == 0:
        return -v0 / S0
    k = min(n, 32)  # the breakpoints in increasing order, as far as the root: the first k, then more
    while True:
        sel = np.argpartition(bc, k - 1)[:k] if k < n else np.arange(n)
        order = sel[np.argsort(bc[sel])]
        S = S0 + np.concatenate([[0.0], np.cumsum(jc[order])])  # slope on [b_{i-1}, b_i], b_0 = 0
        knots = np.concatenate([[0.0], bc[order]])
        vals = v0 + np.concatenate([[0.0], np.cumsum(S[:-1] * np.diff(knots))])  # q' at the knots
        if (vals >= 0).any():
            i = max(int(np.argmax(vals >= 0)), 1)
            return float(knots[i - 1] - vals[i - 1] / S[i - 1])
        if k == n:  # beyond the last breakpoint
            return float(knots[-1] - vals[-1] / S[-1])
        k = min(n, 4 * k)


def residuals(g: np.ndarray, mu: np.ndarray) -> tuple[float, float]:
    """(largest violation, largest distance of an active row (μ > 0) from its bound), dimensionless."""
    return float(np.max(g, initial=0.0)), float(np.max(np.abs(g[mu > 0]), initial=0.0))
