"""The SQP's quadratic programme on explicit rows: the method of multipliers with semismooth Newton steps.

Symbols
-------
x the design vector (free coefficients, P), d a step, g_J and H the cost's gradient and positive
definite banded Newton matrix at x. The imposed kinematic rows (``LimitTerms`` with fixed working
set: Bernstein rows of q, q̇, q̈, each touching 2m coefficients of one joint in one element) are
gathered once into an explicit sparse matrix: row i is g_i(x + d) = g_i(x) + a_iᵀd ≤ 0
(dimensionless, side and scale σ included, the same g as ``LimitTerms``). With multipliers λ ≥ 0
and per-row penalties ρ_i = ρ·w_i (w_i [s]: the time a row stands for) the QP's augmented
Lagrangian is

    q(d) = g_Jᵀd + ½dᵀHd + Σ_i (max(0, λ_i + ρ_i g_i)² − λ_i²) / (2ρ_i),

convex and piecewise quadratic, with gradient g_J + Hd + Σ μ_i a_i (μ = max(0, λ + ρ g)) and,
on the piece where the rows with μ > 0 are active, Hessian H + Σ_active ρ_i a_i a_iᵀ, which keeps
H's band. Evaluating q is one sparse product over the rows (no pass over the (kind, joint) arrays)
and a Newton matrix is H's banded storage (assembled once per model) plus the active rows' 2m × 2m
outer products, then one banded Cholesky. The iteration (``QPModel.solve``) is described in
``hoc_cli.constraints.sqp``; its two exact sub-steps (line minimum, exact multipliers) are in
``hoc_cli.constraints.qp_steps``.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.linalg.blas import dsbmv
from scipy.linalg.lapack import dpbtrf

from hoc_cli.banded import BandedSPD, element_blocks
from hoc_cli.constraints.penalty import EFFORT, LimitRows, PenaltyValue, effective_bounds
from hoc_cli.constraints.qp_steps import line_minimum, pseudo_solve, residuals
from hoc_cli.errors import NumericalError
from hoc_cli.optimize.modify import gauss_newton_shift

if TYPE_CHECKING:
    from scipy.sparse import csr_matrix

_log = logging.getLogger(__name__)  # solver traces at DEBUG level (docs/design.md)
QP_FEAS = 1e-11  # dimensionless violation (and gap of active rows) the QP's rows should reach
QP_STALL = 1e-10  # ... or at least this, when the rounding of the banded solves stops progress
QP_MAX_OUTER = 40
SSN_MAX = 30
QP_BUDGET = 150  # semismooth Newton steps one QP may take
C1 = 1e-4
SHIFT = 1e-12  # the relative diagonal regularisation of ``ControlProblem.banded``
SOFT_START = 0.1  # a QP without multipliers is first minimised with its penalties × this


@dataclass(frozen=True, eq=False)
class QPRows:
    """The imposed kinematic rows of one SQP, explicit.

    vals, cols : (count, 2m) each row's coefficients and their indices in the full coefficient
    vector (node, derivative, joint order); b : (count,) so that g = vals·C[cols] − b; joint, w : (count,) each row's joint and time [s];
    A, AT : (count, P) sparse, the rows on the design vector, and its transpose; parts : per (kind, side) with rows, the
    flat indices of its rows in the kind's (N, R, n) arrays; pair_at, pair_val : (count, 2m(2m+1)/2)
    the upper-banded storage position and value of each row's outer product a aᵀ (entries touching
    a fixed coefficient are 0); size : the full coefficient count; free : (size,) bool.
    """

    rows: LimitRows
    n: int
    vals: np.ndarray
    cols: np.ndarray
    b: np.ndarray
    joint: np.ndarray
    w: np.ndarray
    A: csr_matrix
    AT: csr_matrix
    parts: tuple
    pair_at: np.ndarray
    pair_val: np.ndarray
    size: int
    free: np.ndarray

    @classmethod
    def build(cls, rows: LimitRows, limits, working: np.ndarray, free: np.ndarray, margin: float) -> "QPRows":
        """The rows ``LimitTerms`` imposes for ``working`` (K, n) (kinematic kinds only), margin δ."""
        mesh, n = rows.mesh, limits.n
        N, m = mesh.N, mesh.m
        lo, hi, sig = effective_bounds(limits, margin)
        vals, cols, offset, joint, w, parts = [], [], [], [], [], []
        a = np.arange(2 * m)
        for k in range(EFFORT):
            if not working[k].any():
                continue
            R = rows.rows[k]
            shape = rows.shape(k, n)
            off = ~working[k] | np.zeros(shape, bool)
            if k < 2:  # q and q̇ rows set by x0, x1 alone are data, not constraints
                off = off | rows.data[k][:, :, None]
            weight = np.broadcast_to(rows.weight(k), shape)
            for side, bound in ((-1.0, lo[k]), (1.0, hi[k])):
                e, r, j = np.nonzero(~off & np.isfinite(bound)[None, None, :])
                if e.size == 0:
                    continue
                Re = R[r] if rows.scale is None else R[r] * rows.scale[k][e]  # non-uniform mesh
                vals.append(side * Re / sig[k, j][:, None])
                cols.append((e[:, None] * m + a[None, :]) * n + j[:, None])
                offset.append(side * bound[j] / sig[k, j])
                joint.append(j)
                w.append(weight[e, r, j])
                parts.append((k, side, np.ravel_multi_index((e, r, j), shape)))
        size = (N + 1) * m * n
        if vals:
            vals, cols, offset = np.concatenate(vals), np.concatenate(cols), np.concatenate(offset)
            joint, w = np.concatenate(joint), np.concatenate(w)
        else:
            vals, cols, offset = np.zeros((0, 2 * m)), np.zeros((0, 2 * m), int), np.zeros(0)
            joint, w = np.zeros(0, int), np.zeros(0)
        index = np.cumsum(free) - 1  # full index -> design index (fixed: unused)
        keep = free[cols]
        count = vals.shape[0]
        from scipy.sparse import csr_matrix  # only a run with kinematic limits in play loads scipy.sparse (start-up)

        A = csr_matrix((vals[keep], (np.repeat(np.arange(count), 2 * m).reshape(count, 2 * m)[keep], index[cols[keep]])),
                       shape=(count, int(free.sum())))
        ia, ib = np.triu_indices(2 * m)
        u = 2 * m * n - 1
        ca, cb = cols[:, ia], cols[:, ib]
        pair_at = (u + ca - cb) * size + cb
        pair_val = vals[:, ia] * vals[:, ib] * (free[ca] & free[cb])
        return cls(rows, n, vals, cols, offset, joint, w, A, A.T.tocsr(), tuple(parts), pair_at, pair_val, size, free)

    @property
    def count(self) -> int:
        return self.vals.shape[0]

    def gather(self, lo: tuple, hi: tuple) -> np.ndarray:
        """Per-kind arrays (lo and hi sides, the kinds' row shapes) -> (count,) in row order."""
        return np.concatenate([np.zeros(0)] + [(hi if side > 0 else lo)[k].ravel()[flat] for k, side, flat in self.parts])

    def scatter(self, v: np.ndarray) -> tuple[tuple, tuple]:
        """(count,) in row order -> per-kind arrays (lo, hi), zero on the rows not imposed."""
        n = self.n
        lo = [np.zeros(self.rows.shape(k, n)) for k in range(EFFORT + 1)]
        hi = [np.zeros(self.rows.shape(k, n)) for k in range(EFFORT + 1)]
        start = 0
        for k, side, flat in self.parts:
            (hi if side > 0 else lo)[k].ravel()[flat] = v[start:start + flat.size]
            start += flat.size
        return tuple(lo), tuple(hi)

    def at(self, C: np.ndarray) -> np.ndarray:
        """The rows' g (count,) at coefficients C (N+1, m, n)."""
        return np.einsum("ia,ia->i", self.vals, np.asarray(C).ravel()[self.cols]) - self.b

    def values(self, pv: PenaltyValue) -> np.ndarray:
        """The rows' g (count,) from ``LimitTerms.evaluate`` of the same rows."""
        return self.gather(pv.g_lo, pv.g_hi)


class QPModel:
    """The limited quadratic model at x: g_J, the positive-definite element blocks H, the rows at x."""

    def __init__(self, base, ev, qrows: QPRows, g0: np.ndarray, previous: "QPModel | None" = None) -> None:
        """``g0`` (count,): the rows at x; ``previous``: a model whose H (its modification included) is kept."""
        self.base, self.x, self.g, self.qrows, self.g0 = base, ev.x, ev.grad, qrows, g0
        self.mn = base.mesh.m * base.n
        self.free = base.layout.free
        if previous is None:
            Hs, self._GNs = base.hessian_samples(ev)
            self.H = element_blocks(base.op_h, Hs)
            self.modified, self.mu = False, 0.0
            self._ab = None
        else:
            self.H, self._GNs, self.modified, self.mu = previous.H, previous._GNs, previous.modified, previous.mu
            self._ab = previous._ab
        self.steps = 0  # semismooth Newton steps taken
        self._last = None  # (active rows, penalties, factored Newton matrix) of the last ``newton``

    def modify(self) -> None:
        """H + μ·GN with μ growing until it is positive definite (``hoc_cli.optimize.modify``, as every Newton matrix).

        The exact H is kept while the QP's matrices H + Σ ρ a aᵀ are positive definite: at a limited
        optimum H itself may be indefinite in directions the active rows block (a position limit
        holds an arm back from folding further), and only the curvature on their null space matters.
        """
        H, GN = self.H, element_blocks(self.base.op_h, self._GNs)
        mu, _ = gauss_newton_shift(H, GN, self.base.banded)
        if _log.isEnabledFor(logging.DEBUG):
            _log.debug(f"    model: indefinite, mu {mu:.2e}")
        self.H, self.modified, self.mu, self._ab, self._last = H + mu * GN, True, mu, None, None

    def restore(self, H: np.ndarray) -> None:
        """Back to the unmodified element blocks H (taken before ``modify``), to solve again from other multipliers."""
        self.H, self.modified, self.mu, self._ab, self._last, self.steps = H, False, 0.0, None, None, 0

    def Hd(self, d: np.ndarray) -> np.ndarray:
        """H d (P,) for a step d (P,), from H's banded storage."""
        full = np.zeros(self.free.size)
        full[self.free] = d
        return dsbmv(2 * self.mn - 1, 1.0, self.banded_H(), full, lower=0)[self.free]

    def banded_H(self) -> np.ndarray:
        """H summed into upper banded storage (2mn, size), entries touching a fixed coefficient 0."""
        if self._ab is None:
            L, size = 2 * self.mn, self.qrows.size
            u = L - 1
            a, b = np.triu_indices(L)
            E = self.H.shape[0]
            flat = np.tile(u + a - b, E) * size + (np.arange(E)[:, None] * self.mn + b[None, :]).ravel()
            ab = np.bincount(flat, weights=self.H[:, a, b].ravel(), minlength=(u + 1) * size).reshape(u + 1, size)
            d = np.arange(u + 1)[:, None]
            j = np.arange(size)[None, :]
            i = j - (u - d)
            keep = (i >= 0) & self.free[np.clip(i, 0, size - 1)] & self.free[j]
            self._ab = np.where(keep, ab, 0.0)
        return self._ab

    def value(self, d: np.ndarray, lam: np.ndarray, rw: np.ndarray):
        """(q(d), its gradient (P,), the rows g (count,), μ (count,)) for multipliers λ, penalties ρ_i."""
        g = self.g0 + self.qrows.A @ d
        q, r, mu = self._at(d, self.Hd(d), g, lam, rw)
        return q, r, g, mu

    def _at(self, d: np.ndarray, Hd: np.ndarray, g: np.ndarray, lam: np.ndarray, rw: np.ndarray):
        """(q(d), its gradient, μ) from H d and the rows g at d."""
        mu = np.maximum(0.0, lam + rw * g)
        q = float(self.g @ d + 0.5 * d @ Hd) + float(np.sum((mu * mu - lam * lam) / rw)) / 2.0
        return q, self.g + Hd + self.qrows.AT @ mu, mu

    def newton(self, active: np.ndarray, rw: np.ndarray) -> BandedSPD:
        """The factored H + Σ_active ρ_i a_i a_iᵀ on the free coefficients (as ``ControlProblem.banded``).

        The last one is kept: the next multiplier update and the exact-multiplier step usually ask
        for the same active rows and penalties again.
        """
        last = self._last
        if last is not None and np.array_equal(last[0], active) and np.array_equal(last[1], rw):
            return last[2]
        qr_, size = self.qrows, self.qrows.size
        L = 2 * self.mn
        u = L - 1
        ab = self.banded_H()
        if active.any():
            ab = ab + np.bincount(qr_.pair_at[active].ravel(), weights=(qr_.pair_val[active] * rw[active, None]).ravel(),
                                  minlength=(u + 1) * size).reshape(u + 1, size)
        else:
            ab = ab.copy()
        diag = ab[u]
        scale = float(np.mean(diag[self.free])) if self.free.any() else 1.0
        ab[u] = np.where(self.free, diag * (1.0 + SHIFT) + SHIFT * scale, scale)
        factor, info = dpbtrf(ab, lower=0)
        if info != 0:
            raise NumericalError("the Gauss-Newton matrix is not positive definite")
        K = BandedSPD(factor=factor, free=self.free, size=size)
        self._last = (active.copy(), rw, K)
        return K

    def minimise(self, d: np.ndarray, lam: np.ndarray, rw: np.ndarray):
        """Semismooth Newton on q for fixed multipliers and penalties, from d, with exact line searches.

        q is convex and piecewise quadratic: on a fixed set of active rows one Newton step reaches
        that piece's minimiser; when the rows active there are the same, it is q's minimiser. A full
        step that changes the active rows is taken when it decreases q by the Armijo fraction C1 of
        its slope (its rows are the next piece: few steps when many rows enter or leave at once);
        otherwise the step goes to q's minimum along it: q' is piecewise linear and increasing
        along a step s (``line_minimum``), and its root is exact. Returns (d, g, μ).
        """
        Hd, g = self.Hd(d), self.g0 + self.qrows.A @ d  # H d and the rows are linear in d: updated along steps
        q, r, mu = self._at(d, Hd, g, lam, rw)
        for _ in range(SSN_MAX):
            self.steps += 1
            pattern = mu > 0
            step = -self.newton(pattern, rw).solve(r)
            slope = float(r @ step)
            if not slope < -1e-15 * max(abs(q), 1.0):
                break
            Hs, gs = self.Hd(step), self.qrows.A @ step
            q1, r1, mu1 = self._at(d + step, Hd + Hs, g + gs, lam, rw)
            if np.array_equal(mu1 > 0, pattern):
                return d + step, g + gs, mu1
            if q1 <= q + C1 * slope:  # the full step decreases q enough: the rows active there are the next piece
                if _log.isEnabledFor(logging.DEBUG):
                    _log.debug(f"      ssn: full step, active {pattern.sum()} -> {(mu1 > 0).sum()}")
                d, Hd, g, q, r, mu = d + step, Hd + Hs, g + gs, q1, r1, mu1
                continue
            a = line_minimum(slope, float(step @ Hs), lam, rw, g, g + gs)
            if _log.isEnabledFor(logging.DEBUG):
                _log.debug(f"      ssn: line minimum at {a:.3e}, active {pattern.sum()} -> {(mu1 > 0).sum()}")
            d, Hd, g = d + a * step, Hd + a * Hs, g + a * gs
            q, r, mu = self._at(d, Hd, g, lam, rw)
        return d, g, mu

    def dual_step(self, d: np.ndarray, g: np.ndarray, mu: np.ndarray, lam: np.ndarray, rw: np.ndarray):
        """The multipliers that put the active rows W exactly on their bounds, for the active piece at d.

        With K = H + Σ_W ρ_i a_i a_iᵀ, changing λ_W by δ moves d by −K⁻¹A_Wᵀδ and the rows by
        −Sδ, S = A_W K⁻¹ A_Wᵀ; δ = S⁺ g_W (pseudo-inverse: rows active along a whole element are
        linearly dependent, and their targets consistent) zeroes them. Stationarity
        H d + g + A_Wᵀν = 0 then holds with ν = λ_W + δ (the ρ g_W part of μ = λ + ρ g is spent).
        Returns (d, g, μ, λ) at the new point, or None when a multiplier would turn negative (the
        row must leave W).
        """
        W = mu > 0
        if not W.any():
            return d, g, mu, lam
        qr_ = self.qrows
        count = int(W.sum())
        K = self.newton(W, rw)
        AT = np.zeros((qr_.size, count))  # the active rows' columns, full coefficient vector (fixed rows 0)
        AT[qr_.cols[W], np.repeat(np.arange(count)[:, None], qr_.cols.shape[1], axis=1)] = qr_.vals[W]
        AT[~K.free] = 0.0
        muW = mu[W] - rw[W] * g[W]
        delta, KAdelta = pseudo_solve(K, AT, g[W], qr_.joint[W])  # a row touches one joint
        if delta is None or np.any(muW + delta < 0):
            return None  # a multiplier would turn negative: that row leaves W, this step does not apply
        lam = mu.copy()
        lam[W] = muW + delta
        d = d - KAdelta
        _, _, g, mu = self.value(d, lam, rw)
        return d, g, mu, lam

    def solve(self, lam: np.ndarray, rho: float, d0: np.ndarray, feas: float = QP_FEAS):
        """The QP's step d, its multipliers λ (count,) and penalty; ok False when its rows cannot be met.

        ``feas``: the violation and active-row gap to reach (``QP_FEAS`` near the solution; looser
        while the SQP is far from it: an inexact SQP). Started without multipliers (the first QP on
        a mesh), q is first minimised with the penalties × ``SOFT_START``: across a softer wall many
        rows enter in one full step, where the stiff model stops at each few rows' breakpoint; that
        minimiser starts the minimisation with the full penalties (the method of multipliers
        accepts any start).
        """
        d, lam0 = d0, lam
        prev, prev_crit, rho0 = math.inf, math.inf, rho
        settled = None
        viol = math.inf
        soft = not lam.any()  # no multipliers yet: a softer first minimisation (``SOFT_START``)
        for _ in range(QP_MAX_OUTER):
            rw = rho * self.qrows.w
            try:
                if soft:
                    d, g, mu = self.minimise(d, lam, SOFT_START * rw)
                    soft = False
                d, g, mu = self.minimise(d, lam, rw)
            except NumericalError:  # H + Σ ρ a aᵀ not positive definite: H's curvature is modified
                if self.modified:
                    raise
                self.modify()
                return self.solve(lam0, rho0, d0, feas)
            if self.steps > QP_BUDGET:  # degenerate active rows swapping in and out: give up (the caller falls back)
                return d, lam, rho, False
            viol, gap = residuals(g, mu)
            pattern = mu > 0
            if max(viol, gap) > feas and np.array_equal(pattern, settled):
                # the active piece repeats: its exact multipliers, kept when they do better
                step = self.dual_step(d, g, mu, lam, rw)
                if step is not None:
                    viol2, gap2 = residuals(step[1], step[2])
                    if max(viol2, gap2) < max(viol, gap) and np.array_equal(step[2] > 0, pattern):
                        d, g, mu, viol, gap = step[0], step[1], step[2], viol2, gap2
            settled = pattern
            lam = mu
            if _log.isEnabledFor(logging.DEBUG):
                _log.debug(f"    qp: viol {viol:.2e} gap {gap:.2e} rho {rho:.3g} active {pattern.sum()}")
            crit = max(viol, gap)
            if crit <= feas or (crit <= max(QP_STALL, feas) and crit > 0.5 * prev_crit):
                return d, lam, rho, True
            prev_crit = crit
            if viol > 0.25 * prev and viol > feas:
                rho *= 10.0
                if rho > 1e8 * rho0:  # the rows cannot be met (an infeasible task)
                    return d, lam, rho, False
            prev = viol
        return d, lam, rho, viol <= 1e3 * QP_FEAS
