"""Kinematic limits by sequential quadratic programming (SQP) on hoc's banded Newton matrix.

The position, velocity and acceleration limits are imposed through Bernstein rows
(``bernstein.py``): LINEAR inequalities a_iᵀx ≤ b_i in the design vector x. For linear
constraints an SQP step keeps every linearisation exact, so each iteration is

1. at x: the cost's gradient g and its banded Newton matrix H (made positive definite as in
   ``ControlProblem.positive_definite``), both assembled ONCE per iteration (an exact H is kept
   from the previous iteration when that one's decrement was below ``REUSE_DEC``·|J|: H changes
   by O(|step|), the step is then a chord step, and the stopping test below is unchanged);
2. the quadratic programme  min_d gᵀd + ½dᵀHd  subject to  a_iᵀ(x + d) ≤ b_i  for every row,
   solved to high accuracy by the method of multipliers on the QP itself: its inner problems are
   piecewise quadratic, minimised by semismooth Newton steps whose matrices H + Σ_active ρ_i a_i a_iᵀ
   keep H's band (each row lies in one element), so an inner step is one banded Cholesky and no
   dynamics. The multipliers (λ ≥ 0, warm-started from the previous iteration) converge linearly at
   a rate ~1/ρ, with ρ large because these solves are cheap; redundant active rows (a limit active
   along a whole element makes its Bernstein rows linearly dependent) do not hurt the method of
   multipliers, as they would an active-set solve of the KKT system. Once the active rows repeat,
   their exact multipliers (a Newton step on the dual) finish the QP. The rows are gathered once
   per SQP into an explicit sparse matrix (``hoc_cli.constraints.qp``, which holds the QP);
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

import logging
import math
from dataclasses import dataclass

import numpy as np

from hoc_cli.constraints.bounds import KINDS, JointLimits
from hoc_cli.constraints.penalty import EFFORT, LimitRows, LimitTerms, PenaltyValue
from hoc_cli.constraints.qp import QP_FEAS, QPModel, QPRows
from hoc_cli.errors import NumericalError
from hoc_cli.optimize import IterLog, OptimizeResult, Status
from hoc_cli.optimize.result import StopTest

_log = logging.getLogger(__name__)  # solver traces at DEBUG level (docs/design.md)
RHO_QP = 1e4  # the QP's penalty per unit time, × |J|/T
QP_LOOSE = 1e-7  # the QP's loosest tolerance, far from the solution (it is min(1e-2 r, r²), r the last relative
# decrement: the next decrement is about r² (Newton), and a step whose violation is not well below it
# fails the merit line search; ``QP_FEAS`` near the solution)
STIFF_MU = 10.0  # H + μ·GN with μ >= this is mostly GN: the SQP hands over after
STIFF_ITERATIONS = 3  # this many such iterations in a row
STRONG_MU = 100.0  # ... and at once when μ >= this (a strongly indefinite H: the torque cost far from its optimum)
LS_MAX = 40
REUSE_DEC = 1e-3  # relative decrement below which the SQP keeps its last (unmodified) Newton matrix
NEAR_FEAS = 1e-6  # the stopping test from an x this close to its rows (dimensionless) looks at x + d
C1 = 1e-4
STALLS = 2  # iterations in a row from a feasible x whose J falls by at most tol·|J| (or whose model predicts no
STALL_FEAS = 1e-9  # decrease): the SQP stops, not converged; feasible: Σ max(0, g) at most this
SLOW_WINDOW, SLOW_RATE = 5, 0.5  # ... and when the decrement from feasible points does not halve in 5 iterations


def kinematic_working(limits: JointLimits) -> np.ndarray:
    """(K, n) bool: every (kinematic kind, joint) pair with a finite bound; effort excluded."""
    working = np.zeros((len(KINDS), limits.n), bool)
    for k in range(EFFORT):
        lo, hi = limits.bounds(KINDS[k])
        working[k] = np.isfinite(lo) | np.isfinite(hi)
    return working


@dataclass(frozen=True, eq=False)
class SQPResult:
    """The SQP's outcome: ok (False: the QP or the line search failed; the caller falls back),
    result (an OptimizeResult on the cost J alone; ``result.fun`` is J at ``result.x``), penalty (the
    rows' values and multipliers μ at x), rows (the ``LimitRows`` of the mesh), crawled (it stopped
    because its decrement no longer halved in ``SLOW_WINDOW`` iterations).
    """

    ok: bool
    result: OptimizeResult
    penalty: PenaltyValue | None
    rows: LimitRows
    crawled: bool = False


def sqp(base, system, limits: JointLimits, x0: np.ndarray, tol: float, *, max_iter: int = 50,
        margin: float = 1e-9, working: np.ndarray | None = None,
        multipliers: tuple[tuple, tuple] | None = None) -> SQPResult:
    """Minimise I(q_h) over the free coefficients of ``base`` (a ControlProblem) within the kinematic limits.

    Returns an ``SQPResult``; ``result.x`` is the last iterate (feasible for the kinematic rows after
    the first full step), ``result.converged`` when the stopping test held (module docstring).
    ``working`` (K, n) bool: the (kind, joint) pairs whose rows are imposed (default: every
    kinematic pair with a finite bound); the caller checks the others. ``multipliers`` (λ_lo, λ_hi),
    per kind in the kinds' row shapes (e.g. a previous solve's, ``prolong``-ed to this mesh): the
    first QP's multipliers when, started from 0, that QP needs H's modification (else unused). With
    the rows active at the optimum in its first Newton matrix H + Σ ρ a aᵀ, that matrix is positive
    definite where H + Σ ρ a aᵀ over the rows a cold start activates is not (the torque cost), so H
    is used unmodified. Stops, not converged, when ``STALLS`` iterations in a row from a feasible x
    lower J by at most tol·|J| or are predicted by the model to rise (the QP's own accuracy), or when
    the decrement from feasible points does not halve in ``SLOW_WINDOW`` iterations (a crawl, e.g.
    the torque cost near a limited optimum whose active rows keep shifting).
    """
    mesh, n = base.mesh, limits.n
    rows = LimitRows.build(mesh, base.layout.free, n)
    working = kinematic_working(limits) if working is None else working & kinematic_working(limits)
    qrows = QPRows.build(rows, limits, working, base.layout.free, margin)
    lam = np.zeros(qrows.count)
    warm = None if multipliers is None else qrows.gather(*multipliers)
    x = np.asarray(x0, float)
    ev = base.evaluate(x)
    J = ev.J
    rho = RHO_QP * max(abs(J), 1e-6) / mesh.T
    history: list[IterLog] = []
    n_evals, stop, status, ok = 1, None, Status.MAX_ITER, True
    d = np.zeros_like(x)
    dec = math.inf
    stiff = stalls = 0
    stalled = crawled = False
    decs: list[float] = []  # |decrement| per iteration (inf from an infeasible x)
    model = None
    for it in range(max_iter + 1):
        # within REUSE_DEC·|J| of the optimum (the last decrement) the last model's exact H is kept:
        # H changes by O(|step|), the step is a chord step, and the stopping test is unchanged
        g0 = qrows.at(base.coefficients(x))  # the rows at x
        keep = model is not None and not model.modified and abs(dec) <= REUSE_DEC * abs(J)
        model = QPModel(base, ev, qrows, g0, previous=model if keep else None)
        rel = dec / max(abs(J), 1e-300)
        feas = max(QP_FEAS, min(QP_LOOSE, 1e-2 * rel, rel * rel))
        H = model.H
        d, lam_qp, _, qp_ok = model.solve(lam, rho, np.zeros_like(x), feas)
        if warm is not None and model.modified:  # H needed a modification: the QP again from the given multipliers
            model.restore(H)
            d, lam_qp, _, qp_ok = model.solve(warm, rho, np.zeros_like(x), feas)
        warm, lam = None, lam_qp
        if not qp_ok:
            ok, status = False, Status.LINE_SEARCH_FAILED
            break
        dec = -float(ev.grad @ d + 0.5 * d @ model.Hd(d))  # the model's decrease (½ dᵀHd when H is exact)
        v0 = float(np.sum(np.maximum(g0, 0.0)))
        feasible = float(np.max(g0, initial=0.0)) <= 1e-10
        near = feasible or float(np.max(g0, initial=0.0)) <= NEAR_FEAS  # an inexact QP's step left x just outside
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
            final = _final_step(base, x, d, J, ev.noise, qrows, rise=0.0 if feasible else 2.0 * abs(dec))
            if feasible or final is not None:
                stop, status = ("decrement" if abs(dec) <= tol * abs(J) else "rounding"), Status.CONVERGED
                if final is not None:
                    x, ev = final
                    n_evals += 1
                    J = ev.J
                break
            n_evals += 1
        if it == max_iter:
            break
        stiff = stiff + 1 if model.mu >= STIFF_MU else 0
        if stiff >= STIFF_ITERATIONS:  # Newton steps on a Newton matrix dominated by its modification
            ok, status = False, Status.LINE_SEARCH_FAILED  # crawl: the caller's augmented Lagrangian (PR+ CG) takes over
            break
        nu = 2.0 * float(np.max(lam, initial=0.0)) + 1e-12 * abs(J)
        slope = float(ev.grad @ d) - nu * v0
        if not slope < 0 and not model.modified:  # not a descent direction: H's curvature is modified
            model.modify()
            d, lam, _, qp_ok = model.solve(lam, rho, np.zeros_like(x), feas)
            if not qp_ok:
                ok, status = False, Status.LINE_SEARCH_FAILED
                break
            nu = 2.0 * float(np.max(lam, initial=0.0)) + 1e-12 * abs(J)
            slope = float(ev.grad @ d) - nu * v0
        if model.mu >= STRONG_MU:
            ok, status = False, Status.LINE_SEARCH_FAILED
            break
        phi0 = J + nu * v0
        a, accepted, trial = 1.0, False, None
        for _ in range(LS_MAX):
            try:  # the full step with its gradient: it is usually accepted, and then not evaluated again
                trial = base.evaluate(x + a * d, grad=a == 1.0)
                n_evals += 1
                Jt = trial.J
            except NumericalError:
                trial, Jt = None, math.inf
            vt = float(np.sum(np.maximum(qrows.at(base.coefficients(x + a * d)), 0.0)))
            phi = Jt + nu * vt
            if phi <= phi0 + C1 * a * slope or (math.isfinite(phi) and abs(phi - phi0) <= 4 * ev.noise):
                accepted = True
                break
            a *= 0.5
        if not accepted:
            ok, status = False, Status.LINE_SEARCH_FAILED
            break
        x = x + a * d
        if trial is None or trial.grad is None:
            ev = base.evaluate(x)
            n_evals += 1
        else:
            ev = trial
        stalls = stalls + 1 if (J - ev.J <= tol * abs(J) or dec <= 0) and v0 <= STALL_FEAS else 0
        decs.append(abs(dec) if v0 <= STALL_FEAS else math.inf)
        if len(decs) > SLOW_WINDOW and decs[-1] > SLOW_RATE * decs[-1 - SLOW_WINDOW]:
            stalls, crawled = STALLS, True  # feasible, and the decrement does not halve in SLOW_WINDOW iterations
        J = ev.J
        if _log.isEnabledFor(logging.DEBUG):
            _log.debug(f"  sqp {it}: J {J:.12g} dec {dec:.2e} alpha {a} viol {v0:.2e}")
        history.append(IterLog(it + 1, J, float(np.max(np.abs(ev.grad), initial=0.0)), dec, a, n_evals))
        if stalls >= STALLS:  # feasible, and J no longer falls: the QP's steps are at its own accuracy
            stalled = True
            break
    msg = {"decrement": "the SQP stopping test held: |gᵀd + ½ dᵀHd| <= tol·|J| for the limited Newton step d",
           "rounding": "the SQP rounding-level test held: |gᵀd + ½ dᵀHd| <= the rounding level of J, which exceeds "
                       "tol·|J|"}
    text = msg[stop] if stop else ("the SQP's quadratic programme or line search failed" if not ok
                                   else "the SQP crawled (its decrement did not halve in 5 iterations)" if crawled
                                   else "the SQP stalled (J no longer falls, the stopping test not met)" if stalled
                                   else "the SQP iteration limit was reached")
    lo, hi = qrows.scatter(lam)  # the rows and their multipliers at the last x (the last QP's λ)
    pv = LimitTerms(system, limits, rows, working, lo, hi, rho, margin).evaluate(base.coefficients(x), grad=False)
    result = OptimizeResult(x=x, fun=J, grad=ev.grad, status=status, iterations=len(history), n_evals=n_evals,
                            n_precond=len(history) + 1, decrement=abs(dec), history=tuple(history), message=text,
                            stop_test=StopTest(stop) if stop else None)
    return SQPResult(ok=ok, result=result, penalty=pv, rows=rows, crawled=crawled)


def _final_step(base, x: np.ndarray, d: np.ndarray, J: float, noise: float, qrows: QPRows,
                rise: float = 0.0):
    """(x + d, its evaluation) when x + d is within the imposed rows (to 1e-10) and J does not rise
    beyond its rounding level (+ ``rise``: the model's predicted rise from an x just outside the
    rows); else None.
    """
    try:
        ev = base.evaluate(x + d)
    except NumericalError:
        return None
    feasible = float(np.max(qrows.at(base.coefficients(x + d)), initial=0.0)) <= 1e-10
    return (x + d, ev) if feasible and ev.J <= J + 4 * noise + rise else None
