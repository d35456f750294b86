"""The Newton (SQP) steps of a warm replan with the kinematic limits as inequality rows of every step.

Each step solves, densely and exactly (``qp_step.solve_qp``), the quadratic programme of the Lagrangian
ℒ = I + λ·c + μ·g_A + weight·T at the current (x, T):

    min  ∇Iᵀdx + F_I·dT + ½ [dx; dT]ᵀ H [dx; dT]
    s.t. D dx + c_T dT = −c                  (the goal rows, linearised)
         A dx + a_T dT ≤ −g_A                (the Bernstein rows within ``CANDIDATE_GAP`` of their bound)
         T_min ≤ T + dT ≤ T_max              (a free T)

H: the banded Newton matrix of ℒ (the cost's exact Hessian on its own quadrature, the goal rows' curvature
Σλ∇²c weighed by the multipliers λ; the limit rows are linear in x) plus ρDᵀD, which makes it positive definite where the final q is
held by the goal rows alone without changing the step (the multipliers absorb −ρc), and ρAᵀA over the
working set's rows (the limits hold the motion there; zero along steps that keep them); its T row and
column b = ∂∇ℒ/∂T, h = ∂²ℒ/∂T² along the rescaled family are exact (``replan_point.time_column``: from the
cost's per-sample Hessians the Newton matrix was made of, so one evaluation of ℒ per step), and so are the rows'
T columns c_T, a_T (a Bernstein row of d^k q/dt^k scales as T^−k); only at a step whose Newton matrix was made
elsewhere (the previous replan's last: on the real-time path, ``quick``, or with T fixed) are b and h a forward difference
at T + δ. Offline steps in x and T make their first Newton matrix afresh: against the fixed-T steps' last matrix the
differenced column's h − bᵀH⁻¹b came out 1e7 on the lbr7 catch (−700 with its own matrix), and the first step in T
moved T by 7e-7 s instead of 0.04 s. The programme's multipliers are the next ones: the rows with μ > 0 are the
next working set (their μ·g_A enters ℒ's T derivatives). Since every step's working set is that of its
own programme, a change of the active limits costs no extra rounds. A step that would break a Bernstein row
outside the programme (g > 0 at the step's end; far from the optimum, steps are long) is re-solved with those rows
added (at most ``EXPAND_ROUNDS`` times): the rows are linear in x, so at a fixed T the step then keeps every one.
On the real-time path (``quick``) that programme, whose least-distance solve costs in proportion to its rows, not
its active ones, is solved over the last programme's active rows and the rows added first, then with any left-out
row its step breaks (``solve_qp_within``): the same step (multipliers of dependent rows may be shared otherwise).
Off it, each step's first programme is solved so over the last step's active rows and the candidates new to it:
the multipliers of dependent rows (a limit held along an element) are then shared as the last step shared them,
so the working set does not change from step to step with the programme's pick (from every row and no active one,
the Panda reach's steps on 4 elements cycled between 29 and 31 active rows: 44 steps there, 38 so).
When the goal rows' violation floor (the step may not raise the violation above max(violation, 1e-3)) or the
merit test would cut the full step, its second-order correction is tried first (``_corrected_step``); when that
too is cut, the step is halved (``damped_trial``). On the lbr7 catch's steps from scratch (4 elements) the two
take 21 steps where the halved steps alone take 50.

It stops when the programme's decrease −(∇Iᵀd + ½dᵀHd) is within ±``tol``·|J| (a negative one, a step that must
raise the model to reach the rows, is no optimum), the goal rows are met to 1e-9
(m, rad, m/s), the imposed rows to 1e-9 (relative to the limit) and, with a free T, |∂ℒ/∂T| ≤
1e-7·(|J|/T + weight) or T sits at a bound it is pushed against (``minimize_time``'s test), with the
exact extrema check to confirm. Pure maths: no I/O.
"""
from __future__ import annotations

import functools
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_triangular

from hoc_cli.banded import element_blocks, element_blocks_kron
from hoc_cli.constraints.check import check_limits
from hoc_cli.errors import NumericalError
from hoc_cli.free_time import fixed_coefficient_motion, rescale, row_time_derivatives
from hoc_cli.goals.active_limits import ActiveRows
from hoc_cli.goals.mesh import mesh_fractions
from hoc_cli.goals.plan import EQ_ACCEPT
from hoc_cli.goals.qp_step import Programme, QPStep, bordered_factor, solve_qp, solve_qp_within
from hoc_cli.goals.replan_point import (
    VIOLATION_FLOOR,
    damped_trial,
    dense_factor,
    evaluate_point,
    goal_values,
    goal_violation,
    point_problem,
    row_values,
    time_column,
)
from hoc_cli.goals.terms import GoalTerms
from hoc_cli.optimize import Status
from hoc_cli.optimize.modify import gauss_newton_shift

_log = logging.getLogger(__name__)  # solver traces at DEBUG level (docs/design.md)
CANDIDATE_GAP = 0.05  # a Bernstein row within this fraction of its limit's size (g > −gap) enters the step's QP
ROW_ACCEPT = 1e-9  # the imposed rows' violation (relative to the limit's size) of a converged replan
SLOPE_RTOL = 1e-7  # |F| = |dℒ/dT| relative to |J|/T + weight at a free T's optimum (as the search's)
LM_START = 1e-8  # the first Levenberg-Marquardt shift after a step the merit test cut below a quarter
LM_MAX = 1e3  # the Levenberg-Marquardt shift stops growing here (the diagonal raised a thousandfold: steps far shorter than
# Newton's, whose programme would otherwise be solved in units of 1e17 and more)
MU_RTOL = 1e-10  # a row joins the working set when its multiplier exceeds this × the step's largest (not rounding)
EXPAND_ROUNDS = 4  # per step: programmes re-solved with the kinematic rows the step would break added
CORRECTION = True  # a step the goal rows' violation floor or the merit test would cut tries its second-order correction
LAG_RTOL = 1e-10  # after a step whose model decrease was within ±this·|J|, the next QP keeps the step's Newton matrix
CHECKPOINTS = ("newton", "slope", "programme", "trial")  # where a step asks ``late`` (``qp_steps``)
RUNAWAY = 1e16  # a programme whose decrease exceeds this·max(|J|, 1) (1/ε: beyond what J resolves) ends the steps


def _newton(problem, ev, extra_of: Callable[[bool], np.ndarray | None], shift: float, quick: bool,
            weights: dict | None = None, samples=None, known: tuple | None = None):
    """The Newton matrix (``BandedSPD``) of the cost plus the element blocks ``extra_of(indefinite)`` at ``ev``: with
    the goal rows' full curvature (``indefinite`` True), else without the curvature's negative part; each factored
    as it is, then (not ``quick``) made positive definite by adding μ times the cost's positive semi-definite part
    plus the same blocks (``gauss_newton_shift``), and both share one Hessian sweep. The shift of the first is only
    searched when that part plus the blocks factors (else no μ can help: the rows' own negative curvature is the
    cause); ``weights`` keeps the last μ accepted for each, and the next search starts a decade below it. ``samples``: ev's
    ``SampleGradients`` (their torques and mass matrices serve the Hessian sweep, ``hessian_samples``). ``quick``
    (the real-time replanner's steps, where time counts): the first is not shifted. ``known``: the cost's per-sample
    Hessians and their positive semi-definite parts to use instead of ev's (``hessian_samples``' pair). Returns (the
    factored matrix, that pair or None); raises ``NumericalError`` when neither is positive definite.
    """
    if problem.terms:
        try:
            return problem.newton(ev, extra=extra_of(True), shift=shift), None
        except NumericalError:
            return problem.newton(ev, extra=extra_of(False), shift=shift), None
    weights = {} if weights is None else weights
    Hs, GNs = known if known is not None else _hessian_samples(problem, ev, samples)
    blocks = element_blocks_kron if quick else element_blocks  # the same blocks to rounding, fewer products
    Hb = blocks(problem.op_h, Hs)
    GNb = None
    for indefinite in (True, False):
        extra = extra_of(indefinite)
        if not indefinite and extra is None:
            raise NumericalError("the Newton matrix is not positive definite")
        H = Hb if extra is None else Hb + extra
        try:
            return problem.banded(H, shift), (Hs, GNs)
        except NumericalError:
            if quick and indefinite:
                continue
        GNb = blocks(problem.op_h, GNs) if GNb is None else GNb
        GN = GNb if extra is None else GNb + extra
        try:
            limit = problem.banded(GN, shift)  # the shift's limit: no μ helps when it does not factor
        except NumericalError:
            if indefinite:
                continue
            raise
        last = weights.get(indefinite)
        mu, factored = gauss_newton_shift(H, GN, lambda M: problem.banded(M, shift),
                                          start=None if last is None else 0.1 * last)
        if factored is not None:
            weights[indefinite] = mu
            return factored, (Hs, GNs)
        return limit, (Hs, GNs)
    raise NumericalError("the Newton matrix is not positive definite")


def _hessian_samples(problem, ev, samples) -> tuple[np.ndarray, np.ndarray]:
    """``problem.hessian_samples(ev, samples)``, kept on the problem for its quadrature and ev's x: a later Newton matrix
    at the same point of the same problem (the next replan's first, from this one's last point) reuses them.
    """
    kept = getattr(problem, "_replan_hessians", None)
    if kept is not None and kept[0] is problem.op and np.array_equal(kept[1], ev.x):
        return kept[2]
    out = problem.hessian_samples(ev, samples)
    problem._replan_hessians = (problem.op, np.array(ev.x), out)
    return out


def _blocks(problem, lam: list, rho: float, C: np.ndarray, res, held: np.ndarray | None, indefinite: bool, where=None,
            parts: list | None = None, samples: list | None = None):
    """Element blocks added to the cost's Newton matrix: the goal rows' Σλ∇²c + ρDᵀD (its negative part
    dropped unless ``indefinite``) and ρAᵀA of the working set's rows (``held``; zero at a step that keeps
    them, so the programme's solution keeps its meaning while the matrix is positive definite where the
    limits hold the motion). ``parts``: ``GoalTerms.newton_blocks``' store, shared by the calls at one point;
    ``samples``: the point's ``curvature_samples``.
    The curvature's weights are the multipliers λ themselves, as in the T column (``time_column``), where
    ``GoalTerms`` weighs by the augmented Lagrangian's λ + ρc: away from the rows (c ≠ 0, after a long step in T or
    a jump of the real-time target) ρc outweighs λ and the x block with λ + ρc turns indefinite. Offline, that block
    lost its negative part while the T column kept λ's, and the programme's curvature in T with x following
    (h − bᵀH⁻¹b) came out 100 to 1000 times the reduced objective's, so the next step left T where it was (the lbr7
    catch's coarse steps in x and T: every second step, 17 steps where these weights take 10); on the real-time
    path (``quick``) 2 of the 7 updates of ``benchmarks/replay_realtime.py`` needed the second factorisation without
    the negative part, none with λ.
    """
    out = held
    if problem.points:
        # λ − ρc with GoalTerms' ρ: weights λ on the curvature, ρDᵀD unchanged
        rows = res if res is not None else GoalTerms(problem.mesh, problem.points, lam, rho, where).residuals(C)
        lam = [np.asarray(v, float) - rho * r[0] for v, r in zip(lam, rows)]
        goal = GoalTerms(problem.mesh, problem.points, lam, rho, where).newton_blocks(C, indefinite=indefinite, res=res,
                                                                                      parts=parts, samples=samples)
        out = goal if out is None else out + goal
    return out


@dataclass(eq=False)
class QPReplan:
    """Where the steps ended: the point (``LagrangianPoint``), T [s], the multipliers (goal rows', then the
    working set's), the working set, status, steps, evaluations, the last decrease, the last Newton matrix's
    dense factor (x block), the exact limit check at the last point when it was made.
    """

    point: object
    T: float
    lam: list
    active: ActiveRows
    status: Status
    steps: int
    evals: int
    decrement: float
    factor: np.ndarray | None = None
    check: object = None
    derive: Callable[[], object] | None = None  # when ``point`` has no derivatives (g None): the point with them
    J_from: float = math.nan  # the cost at the point the last programme was made at (its decrement's point)
    hessians: tuple | None = None  # the cost's sample Hessians of the last Newton matrix (``_newton``'s pair)


class OutOfTime(Exception):
    """Raised by ``qp_steps`` when its ``late`` callback says the step under way would end after its deadline."""


def qp_steps(system, plan0, goals, lam: list, active: ActiveRows, *, free, limits, tol: float, max_steps: int,
             rho_aug: float, floor: float = VIOLATION_FLOOR, merit: bool = False,
             stop: Callable[[int], bool] | None = None, quick: bool = False,
             late: Callable[[str], bool] | None = None, accuracy: float | None = None,
             relative_rho: bool = False, cache: dict | None = None, hessians: tuple | None = None) -> QPReplan:
    """The SQP steps from the previous plan ``plan0`` (module docstring).

    lam : the goal rows' multipliers (one array per goal point) followed by the working set's (a,);
    active : the working set (the previous plan's kinematic rows with μ > 0); free : ``TimeRange`` or None;
    limits : ``JointLimits`` (kinematic limits only are imposed here); rho_aug : ρ of H + ρDᵀD (``relative_rho``:
        ρ = rho_aug·max(|J|, 1) with the cost J at the steps' first point);
    floor : a step is damped while it raises the goal rows' violation above max(violation, floor) (``damped_trial``);
    merit : also while it does not decrease the ℓ1 merit function (``MeritTest``): for steps far from the optimum;
        then the Newton matrix's diagonal is raised by a relative Levenberg-Marquardt shift (``LM_START``, ×10 after
        each step cut below a quarter, ÷10 after a full step, 0 below ``LM_START``).
    stop : asked with the number of steps taken after each step (before the next point's Newton matrix); True ends
        the steps there (a time budget: ``hoc_cli.realtime``); the result's decrement is then the last programme's
        (at the point before the step) and it carries no factor.
    quick : the Newton matrix with the goal rows' full curvature is factored once as it is, and when it is not
        positive definite the curvature's negative part is dropped at once (``_newton``; without it the cost's
        positive semi-definite part is first added in growing multiples, up to 13 more factorisations); with ``stop``,
        the point after the ``max_steps``-th step (where ``stop`` ends the steps) is evaluated without ℒ's derivatives
        (``evaluate_point(..., derivatives=False)``: its g None; the result's ``derive()`` evaluates them there, and
        should ``stop`` not end the steps they are evaluated before the next one), and without merit its cost is not
        evaluated either (``value=False``: its J NaN; ``derive()``'s point has it): the real-time replanner's steps,
        where time counts.
    late : asked with a checkpoint's name (``CHECKPOINTS``) at each checkpoint of a step (before the Newton
        matrix, before the T column's evaluation, before each programme, before the trial point); True stops the
        steps there (a hard time budget: the real-time replanner): in the first step ``OutOfTime`` is raised (the
        caller keeps its plan), in a later one the steps end at the point the last completed step reached, as
        after ``stop``.
    accuracy : when given, the stopping test's decrement (relative to |J|), goal rows (m, rad, m/s) and |∂ℒ/∂T|
        (relative to |J|/T + weight) are met to it instead of ``tol``, ``EQ_ACCEPT`` and ``SLOPE_RTOL`` (the imposed
        rows still to ``ROW_ACCEPT``, the check still exact; when the check finds a limit broken there, the steps go on
        to the full test): a coarse stage whose optimum only starts the mesh's steps.
    relative_rho : see rho_aug.
    cache : the points' problems by T (``replan_point.point_problem``) of an earlier replan on the same mesh,
        quadrature, cost, x0 and goals: where the steps evaluate a point it evaluated last on a problem, its dynamics,
        goal rows and Hessian samples are reused (``evaluate_point``, ``_hessian_samples``).
    hessians : the cost's sample Hessians (``_newton``'s pair, a ``QPReplan``'s ``hessians``) of a point at most a
        tiny step from plan0's x (the stopping test of the replan that ended there, ``keeps_factor``): the first
        Newton matrix is made from them, with this point's rows' blocks, instead of a new sweep (as that test used them).
    """
    mesh0, problem0 = plan0.mesh, plan0.problem
    order, N, G, cost = mesh0.order, mesh0.N, plan0.G, problem0.cost
    fractions = mesh_fractions(mesh0)  # a non-uniform mesh scales with T
    q0, dq0 = problem0.boundary[:2]
    T, C = mesh0.T, np.array(plan0.coeffs)
    weight = free.weight if free is not None else 0.0
    npts = len(lam) - 1
    cache = {} if cache is None else cache  # the points' problems by T (``point_problem``), perhaps an earlier replan's

    def at(T_, C_, lam_, active_, derivatives=True, value=True):
        return evaluate_point(system, order, N, T_, C_, q0, dq0, goals, cost, G, lam_, limits, None, weight,
                              free is not None, cache, active_, fractions=fractions, derivatives=derivatives, value=value)

    def at_rows(T_):  # the kinematic rows of the mesh at T_
        return point_problem(system, order, N, T_, q0, dq0, goals, cost, G, limits, cache, fractions)[1]

    def goal_rows_at(T_, C_):  # the goal rows' violation alone (``at``'s, without the dynamics)
        return goal_violation(system, order, N, T_, C_, q0, dq0, goals, cost, G, limits, cache, fractions=fractions,
                              slope=free is not None)

    def goal_values_at(T_, C_):  # (limit rows, C, the goal rows) alone (``at``'s, without the dynamics)
        return goal_values(system, order, N, T_, C_, q0, dq0, goals, cost, G, limits, cache, fractions=fractions,
                           slope=free is not None)

    def due(name: str) -> None:
        if late is not None and late(name):
            raise OutOfTime(name)

    pt = at(T, C, lam, active)
    if relative_rho:
        rho_aug = rho_aug * max(abs(pt.J), 1.0)
    full = (tol, EQ_ACCEPT, SLOPE_RTOL)  # the stopping test's decrement, goal rows and T slope
    tol, eq_tol, slope_rtol = full if accuracy is None else (accuracy, accuracy, accuracy)
    status, steps, evals, decrement = Status.MAX_ITER, 0, 0, math.inf
    J_from = pt.J
    U_last = check = Hs_last = pair_last = None
    previous = None  # (the last step's programme outcome, its candidate rows)
    test = MeritTest(system, limits, r_goal=sum(v.size for v in lam[:npts]), weight=weight) if merit else None
    weights: dict = {}  # the Gauss-Newton weights last accepted (``_newton``)
    lm = 0.0  # with the merit test: a Levenberg-Marquardt shift of the Newton matrix (relative, as BandedSPD's)
    done = 0  # steps completed (a step is applied at its end)
    try:
        while True:
            if stop is not None and steps and stop(steps):
                U_last = None  # the last factor is the point's before the step
                break
            if pt.g is None:  # evaluated as the last point (``last`` below), but the steps go on: with its derivatives
                pt = at(T, pt.C, lam, active)
            evals += 1
            problem, C = pt.problem, pt.C
            layout = problem.layout
            P = pt.x.size
            r = sum(v.size for v in lam[:npts])
            E, cg = pt.D[:r], pt.c[:r]
            g_I = pt.g - pt.D.T @ np.concatenate(lam) if pt.D.size else pt.g
            Hs = None  # the cost's per-sample Hessians of the Newton matrix U (the T column's b, h come from them)
            if steps == 0 and _fits(plan0.newton_factor, pt.x.size) and (quick or free is None):
                U = plan0.newton_factor  # the previous replan's last Newton matrix, at this very x (no samples: b, h differenced)
            elif U_last is not None and keeps_factor(decrement, pt.J):
                U = U_last  # the last step was tiny: its Newton matrix serves the stopping test (and a last step)
                Hs = Hs_last  # and its sample Hessians the T column (with this point's gradients)
            else:
                due("newton")
                held = active.gram_blocks(pt.rows, limits, rho_aug) if active.size else None
                parts: list = []  # the goal rows' curvature at this point, for both calls

                def extra_of(indefinite: bool, held=held, C=C, parts=parts):  # far from the optimum: without the negative part
                    return _blocks(problem, lam[:npts], rho_aug, C, pt.res, held, indefinite, pt.where, parts,
                                   pt.curvature_samples)

                known = hessians if steps == 0 and hessians is not None and hessians[0].shape[0] == problem.op.w.size \
                    else None
                try:
                    W, pair = _newton(problem, pt.ev, extra_of, lm, quick, weights, pt.samples, known)
                except NumericalError:
                    if _log.isEnabledFor(logging.DEBUG):
                        _log.debug(f"qp step {steps}: the Newton matrix is not positive definite")
                    break
                U = dense_factor(W)
                Hs, pair_last = (None, None) if pair is None else (pair[0], pair)
            U_last, Hs_last = U, Hs
            everything = row_values(limits, pt.rows, C)
            lo_mask = tuple(g > -CANDIDATE_GAP for g in everything.g_lo)
            hi_mask = tuple(g > -CANDIDATE_GAP for g in everything.g_hi)
            violation = max(float(np.max(np.abs(cg), initial=0.0)), 0.0)
            grad, rhs_E = g_I, -cg
            if free is not None:
                due("slope")
                col = time_column(pt, lam, active, Hs)  # act_T: the working set's rows' T column (ρAᵀA's T part)
                b, h, cT, act_T = col.b, col.h, col.c_T, col.held_T
                if b is None:  # a Newton matrix made elsewhere (no sample Hessians here): b, h by the difference at T + δ
                    b, h = _difference_column(pt, T, at, lam, active)
                    evals += 1
                V1 = fixed_coefficient_motion(layout.free, C, T)[0]
                b = b + E.T @ (rho_aug * cT) + pt.D[r:].T @ (rho_aug * act_T)
                h = h + rho_aug * float(cT @ cT + act_T @ act_T)
                v = solve_triangular(U, b, trans="T", check_finite=False)
                schur = h - float(v @ v)  # the model's curvature in T with x following: made positive (its size kept)
                if schur <= 1e-9 * abs(h):
                    h = float(v @ v) + max(abs(schur), 1e-6 * abs(h))
                U = bordered_factor(U, b, h)
                # the T derivative of I + weight·T as the Lagrangian's minus the rows' own T columns times their
                # multipliers: the programme's T row then agrees with ℒ's exactly (ℒ's limit part is analytic)
                F_I = pt.F - float(cT @ np.concatenate(lam[:npts])) - float(act_T @ lam[-1]) if r else pt.F - float(act_T @ lam[-1])
                grad = np.concatenate([g_I, [F_I]])
                E = np.hstack([E, cT[:, None]])
            failed, kept = False, None
            # the elimination of E shared by the rounds and the correction; quick: each row transformed once (``keys``)
            prog = Programme(U, grad, E, keyed=quick)
            keys = None
            for rounds in range(EXPAND_ROUNDS + 1):
                cand = ActiveRows.where(lo_mask, hi_mask)
                A, A_full = cand.jacobian(pt.rows, limits, layout.free)
                values = A_full @ C.ravel()
                gA = values + cand.offsets(limits)
                rhs_A = -gA
                if quick:
                    keys = row_keys(cand)
                if free is not None:  # rows of d^k q/dt^k: T^−k along the family (``row_time_derivatives``)
                    aT = row_time_derivatives(values, cand.kind, T, A_full @ V1.ravel())[0]
                    bounds = np.zeros((2, P + 1))
                    bounds[0, -1], bounds[1, -1] = 1.0, -1.0
                    A = np.vstack([np.hstack([A, aT[:, None]]), bounds])
                    rhs_A = np.concatenate([rhs_A, [free.max - T, T - free.min]])
                    if quick:
                        keys = np.concatenate([keys, [-1, -2]])
                due("programme")
                try:
                    if quick and kept is not None:  # the last programme's active rows and the rows added first
                        step = solve_qp_within(U, grad, E, rhs_E, A, rhs_A, _reduced_rows(cand, *kept[:2], A.shape[0]),
                                               programme=prog, keys=keys)
                    elif not quick and previous is not None and kept is None:
                        # over the last step's active rows and the new rows first: the same step, and the multipliers of
                        # dependent rows shared as the last step shared them (from every row, the programme's split changed
                        # from step to step and the working set with it: the Panda reach's coarse steps cycled 29 ↔ 31 rows)
                        step = solve_qp_within(U, grad, E, rhs_E, A, rhs_A, _reduced_rows(cand, *previous, A.shape[0]),
                                               programme=prog)
                    elif quick:  # first over the rows that the step without inequality rows breaks (solve_qp_within)
                        step = solve_qp_within(U, grad, E, rhs_E, A, rhs_A, np.zeros(A.shape[0], bool), programme=prog,
                                               keys=keys)
                    else:
                        step = solve_qp(U, grad, E, rhs_E, A, rhs_A, programme=prog, keys=keys)
                except NumericalError as exc:
                    if _log.isEnabledFor(logging.DEBUG):
                        _log.debug(f"qp step {steps}: {exc}")
                    if kept is not None:  # the programme with the rows added failed: the last one's step
                        step, cand, A, rhs_A, gA, keys = kept
                    else:
                        failed = True
                    break
                if rounds == EXPAND_ROUNDS:
                    break
                kept = step, cand, A, rhs_A, gA, keys
                beyond = _rows_beyond(step.d, P, free, T, pt, problem, limits, at_rows, lo_mask, hi_mask, quick)
                if beyond is None:
                    break
                lo_mask, hi_mask = beyond
            if failed:
                break
            previous = step, cand
            row_violation = float(np.max(gA, initial=0.0))
            decrement, J_from = step.decrease, pt.J
            if _runs_away(step, decrement, pt.J):  # no plan near this T: the multipliers grow with each step's matrix
                status = Status.MAX_ITER if math.isfinite(decrement) and np.all(np.isfinite(step.d)) else Status.NOT_FINITE
                if _log.isEnabledFor(logging.DEBUG):
                    _log.debug(f"qp step {steps}: the programme runs away (decrease {decrement:.2e}, J {pt.J:.6g})")
                break
            if _log.isEnabledFor(logging.DEBUG):
                _log.debug(f"qp step {steps} T {T:.9f} J {pt.J:.12g} dec {decrement:.2e} viol {violation:.1e} "
                      f"rows {row_violation:.1e} cand {cand.size} active {active.size}"
                      + (f" F {pt.F:.3e} F_I {grad[-1]:.3e} h {h:.3e} dT {step.d[-1]:.2e}" if free is not None else ""))
            t_done = free is None or abs(pt.F) <= slope_rtol * (abs(pt.J) / T + weight) or (
                (T >= free.max and pt.F < 0) or (T <= free.min and pt.F > 0))
            if abs(decrement) <= tol * max(abs(pt.J), 1.0) and violation <= eq_tol and row_violation <= ROW_ACCEPT and t_done:
                if lm > 0.0:  # a shifted matrix understates the decrease: test again with the Newton matrix itself
                    lm, decrement, U_last = 0.0, math.inf, None
                    continue
                check = check_limits(system, limits, problem.mesh, C)
                if check.feasible:
                    status = Status.CONVERGED
                    break
                if accuracy is None:
                    break
                check = accuracy = None  # stopped early with a limit broken between the held rows: on to the full test
                tol, eq_tol, slope_rtol = full
            if steps == max_steps:
                break
            steps += 1
            dx = step.d[:P]
            dT = float(step.d[P]) if free is not None else 0.0
            nu = step.nu - rho_aug * cg
            mu = step.mu[:cand.size]
            held = mu > MU_RTOL * float(np.max(mu, initial=0.0))  # not the rows whose μ is rounding
            new_active = cand.keep(held)
            goal_parts = list(np.split(nu, np.cumsum([v.size for v in lam[:npts]])[:-1])) if npts else []
            lam_new = goal_parts + [mu[held]]  # (no goal rows, e.g. joint vias pinned on nodes: the working set's alone)

            # the point after the last step ``stop`` will allow (the real-time path): no derivatives of ℒ there
            last = quick and stop is not None and steps == max_steps
            valued = not last or test is not None  # the merit test reads the trial points' J

            def trial_at(alpha: float):
                T_a = T + alpha * dT
                return T_a, at(T_a, rescale(problem.coefficients(pt.x + alpha * dx), T, T_a), lam_new, new_active,
                               not last, valued)

            def violation_at(alpha: float) -> float:
                T_a = T + alpha * dT
                return goal_rows_at(T_a, rescale(problem.coefficients(pt.x + alpha * dx), T, T_a))

            due("trial")
            accept = None
            if test is not None:
                accept = test.prepare(pt, T, grad @ step.d, np.concatenate([nu, mu]), everything)
            at_trial = functools.partial(at, derivatives=not last, value=valued)
            corrected = None if not CORRECTION else _corrected_step(step, P, free, T, pt, problem, at_trial, goal_rows_at, lam_new, new_active, r,
                                                                    violation, floor, accept, U, grad, E, A, rhs_A, cand,
                                                                    limits, rho_aug, cg, lam[:npts], at_full=trial_at, quick=quick,
                                                                    programme=prog, keys=keys, rows_only=not valued,
                                                                    goal_values_at=goal_values_at)
            if corrected is not None:
                trial, T_try, alpha, v_try, lam_new, new_active, dx, dT = corrected
            else:
                trial, T_try, alpha, v_try = damped_trial(trial_at, r, violation, floor, accept, violation_at)
            if trial is None:
                break
            if test is not None:  # steps cut short: the model is too flat somewhere; full steps: trust it again
                lm = min(max(10.0 * lm, LM_START), LM_MAX) if alpha < 0.25 else (0.0 if lm <= LM_START else 0.1 * lm) if alpha == 1.0 else lm
            if _log.isEnabledFor(logging.DEBUG):
                _log.debug(f"  alpha {alpha} pi {test.pi if test is not None else 0.0:.2e} lm {lm:.1e} "
                           f"|dx| {np.max(np.abs(dx)):.2e} dT {dT:.2e} v_try {v_try:.1e} |E dx + c| "
                      f"{np.max(np.abs(pt.D[:r] @ dx + cg), initial=0.0):.1e}")
            pt, T, lam, active = trial, T_try, lam_new, new_active
            done += 1
    except OutOfTime:
        if not done:  # no step completed: the caller keeps its plan
            raise
        steps, U_last, check = done, None, None  # a later step stopped: the point after the last completed one
    derive = functools.partial(at, T, pt.C, lam, active) if pt.g is None else None
    return QPReplan(point=pt, T=T, lam=lam, active=active, status=status, steps=steps, evals=evals,
                    decrement=decrement, factor=U_last, check=check, derive=derive, J_from=J_from, hessians=pair_last)


def _difference_column(pt, T: float, at, lam: list, active: ActiveRows) -> tuple[np.ndarray, float]:
    """(b, h) of the ``TimeColumn`` at ``pt`` by a forward difference along the rescaled family: ℒ's gradient and F at
    T + δ, δ = 1e-6·T (``at``: ``evaluate_point`` at (T, C) with ``lam`` and ``active``). One more evaluation; used
    where the Newton matrix, hence the sample Hessians, were not made at pt (the rows' T columns stay exact: the
    programme's T row must hold the same rows' slopes as F, or its optimum is off F = 0 by their difference).
    """
    delta = 1e-6 * T
    C = pt.C
    ph = at(T + delta, rescale(C, T, T + delta), lam, active)
    scale = pt.problem.layout.pack(rescale(np.ones_like(C), T, T + delta))
    return (scale * ph.g - pt.g) / delta, (ph.F - pt.F) / delta


def row_keys(rows: ActiveRows) -> np.ndarray:
    """One non-negative integer per row (a,), the same for the same (kind, element, row, joint, side) in any set:
    a keyed ``Programme``'s row keys (the T bounds' rows take −1 and −2).
    """
    key = rows.kind.astype(np.int64) << 16 | rows.elem
    key = (key << 8 | rows.row) << 8 | rows.joint
    return key << 1 | (rows.side > 0)


def _reduced_rows(cand: ActiveRows, last: QPStep, last_cand: ActiveRows, k: int) -> np.ndarray:
    """The rows (k,) bool of the programme over ``cand`` (then k − cand.size rows of T's bounds, always kept) to
    solve first after the programme over ``last_cand`` (a subset of ``cand``) gave the step ``last``: its rows
    with μ > 0 and the rows ``cand`` added (``solve_qp_within`` then adds any other row the step breaks).
    """
    def keys(a: ActiveRows) -> np.ndarray:  # one integer per row (kind, element, row, joint, side)
        return np.ravel_multi_index((a.kind, a.elem, a.row, a.joint, (a.side > 0).astype(int)), dims)

    dims = tuple(int(max(getattr(cand, f).max(initial=0), getattr(last_cand, f).max(initial=0))) + 1
                 for f in ("kind", "elem", "row", "joint")) + (2,)
    old = keys(last_cand)
    dropped = old[last.mu[:last_cand.size] <= 0.0]
    out = np.ones(k, bool)
    out[:cand.size] = ~np.isin(keys(cand), dropped)
    return out


def _rows_beyond(d: np.ndarray, P: int, free, T: float, pt, problem, limits, rows_at, lo_mask, hi_mask,
                 quick: bool = False):
    """The candidate masks (lo, hi) grown by the kinematic rows outside them that the full step ``d`` would break
    (g > 0 at the trial point), or None when it breaks none. ``quick``: the rows at the trial point's T from those at
    T (``row_values``' ratio) instead of the mesh's rows at that T (``rows_at``): the same numbers to rounding.
    """
    dT = float(d[P]) if free is not None else 0.0
    T1 = T + dT
    if quick:
        at1 = row_values(limits, pt.rows, problem.coefficients(pt.x + d[:P]), T / T1)
    else:
        C1 = rescale(problem.coefficients(pt.x + d[:P]), T, T1)
        rows1 = pt.rows if dT == 0.0 else rows_at(T1)
        at1 = row_values(limits, rows1, C1)
    lo = tuple((g > 0.0) & ~m for g, m in zip(at1.g_lo, lo_mask))
    hi = tuple((g > 0.0) & ~m for g, m in zip(at1.g_hi, hi_mask))
    if not any(x.any() for x in lo + hi):
        return None
    return tuple(a | b for a, b in zip(lo, lo_mask)), tuple(a | b for a, b in zip(hi, hi_mask))


def _corrected_step(step, P: int, free, T: float, pt, problem, at, goal_rows_at, lam_new, new_active, r: int,
                    violation: float, floor: float, accept, U, grad, E, A, rhs_A, cand, limits, rho_aug: float,
                    cg, lam_goal, at_full, quick: bool = False, programme: Programme | None = None,
                    keys: np.ndarray | None = None, rows_only: bool = False, goal_values_at: Callable | None = None):
    """(point, T, 1, its goal rows' violation, multipliers, working set, dx, dT) of the full ``step`` when the goal rows'
    violation floor and the merit test (``accept``) take it, else of its second-order correction when they take that,
    else None (the step is then damped, ``damped_trial``).

    The correction (Nocedal & Wright, Numerical Optimization, §18.3, the Maratos effect's remedy) re-solves the step's
    programme (the same factor ``U``, gradient and rows) with the goal rows' and candidate limit rows' values at the
    trial point: E d' = E d − c(x + d), A d' ≤ A d − g(x + d). Where the rows curve (the flange's pose along a long
    step) it brings the step back onto them at the cost of one more programme and one more evaluation. ``quick``
    (the real-time path): that programme is solved over the step's active rows first (``solve_qp_within``).
    ``programme``: the step's ``Programme(U, grad, E)`` (its elimination and transformed rows A are reused), ``keys``
    its row keys of A when it is keyed (``row_keys``). ``rows_only``: ``at`` evaluates the goal rows alone (no
    dynamics: ``evaluate_point(..., value=False)``), so the corrected point is evaluated once and its violation read
    from it (``goal_rows_at``'s numbers). Else the full step's goal rows are evaluated first, alone (``goal_values_at``:
    (T, C) -> (limit rows, C, c), ``replan_point.goal_values``' numbers): a step whose rows break the floor is corrected
    without the dynamics at its end (the UR5's moving target: 5 of its 32 evaluations).
    """
    dx, dT = step.d[:P], (float(step.d[P]) if free is not None else 0.0)
    T1 = T + dT
    try:
        if rows_only:
            _, trial = at_full(1.0)
            rows1, C1, c1 = trial.rows, trial.C, trial.c[:r]
        else:  # the goal rows first: a step they reject needs no dynamics at its end, only those rows for its correction
            rows1, C1, c1 = goal_values_at(T1, rescale(problem.coefficients(pt.x + dx), T, T1))
        v1 = float(np.max(np.abs(c1), initial=0.0))
        if v1 <= max(violation, floor) and not rows_only:
            _, trial = at_full(1.0)
    except NumericalError:
        return None
    if v1 <= max(violation, floor) and (accept is None or accept(1.0, T1, trial)):
        return trial, T1, 1.0, v1, lam_new, new_active, dx, dT
    # the second-order correction: the same programme with the rows' values at the trial point
    _, A1_full = cand.jacobian(rows1, limits, problem.layout.free)
    g1 = A1_full @ C1.ravel() + cand.offsets(limits)
    rhs_E = E @ step.d - c1
    k = cand.size
    rhs_A2 = rhs_A.copy()
    rhs_A2[:k] = A[:k] @ step.d - g1
    try:
        if quick:  # the step's active rows (and T's bounds) first: the same step, as in ``qp_steps``
            held_rows = step.mu > 0.0
            held_rows[k:] = True
            step2 = solve_qp_within(U, grad, E, rhs_E, A, rhs_A2, held_rows, programme=programme, keys=keys)
        else:
            step2 = solve_qp(U, grad, E, rhs_E, A, rhs_A2, programme=programme)
    except NumericalError:
        return None
    dx2, dT2 = step2.d[:P], (float(step2.d[P]) if free is not None else 0.0)
    T2 = T + dT2
    # the goal rows' multipliers of the programme without ρEᵀE: ν + ρe for rows E d = e (the step's own: e = −c); the
    # correction's e is E d − c(x + d), and ν − ρc there would be off by ρc(x + d) (the lbr7 catch: λ 20 times the
    # optimum's after a corrected step in T, whose next Newton matrix then lost its negative part and held T)
    nu = step2.nu + rho_aug * rhs_E
    mu = step2.mu[:k]
    held = mu > MU_RTOL * float(np.max(mu, initial=0.0))
    active2 = cand.keep(held)
    parts = list(np.split(nu, np.cumsum([v.size for v in lam_goal])[:-1])) if lam_goal else []
    lam2 = parts + [mu[held]]
    C2 = rescale(problem.coefficients(pt.x + dx2), T, T2)
    trial2 = None
    try:
        if rows_only:  # the point's evaluation is its goal rows alone: their violation read from it
            trial2 = at(T2, C2, lam2, active2)
            v2 = float(np.max(np.abs(trial2.c[:r]), initial=0.0))
        else:
            v2 = goal_rows_at(T2, C2)
    except NumericalError:
        return None
    if _log.isEnabledFor(logging.DEBUG):
        _log.debug(f"  correction: violation {v1:.1e} at the step, {v2:.1e} corrected")
    if not v2 <= max(violation, floor):
        return None
    try:
        trial2 = at(T2, C2, lam2, active2) if trial2 is None else trial2
    except NumericalError:
        return None
    if accept is not None and not accept(1.0, T2, trial2):
        return None
    return trial2, T2, 1.0, v2, lam2, active2, dx2, dT2


class MeritTest:
    """Armijo's test on the ℓ1 merit function φ = I + weight·T + π (Σ|c| + Σ max(0, g)) over the goal rows c
    and every kinematic Bernstein row g (Nocedal & Wright, Numerical Optimization, §18.3): a step of the
    programme is a descent direction of φ once π exceeds its multipliers, so backtracking on φ keeps steps
    far from the optimum from running off (the steps' own test only watches the goal rows). π ≥ 1.1 × the step's
    largest multiplier, and halfway between its last value and that (Powell's update): the multipliers of steps far
    from feasibility can be 500 times those near the optimum, where a π kept that large makes the second-order
    rise of the curved goal rows outweigh the cost's decrease and cuts every full step (the Maratos effect).
    """

    ARMIJO = 1e-4

    def __init__(self, system, limits, r_goal: int, weight: float) -> None:
        self.system, self.limits, self.r, self.weight = system, limits, r_goal, weight
        self.pi = 0.0

    def infeasibility(self, pt, everything=None) -> float:
        """Σ|c| over the goal rows + Σ max(0, g) over every kinematic row at the point (``everything``: its
        ``row_values`` when known).
        """
        if everything is None:
            everything = row_values(self.limits, pt.rows, pt.C)
        rows = sum(float(np.sum(np.maximum(g, 0.0))) for g in everything.g_lo + everything.g_hi)
        return float(np.sum(np.abs(pt.c[:self.r]))) + rows

    def prepare(self, pt, T: float, slope_I: float, multipliers: np.ndarray, everything):
        """The acceptance test of the step from ``pt`` (at T): ``slope_I`` the derivative of I + weight·T along it,
        ``multipliers`` its programme's, ``everything``: ``row_values`` at ``pt``.
        """
        needed = 1.1 * float(np.max(np.abs(multipliers), initial=0.0))
        self.pi = max(needed, 0.5 * (self.pi + needed))
        h0 = self.infeasibility(pt, everything)
        phi0 = pt.J + self.weight * T + self.pi * h0
        slope = slope_I - self.pi * h0
        if slope >= 0.0:  # not a descent direction of φ (a modified Hessian far out): the steps' own test only
            return None

        def accept(alpha: float, T_try: float, trial) -> bool:
            phi = trial.J + self.weight * T_try + self.pi * self.infeasibility(trial)
            return phi <= phi0 + self.ARMIJO * alpha * slope

        return accept


def _runs_away(step, decrement: float, J: float) -> bool:
    """Whether the step's programme left what floating point resolves: a non-finite step, multiplier or decrease, or a
    decrease beyond ``RUNAWAY``·max(|J|, 1). Steps at a T with no plan within the limits (the UR5's fast catch at its
    guess) make programmes whose rows are almost inconsistent; their multipliers enter the next Newton matrix (Σλ∇²c)
    and grow with it, ×1e4 a step, until the matrix overflows.
    """
    finite = math.isfinite(decrement) and all(np.all(np.isfinite(v)) for v in (step.d, step.nu, step.mu))
    return not finite or abs(decrement) > RUNAWAY * max(abs(J), 1.0)


def keeps_factor(decrement: float, J: float) -> bool:
    """Whether the next step may reuse the last step's Newton matrix: only when that step's programme predicted
    a decrease within ±``LAG_RTOL``·|J| (the point barely moved). A negative decrease (the goal or limit rows forced
    a step that raises the model, far from the optimum) is not a small step: the matrix of a point that far back,
    with another working set, leaves the programme's T row inconsistent (‖U⁻ᵀb‖² ≫ h, T frozen) and its x step
    too long.
    """
    return abs(decrement) <= LAG_RTOL * max(abs(J), 1.0)


def _fits(U: np.ndarray | None, P: int) -> bool:
    return U is not None and U.shape == (P, P)
