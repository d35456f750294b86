"""Kinematic limits by sequential quadratic programming (SQP) on hoc's banded Newton matrix.

The position, velocity and acceleration limits are imposed through Bernstein rows
(``bernstein.py``): LINEAR inequalities a_iᵀx ≤ b_i in the design vector x. For linear
constraints an SQP step keeps every linearisation exact, so each iteration is

1. at x: the cost's gradient g and its banded Newton matrix H (made positive definite as in
   ``ControlProblem.positive_definite``), both assembled ONCE per iteration (H is kept from the
   previous iteration when that one's decrement was below ``REUSE_DEC``·|J|: the step since then
   is so small that the change of H is below the rounding of J);
2. the quadratic programme  min_d gᵀd + ½dᵀHd  subject to  a_iᵀ(x + d) ≤ b_i  for every row,
   solved to high accuracy by the method of multipliers on the QP itself: its inner problems are
   piecewise quadratic, minimised by semismooth Newton steps whose matrices H + Σ_active ρ_i a_i a_iᵀ
   keep H's band (each row lies in one element), so an inner step is one banded Cholesky and no
   dynamics. The multipliers (λ ≥ 0, warm-started from the previous iteration) converge linearly at
   a rate ~1/ρ, with ρ large because these solves are cheap; redundant active rows (a limit active
   along a whole element makes its Bernstein rows linearly dependent) do not hurt the method of
   multipliers, as they would an active-set solve of the KKT system;
3. a backtracking line search on the exact ℓ1 merit function J + ν Σ max(0, g_i), ν = 2 max λ
   (Nocedal & Wright, Numerical Optimization, §18.3). Linear rows are met exactly at x + d, so
   after one full step every iterate is feasible and the merit is J itself.

Stopping test: x within the imposed bounds and the Newton decrement of the limited model,
|gᵀd + ½ dᵀHd| (= ½ dᵀHd at a fixed active set; ≥ 0 up to rounding, since d = 0 is feasible;
reported as its absolute value), at most tol·|J| (or at most J's rounding level): the constrained analogue of the inner
minimiser's test; the plan is then x + d when it is within the bounds and J does not rise. An x
just outside the bounds (by the tolerance of the previous, inexactly solved QP) passes the test
when x + d is within them and J rises by at most 2|gᵀd + ½ dᵀHd|: that x + d is the plan.
Near the optimum the active set is fixed and the iteration is Newton's method on the
equality-constrained problem: a few iterations, one Newton matrix each. Effort limits
(nonlinear) are not imposed here: the caller checks them and falls back to the augmented
Lagrangian when one is broken.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, cho_solve, qr
from scipy.linalg.lapack import dtbtrs

from hoc_cli.banded import element_blocks
from hoc_cli.constraints.bounds import KINDS, JointLimits
from hoc_cli.constraints.penalty import EFFORT, LimitRows, LimitTerms, PenaltyValue
from hoc_cli.errors import NumericalError
from hoc_cli.optimize import IterLog, OptimizeResult, Status
from hoc_cli.optimize.result import StopTest

_DEBUG = bool(os.environ.get("HOC_DEBUG_AL"))
RHO_QP = 1e4  # the QP's penalty per unit time, × |J|/T
QP_FEAS = 1e-11  # dimensionless violation (and gap of active rows) the QP's rows should reach
QP_STALL = 1e-10  # ... or at least this, when the rounding of the banded solves stops progress
QP_LOOSE = 1e-7  # ... the loosest, far from the solution (the tolerance is min(1e-2 r, r²), r the last relative
# decrement: the next decrement is about r² (Newton), and a step whose violation is not well below it
# fails the merit line search)
QP_MAX_OUTER = 40
SSN_MAX = 30
QP_BUDGET = 150  # semismooth Newton steps one QP may take
STIFF_MU = 10.0  # H + μ·GN with μ >= this is mostly GN: the SQP hands over after
STIFF_ITERATIONS = 3  # this many such iterations in a row
STRONG_MU = 100.0  # ... and at once when μ >= this (a strongly indefinite H: the torque cost far from its optimum)
LS_MAX = 40
REUSE_DEC = 1e-6  # relative decrement below which the SQP keeps its last Newton matrix
NEAR_FEAS = 1e-6  # the stopping test from an x this close to its rows (dimensionless) looks at x + d
RANK_TOL = 1e-10  # active rows whose pivoted-QR diagonal falls below this (relative) are dependent
C1 = 1e-4


def block_matvec(blocks: np.ndarray, v: np.ndarray, stride: int) -> np.ndarray:
    """Σ_e (element block e) applied to the window of v (size,) at offset e·stride; (size,)."""
    N, L, _ = blocks.shape
    X = np.lib.stride_tricks.sliding_window_view(v, L)[::stride][:N]  # (N, L)
    Y = np.einsum("eab,eb->ea", blocks, X)
    out = np.zeros_like(v)
    out[: N * stride] += Y[:, :stride].ravel()
    out[stride:] += Y[:, stride:].ravel()
    return out


def kinematic_working(limits: JointLimits) -> np.ndarray:
    """(4, n) bool: every (kinematic kind, joint) pair with a finite bound; effort excluded."""
    working = np.zeros((len(KINDS), limits.n), bool)
    for k in range(EFFORT):
        lo, hi = limits.bounds(KINDS[k])
        working[k] = np.isfinite(lo) | np.isfinite(hi)
    return working


@dataclass(frozen=True, eq=False)
class SQPResult:
    """The SQP's outcome: ok (False: the QP or the line search failed; the caller falls back),
    result (an OptimizeResult on the cost J alone), penalty (the rows' values and multipliers μ at x).
    """

    ok: bool
    result: OptimizeResult
    penalty: PenaltyValue | None


class _Model:
    """The limited quadratic model at x: g, the positive-definite element blocks H, the rows."""

    def __init__(self, base, ev, rows: LimitRows, terms: LimitTerms, previous: "_Model | None" = None) -> None:
        """``previous``: a model whose H (its modification included) is kept instead of a new one."""
        self.base, self.x, self.g, self.rows, self.terms = base, ev.x, ev.grad, rows, terms
        self.mn = base.mesh.m * base.n
        self.free = base.layout.free
        if previous is None:
            Hs, self._GNs = base.hessian_samples(ev)
            self.H = element_blocks(base.op_h, Hs)
            self.modified, self.mu = False, 0.0
        else:
            self.H, self._GNs, self.modified, self.mu = previous.H, previous._GNs, previous.modified, previous.mu
        self.steps = 0  # semismooth Newton steps taken

    def modify(self) -> None:
        """H + μ·GN with μ growing until H is positive definite (as ``ControlProblem.positive_definite``).

        The exact H is kept while the QP's matrices H + Σ ρ a aᵀ are positive definite: at a limited
        optimum H itself may be indefinite in directions the active rows block (a position limit
        holds an arm back from folding further), and only the curvature on their null space matters.
        """
        H, GN = self.H, element_blocks(self.base.op_h, self._GNs)
        tr = np.trace(GN.sum(axis=0))
        mu = 1e-3 * max(abs(np.trace(H.sum(axis=0))), tr) / tr
        for _ in range(12):
            try:
                self.base.banded(H + mu * GN)
                break
            except NumericalError:
                mu *= 10
        if _DEBUG:
            print(f"    model: indefinite, mu {mu:.2e}")
        self.H, self.modified, self.mu = H + mu * GN, True, mu

    def Hd(self, d: np.ndarray) -> np.ndarray:
        full = np.zeros(self.free.size)
        full[self.free] = d
        return block_matvec(self.H, full, self.mn)[self.free]

    def value(self, d: np.ndarray, terms: LimitTerms) -> tuple[float, np.ndarray, PenaltyValue]:
        """q(d) = gᵀd + ½dᵀHd + Φ(x + d), its gradient, Φ's terms."""
        Hd = self.Hd(d)
        pv = terms.evaluate(self.base.coefficients(self.x + d))
        q = float(self.g @ d + 0.5 * d @ Hd) + pv.value
        return q, self.g + Hd + self.base.layout.pack(pv.grad), pv

    def minimise(self, d: np.ndarray, terms: LimitTerms) -> tuple[np.ndarray, PenaltyValue]:
        """Semismooth Newton on q for fixed multipliers and penalty, from d, with exact line searches.

        q is convex and piecewise quadratic: on a fixed set of active rows one Newton step reaches
        that piece's minimiser; when the rows active there are the same, it is q's minimiser. A full
        step that changes the active rows is taken when it decreases q by the Armijo fraction C1 of
        its slope (its rows are the next piece: few steps when many rows enter or leave at once);
        otherwise the step goes to q's minimum along it: q' is piecewise linear and increasing
        along a step s (``_line_minimum``), and its root is exact.
        """
        q, r, pv = self.value(d, terms)
        for _ in range(SSN_MAX):
            self.steps += 1
            pattern = _pattern(pv)
            K = self.base.banded(self.H + terms.newton_blocks(self.base.coefficients(self.x + d), pv))
            step = -K.solve(r)
            slope = float(r @ step)
            if not slope < -1e-15 * max(abs(q), 1.0):
                break
            q_new, r_new, pv_new = self.value(d + step, terms)
            if np.array_equal(_pattern(pv_new), pattern):
                return d + step, pv_new
            if q_new <= q + C1 * slope:  # the full step decreases q enough: the rows active there are the next piece
                if _DEBUG:
                    print(f"      ssn: full step, active {pattern.sum()} -> {_pattern(pv_new).sum()}")
                d, q, r, pv = d + step, q_new, r_new, pv_new
                continue
            a = _line_minimum(slope, float(step @ self.Hd(step)), terms, pv, pv_new)
            if _DEBUG:
                print(f"      ssn: line minimum at {a:.3e}, active {pattern.sum()} -> {_pattern(pv_new).sum()}")
            d = d + a * step
            q, r, pv = self.value(d, terms)
        return d, pv

    def dual_step(self, d: np.ndarray, pv: PenaltyValue, terms: LimitTerms):
        """The multipliers that put the active rows W exactly on their bounds, for the active piece at d.

        With K = H + Σ_W ρ_i a_i a_iᵀ, changing λ_W by δ moves d by −K⁻¹A_Wᵀδ and the rows by
        −Sδ, S = A_W K⁻¹ A_Wᵀ; δ = S⁺ g_W (pseudo-inverse: rows active along a whole element are
        linearly dependent, and their targets consistent) zeroes them. Stationarity
        H d + g + A_Wᵀν = 0 then holds with ν = λ_W + δ (the ρ g_W part of μ = λ + ρ g is spent).
        Returns (d, rows, terms) at the new point, or None when a multiplier would turn negative
        (the row must leave W).
        """
        n, m = self.base.n, self.base.mesh.m
        _, _, sig = terms._bounds
        cols, vals, gW, muW, where, joint = [], [], [], [], [], []
        count = 0
        for k in range(EFFORT):
            R = terms.rows.rows[k]
            for side, mu, g in ((-1.0, pv.mu_lo[k], pv.g_lo[k]), (1.0, pv.mu_hi[k], pv.g_hi[k])):
                e, r, j = np.nonzero(mu > 0)
                if e.size == 0:
                    continue
                a = np.arange(2 * m)
                cols.append((e[:, None] * m + a[None, :]) * n + j[:, None])
                Re = R[r] if terms.rows.scale is None else R[r] * terms.rows.scale[k][e]  # non-uniform mesh
                vals.append(side * Re / sig[k, j][:, None])
                gW.append(g[e, r, j])
                w = np.broadcast_to(terms.rows.weight(k), mu.shape)[e, r, j]  # non-uniform mesh: per row
                muW.append(mu[e, r, j] - terms.rho * w * g[e, r, j])
                where.append((k, side, e, r, j))
                joint.append(j)
                count += e.size
        if count == 0:
            return d, pv, terms
        cols, vals, gW, muW = np.concatenate(cols), np.concatenate(vals), np.concatenate(gW), np.concatenate(muW)
        K = self.base.banded(self.H + terms.newton_blocks(self.base.coefficients(self.x + d), pv))
        AT = np.zeros((K.size, count))  # the active rows' columns, full coefficient vector (fixed rows 0)
        AT[cols, np.repeat(np.arange(count)[:, None], 2 * m, axis=1)] = vals
        AT[~K.free] = 0.0
        delta, KAdelta = _pseudo_solve(K, AT, gW, np.concatenate(joint))  # a row touches one joint
        if delta is None or np.any(muW + delta < 0):
            return None  # a multiplier would turn negative: that row leaves W, this step does not apply
        d = d - KAdelta
        lam_lo = [np.array(x) for x in pv.mu_lo]
        lam_hi = [np.array(x) for x in pv.mu_hi]
        start = 0
        for k, side, e, r, j in where:
            target = lam_hi if side > 0 else lam_lo
            target[k][e, r, j] = muW[start:start + e.size] + delta[start:start + e.size]
            start += e.size
        terms = LimitTerms(terms.system, terms.limits, terms.rows, terms.working, tuple(lam_lo), tuple(lam_hi),
                           terms.rho, terms.margin)
        return d, terms.evaluate(self.base.coefficients(self.x + d), grad=False), terms

    def solve(self, lam: tuple, rho: float, d0: np.ndarray, feas: float = QP_FEAS) -> tuple[np.ndarray, tuple, float, bool]:
        """The QP's step d, its multipliers (lo, hi) and penalty; ok False when its rows cannot be met.

        ``feas``: the violation and active-row gap to reach (``QP_FEAS`` near the solution; looser
        while the SQP is far from it: an inexact SQP).
        """
        terms = self.terms
        d = d0
        lam_lo, lam_hi = lam
        prev, prev_crit, rho0 = math.inf, math.inf, rho
        settled = None
        for _ in range(QP_MAX_OUTER):
            t = LimitTerms(terms.system, terms.limits, terms.rows, terms.working, lam_lo, lam_hi, rho, terms.margin)
            try:
                d, pv = self.minimise(d, t)
            except NumericalError:  # H + Σ ρ a aᵀ not positive definite: H's curvature is modified
                if self.modified:
                    raise
                self.modify()
                return self.solve(lam, rho0, d0, feas)
            if self.steps > QP_BUDGET:  # degenerate active rows swapping in and out: give up (the caller falls back)
                return d, (lam_lo, lam_hi), rho, False
            viol, gap = _residuals(pv)
            pattern = _pattern(pv)
            if max(viol, gap) > feas and np.array_equal(pattern, settled):
                # the active piece repeats: its exact multipliers, kept when they do better
                step = self.dual_step(d, pv, t)
                if step is not None:
                    viol2, gap2 = _residuals(step[1])
                    if max(viol2, gap2) < max(viol, gap) and np.array_equal(_pattern(step[1]), pattern):
                        d, pv, viol, gap = step[0], step[1], viol2, gap2
            settled = pattern
            lam_lo, lam_hi = pv.mu_lo, pv.mu_hi
            if _DEBUG:
                print(f"    qp: viol {viol:.2e} gap {gap:.2e} rho {rho:.3g} active {_pattern(pv).sum()}")
            crit = max(viol, gap)
            if crit <= feas or (crit <= max(QP_STALL, feas) and crit > 0.5 * prev_crit):
                return d, (lam_lo, lam_hi), rho, True
            prev_crit = crit
            if viol > 0.25 * prev and viol > feas:
                rho *= 10.0
                if rho > 1e8 * rho0:  # the rows cannot be met (an infeasible task)
                    return d, (lam_lo, lam_hi), rho, False
            prev = viol
        return d, (lam_lo, lam_hi), rho, viol <= 1e3 * QP_FEAS


def sqp(base, system, limits: JointLimits, x0: np.ndarray, tol: float, *, max_iter: int = 50,
        margin: float = 1e-9, working: np.ndarray | None = None) -> SQPResult:
    """Minimise I(q_h) over the free coefficients of ``base`` (a ControlProblem) within the kinematic limits.

    Returns an ``SQPResult``; ``result.x`` is the last iterate (feasible for the kinematic rows after
    the first full step), ``result.converged`` when the stopping test held (module docstring).
    ``working`` (4, n) bool: the (kind, joint) pairs whose rows are imposed (default: every
    kinematic pair with a finite bound); the caller checks the others.
    """
    mesh, n = base.mesh, limits.n
    rows = LimitRows.build(mesh, base.layout.free, n)
    working = kinematic_working(limits) if working is None else working & kinematic_working(limits)
    zeros = tuple(np.zeros(rows.shape(k, n)) for k in range(len(KINDS)))
    lam = (zeros, zeros)
    x = np.asarray(x0, float)
    ev = base.evaluate(x)
    J = ev.J
    rho = RHO_QP * max(abs(J), 1e-6) / mesh.T
    probe = LimitTerms(system, limits, rows, working, zeros, zeros, rho, margin)
    history: list[IterLog] = []
    n_evals, stop, status, ok = 1, None, Status.MAX_ITER, True
    d = np.zeros_like(x)
    pv = None
    dec = math.inf
    stiff = 0
    model = None
    for it in range(max_iter + 1):
        # within REUSE_DEC·|J| of the optimum (the last decrement), H changes by O(|step|) and its
        # effect on the next step is below the rounding of J: the last model's H is kept
        model = _Model(base, ev, rows, probe, previous=model if abs(dec) <= REUSE_DEC * abs(J) else None)
        rel = dec / max(abs(J), 1e-300)
        feas = max(QP_FEAS, min(QP_LOOSE, 1e-2 * rel, rel * rel))
        d, lam, _, qp_ok = model.solve(lam, rho, np.zeros_like(x), feas)
        if not qp_ok:
            ok, status = False, Status.LINE_SEARCH_FAILED
            break
        dec = -float(ev.grad @ d + 0.5 * d @ model.Hd(d))  # the model's decrease (½ dᵀHd when H is exact)
        at_x = LimitTerms(system, limits, rows, working, lam[0], lam[1], rho, margin).evaluate(
            base.coefficients(x), grad=False)
        v0 = _violation_sum(at_x)
        pv = at_x
        feasible = at_x.max_violation() <= 1e-10
        near = feasible or at_x.max_violation() <= NEAR_FEAS  # an inexact QP's step left x just outside
        if near and (abs(dec) <= tol * abs(J) or abs(dec) <= ev.noise) and feas > QP_FEAS:
            # the stopping test is taken only on an accurately solved QP
            feas = QP_FEAS
            d, lam, _, qp_ok = model.solve(lam, rho, d, feas)
            if not qp_ok:
                ok, status = False, Status.LINE_SEARCH_FAILED
                break
            dec = -float(ev.grad @ d + 0.5 * d @ model.Hd(d))
        # |dec|: at a feasible x the QP's minimiser has dec >= 0 up to the QP's rounding (d = 0 is feasible)
        if near and (abs(dec) <= tol * abs(J) or abs(dec) <= ev.noise):
            # The last (small) step too: the QP's multipliers are exact for x + d (gradient + H d +
            # Aᵀμ = 0), to O(|d|²) at the optimum rather than O(|d|) at x; ``free_time`` uses them.
            # From an x just outside the rows, the test holds only when x + d is within them.
            final = _final_step(base, x, d, J, ev.noise, probe, rise=0.0 if feasible else 2.0 * abs(dec))
            if feasible or final is not None:
                stop, status = ("decrement" if abs(dec) <= tol * abs(J) else "rounding"), Status.CONVERGED
                if final is not None:
                    x, ev = final
                    n_evals += 1
                    J = ev.J
                    pv = LimitTerms(system, limits, rows, working, lam[0], lam[1], rho, margin).evaluate(
                        base.coefficients(x), grad=False)
                break
            n_evals += 1
        if it == max_iter:
            break
        stiff = stiff + 1 if model.mu >= STIFF_MU else 0
        if stiff >= STIFF_ITERATIONS:  # Newton steps on a Newton matrix dominated by its modification
            ok, status = False, Status.LINE_SEARCH_FAILED  # crawl: the caller's augmented Lagrangian (PR+ CG) takes over
            break
        nu = 2.0 * max(float(np.max(m, initial=0.0)) for m in lam[0] + lam[1]) + 1e-12 * abs(J)
        slope = float(ev.grad @ d) - nu * v0
        if not slope < 0 and not model.modified:  # not a descent direction: H's curvature is modified
            model.modify()
            d, lam, _, qp_ok = model.solve(lam, rho, np.zeros_like(x), feas)
            if not qp_ok:
                ok, status = False, Status.LINE_SEARCH_FAILED
                break
            nu = 2.0 * max(float(np.max(m, initial=0.0)) for m in lam[0] + lam[1]) + 1e-12 * abs(J)
            slope = float(ev.grad @ d) - nu * v0
        if model.mu >= STRONG_MU:
            ok, status = False, Status.LINE_SEARCH_FAILED
            break
        phi0 = J + nu * v0
        a, accepted = 1.0, False
        for _ in range(LS_MAX):
            try:
                trial = base.evaluate(x + a * d, grad=False)
                n_evals += 1
                Jt = trial.J
            except NumericalError:
                Jt = math.inf
            vt = _violation_sum(probe.evaluate(base.coefficients(x + a * d), grad=False))
            phi = Jt + nu * vt
            if phi <= phi0 + C1 * a * slope or (math.isfinite(phi) and abs(phi - phi0) <= 4 * ev.noise):
                accepted = True
                break
            a *= 0.5
        if not accepted:
            ok, status = False, Status.LINE_SEARCH_FAILED
            break
        x = x + a * d
        ev = base.evaluate(x)
        n_evals += 1
        J = ev.J
        if _DEBUG:
            print(f"  sqp {it}: J {J:.12g} dec {dec:.2e} alpha {a} viol {v0:.2e}")
        history.append(IterLog(it + 1, J, float(np.max(np.abs(ev.grad), initial=0.0)), dec, a, n_evals))
    msg = {"decrement": "the SQP stopping test held: |gᵀd + ½ dᵀHd| <= tol·|J| for the limited Newton step d",
           "rounding": "the SQP rounding-level test held: |gᵀd + ½ dᵀHd| <= the rounding level of J, which exceeds "
                       "tol·|J|"}
    text = msg[stop] if stop else ("the SQP's quadratic programme or line search failed" if not ok
                                   else "the SQP iteration limit was reached")
    result = OptimizeResult(x=x, fun=J, grad=ev.grad, status=status, iterations=len(history), n_evals=n_evals,
                            n_precond=len(history) + 1, decrement=abs(dec), history=tuple(history), message=text,
                            stop_test=StopTest(stop) if stop else None)
    return SQPResult(ok=ok, result=result, penalty=pv)


def _pseudo_solve(K, AT: np.ndarray, gW: np.ndarray,
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


def _final_step(base, x: np.ndarray, d: np.ndarray, J: float, noise: float, probe: LimitTerms,
                rise: float = 0.0):
    """(x + d, its evaluation) when x + d is within the imposed rows (to 1e-10) and J does not rise
    beyond its rounding level (+ ``rise``: the model's predicted rise from an x just outside the
    rows); else None.
    """
    try:
        ev = base.evaluate(x + d)
    except NumericalError:
        return None
    feasible = probe.evaluate(base.coefficients(x + d), grad=False).max_violation() <= 1e-10
    return (x + d, ev) if feasible and ev.J <= J + 4 * noise + rise else None


def _line_minimum(slope: float, curvature: float, terms: LimitTerms, at0: PenaltyValue, at1: PenaltyValue) -> float:
    """The minimiser a > 0 of q(d + a s): the root of the increasing piecewise-linear q'(a).

    slope = ∇q(d)ᵀs, curvature = sᵀHs; at0, at1 the rows at d and d + s (g is linear in a).
    q'(a) = slope + a·curvature + Σ_i Δg_i (max(0, c_i + a ρ_i Δg_i) − max(0, c_i)), c_i = λ_i + ρ_i g_i.
    """
    c0, c1, dg = [], [], []
    for k in range(len(KINDS)):
        rw = terms.rho * terms.rows.weight(k)
        for lam, g0, g1 in ((terms.lam_lo[k], at0.g_lo[k], at1.g_lo[k]), (terms.lam_hi[k], at0.g_hi[k], at1.g_hi[k])):
            on = np.isfinite(g0)
            if on.any():
                delta = g1[on] - g0[on]
                w = np.broadcast_to(rw, g0.shape)[on]  # non-uniform mesh: a penalty per row
                c0.append(lam[on] + w * g0[on]), c1.append(w * delta), dg.append(delta)
    if not c0:
        return -slope / curvature
    c0, c1, dg = np.concatenate(c0), np.concatenate(c1), np.concatenate(dg)
    base = slope - float(dg @ np.maximum(c0, 0.0))  # q'(a) = base + a·curvature + Σ dg max(0, c0 + a c1)
    with np.errstate(divide="ignore", invalid="ignore"):
        b = np.where(c1 != 0, -c0 / c1, -1.0)
    cross = b > 0
    order = np.argsort(b[cross])
    bk = b[cross][order]
    enter = (c1[cross] > 0)[order]
    jump = np.where(enter, 1.0, -1.0) * (dg[cross] * c1[cross])[order]  # slope change at each breakpoint
    act0 = (c0 > 0) | ((c0 == 0) & (c1 > 0))
    S0 = curvature + float(np.sum((dg * c1)[act0]))
    v0 = base + float(np.sum((dg * c0)[act0]))  # q'(0+)
    if bk.size == 0:
        return -v0 / S0
    S = S0 + np.concatenate([[0.0], np.cumsum(jump)])  # slope on [b_{k-1}, b_k], b_0 = 0
    knots = np.concatenate([[0.0], bk])
    vals = v0 + np.concatenate([[0.0], np.cumsum(S[:-1] * np.diff(knots))])  # q' at the knots
    k = int(np.argmax(vals >= 0)) if (vals >= 0).any() else len(vals)
    k = max(k, 1)
    return float(knots[k - 1] - vals[k - 1] / S[k - 1])


def _residuals(pv: PenaltyValue) -> tuple[float, float]:
    """(largest violation, largest distance of an active row (μ > 0) from its bound), dimensionless."""
    gap = max(float(np.max(np.abs(g[m > 0]), initial=0.0)) for g, m in zip(pv.g_lo + pv.g_hi, pv.mu_lo + pv.mu_hi))
    return pv.max_violation(), gap


def _pattern(pv: PenaltyValue) -> np.ndarray:
    """The rows where μ > 0 (the active piece of Φ), flattened."""
    return np.concatenate([(m > 0).ravel() for m in pv.mu_lo + pv.mu_hi])


def _violation_sum(pv: PenaltyValue) -> float:
    """Σ max(0, g) over every row (dimensionless)."""
    return float(sum(np.sum(np.maximum(g, 0.0)) for g in pv.g_lo + pv.g_hi))
