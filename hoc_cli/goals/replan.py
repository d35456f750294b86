"""Warm replanning: the plan after a small change of its goals, by Newton steps from the previous optimum.

A real-time user re-solves the same task when the target moves a little. ``replan`` starts from the
previous plan's coefficients, its T, the goal rows' multipliers λ, and the limits' multipliers μ (no
coarse-to-fine continuation, no initial guess, no inverse kinematics, no quadrature refinement: G stays
the previous plan's). The unknowns are x (the free Hermite coefficients, in the s = t/T domain), T when
it is free, and the multipliers.

Kinematic limits (the usual case; ``replan_qp``): each step is an SQP step whose quadratic programme has
the goal rows as linearised equalities and the Bernstein rows near their bound as inequalities, solved
exactly (``qp_step``), so the limits' working set follows the steps with no multiplier rounds.

Effort limits binding at the previous plan (``_penalty_steps``): the limits stay augmented-Lagrangian
terms Φ at fixed μ in ℒ = I + Φ + λ·c + weight·T, and each step is one Newton step on the KKT system of
x, T and λ together:

    [ W    b    Dᵀ ] [dx]     [∇ₓℒ]
    [ bᵀ   h    c_Tᵀ] [dT] = − [ F ]        F = ∂ℒ/∂T,  c the goal rows, D = ∂c/∂x
    [ D    c_T  0  ] [dλ]     [ c ]

W is the block-banded Hessian of I + Φ on the cost's own quadrature (exact, so the steps converge
quadratically) plus Σλ∇²c (finite differences) plus ρDᵀD (ρ = 1e3·|J|: positive definite where W alone
is not, without changing the step); b = ∂∇ₓℒ/∂T, h = ∂²ℒ/∂T² and c_T = ∂c/∂T come from a forward
difference (δ = 1e-6·T) of the exact gradient, F and c at T + δ (the coefficients rescaled). The system is
solved by one banded Cholesky factorisation of W and the (1 + r)-square Schur complement on (dT, dλ). A
step is halved while it raises max|c| above max(max|c|, 1e-3) (down to 1/32); T is clipped to its range.
It stops when the decrement ½∇ₓℒᵀW⁻¹∇ₓℒ ≤ ``tol``·|J|, every goal row is met to 1e-9 (m, rad, m/s),
|F| ≤ 1e-7·(|J|/T + weight) (or T sits at a bound it is pushed against) and the plan is within its
limits (``check_limits``); at an inner optimum that fails the last test the limits' multipliers are
updated (μ ← max(0, μ + ρg)) and a pair that broke its limit joins the working set.

After ``max_steps`` steps the full solver finishes (``plan_goals``, and the free-T search with a free T),
from the previous plan when the steps wandered off. Measured in docs/goals.md. Pure maths: no I/O.
"""
from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass

import numpy as np

from hoc_cli.constraints.augmented_lagrangian import EnforceResult
from hoc_cli.constraints.bounds import KINDS, KINEMATIC
from hoc_cli.constraints.check import check_limits
from hoc_cli.constraints.penalty import LimitRows
from hoc_cli.errors import NumericalError
from hoc_cli.free_time import TimePoint, minimize_time, plan_time_derivative, rescale
from hoc_cli.goals.active_limits import ActiveRows, all_rows, from_multipliers, penalty_value
from hoc_cli.goals.mesh import mesh_fractions
from hoc_cli.goals.plan import EQ_ACCEPT, GoalProblem, GoalResult, Goals, plan_goals
from hoc_cli.goals.replan_point import VIOLATION_FLOOR, damped_trial, evaluate_point, solve_many
from hoc_cli.goals.replan_qp import QPReplan, qp_steps
from hoc_cli.goals.terms import GoalTerms
from hoc_cli.goals.time_solver import goal_solver
from hoc_cli.optimize import OptimizeResult, Status
from hoc_cli.optimize.blas import one_thread

_log = logging.getLogger(__name__)  # solver traces at DEBUG level (docs/design.md)
DECREMENT_TOL = 1e-12  # Newton decrement ½ gᵀH⁻¹g relative to |J|
RHO_AUG = 1e3  # ρ of the KKT matrix's W + ρDᵀD per unit |J| (measured on the lbr7 catch: 1e1 leaves W + ρDᵀD
# indefinite, 1e6 too ill-conditioned for the banded Cholesky factorisation)
SLOPE_RTOL = 1e-7  # |F'| relative to |J|/T + weight (as ``hoc_cli.free_time.minimize_time``)
NEWTON_SHIFT = 0.0  # no regularisation: the augmented matrix is positive definite and the last joint's
# acceleration curvature (1e-6 of the largest entry on the lbr7) must survive
QP_MODE = True  # kinematic limits as QP rows (False: penalty terms at fixed multipliers, as with effort limits)
RELEASE_RTOL = 1e-6  # the working set's multipliers are tested once the decrement is below this·|J| ...
RELEASE_VIOLATION = 1e-6  # ... and the rows are met to this


@dataclass(frozen=True)
class TimeRange:
    """A free T in [min, max] [s] with the price of time ``weight`` (cost units per second)."""

    min: float
    max: float
    weight: float = 0.0


@dataclass(eq=False)
class ReplanResult:
    """A warm replan: ``plan`` (a ``GoalResult``), T [s], dJ*/dT there, ``curvature`` d²J*/dT² (the
    next replan's), Newton ``steps``, ``fallback`` (the full solver had to finish), ``wall_time_s``.
    """

    plan: GoalResult
    T: float
    dJ_dT: float
    curvature: float | None
    steps: int
    fallback: bool
    wall_time_s: float

    @property
    def converged(self) -> bool:
        return self.plan.converged


def curvature_of(history) -> float | None:
    """d²J*/dT² at the optimum of a free-T search (``FreeTimeResult``): the secant of dJ*/dT between the
    optimum and the nearest other solve (None when there is none or the secant is not positive).
    """
    best = history.point
    others = [p for p in history.history if p.T != best.T]
    if not others:
        return None
    p = min(others, key=lambda p: abs(p.T - best.T))
    d2 = (best.dJ_dT - p.dJ_dT) / (best.T - p.T)
    return d2 if d2 > 0 else None


def _start(previous) -> tuple[GoalResult, float | None]:
    """(the plan, its curvature) of a ``ReplanResult``, a ``FreeTimeResult`` or a ``GoalResult``."""
    if isinstance(previous, ReplanResult):
        return previous.plan, previous.curvature
    if hasattr(previous, "history") and hasattr(previous, "point"):
        return previous.result, curvature_of(previous)
    return previous, None


@one_thread()  # one BLAS thread while solving (hoc_cli/optimize/blas.py)
def replan(system, previous, goals: Goals, *, free: TimeRange | None = None, limits=None,
           curvature: float | None = None, tol: float = DECREMENT_TOL, max_steps: int = 40,
           fallback: bool = True, violation_floor: float = VIOLATION_FLOOR, merit: bool = False,
           accuracy: float | None = None, cache: dict | None = None, hessians: tuple | None = None) -> ReplanResult:
    """Re-solve ``goals`` warm from ``previous`` (see the module docstring).

    Parameters
    ----------
    system : the dynamics (``RobotSystem``) of the previous plan.
    previous : ``ReplanResult`` | ``FreeTimeResult`` | ``GoalResult``
        The plan to start from: its mesh (order, N; T is the starting T), quadrature G, cost, x0,
        multipliers and (limits) working set.
    goals : ``Goals``
        The new goals (e.g. the target moved); the same kind of rows as the previous plan's.
    free : the range of a free T, or None to keep T fixed at the previous plan's.
    limits : ``JointLimits`` enforced, or None.
    curvature : d²J*/dT² [cost units/s²] to report as the result's ``curvature`` instead of the previous plan's
        (the steps take ∂²ℒ/∂T² from a finite difference).
    tol : the Newton decrement's tolerance relative to |J|.
    max_steps : Newton steps before the full solver takes over (``fallback``; else returned as is).
    violation_floor : a step is halved while it raises the goal rows' violation above max(violation, this)
        (m, rad, m/s); far from the optimum (a cold start from the initial trajectory) a larger floor lets
        the steps follow curved rows with fewer halvings.
    merit : with kinematic limits as the steps' rows, also halve a step while it does not decrease the ℓ1
        merit function (``replan_qp.MeritTest``): for steps from far away (the initial trajectory).
    accuracy : with kinematic limits as the steps' rows, the looser stopping test of a coarse stage
        (``replan_qp.qp_steps``); None: the full one.
    cache : with kinematic limits as the steps' rows, the points' problems by T (``replan_point.point_problem``'s
        ``cache``) of an earlier replan on the same mesh, quadrature, cost, x0 and goals, whose points (their
        dynamics and goal rows, Hessian samples) this one reuses where it evaluates the same x and T
        (``qp_steps``); None: a new one.
    hessians : with kinematic limits as the steps' rows, the cost's sample Hessians of the last Newton matrix of the
        replan that ended at ``previous`` (its plan's ``newton_hessians``), for the first Newton matrix (``qp_steps``).

    Returns
    -------
    ReplanResult
    """
    start = time.perf_counter()
    plan0, d2 = _start(previous)
    d2 = curvature if curvature is not None else d2
    mesh0, problem0 = plan0.mesh, plan0.problem
    G, cost = plan0.G, problem0.cost
    q0, dq0 = problem0.boundary[:2]
    weight = free.weight if free is not None else 0.0
    limited = limits is not None and limits.any
    lam, rho = (plan0.terms.lam, plan0.terms.rho) if plan0.terms is not None else (None, 0.0)
    points = GoalProblem(system, mesh0, q0, dq0, goals, cost=cost, G=G).points
    if lam is None or len(lam) != len(points):
        lam = [np.zeros(p.residual.size) for p in points]
    lam = [np.array(v, float) for v in lam]
    state = None
    if limited:
        lr = plan0.limits
        working = np.zeros((len(KINDS), limits.n), bool) if lr is None else lr.working.copy()
        rows0 = LimitRows.build(mesh0, problem0.layout.free, limits.n)
        zeros = tuple(np.zeros(rows0.shape(k, limits.n)) for k in range(len(KINDS)))
        if lr is not None and lr.penalty is not None:
            state = [working, lr.penalty.mu_lo, lr.penalty.mu_hi, lr.rho or 1.0]
        else:
            state = [working, zeros, zeros, 1.0]
    active = None  # the kinematic limits' working set when the steps solve QPs (None: penalty terms at fixed μ)
    if limited and QP_MODE:
        lr = plan0.limits
        pen = lr.penalty if lr is not None else None
        active = from_multipliers(pen) if pen is not None else ActiveRows.empty()
        if active is not None:
            lam.append(active.gather(pen.mu_lo, pen.mu_hi) if pen is not None else np.zeros(0))
    npts = len(points)
    rho_aug = RHO_AUG * max(abs(plan0.J), 1.0)
    if active is not None:
        out = qp_steps(system, plan0, goals, lam, active, free=free, limits=limits, tol=tol, max_steps=max_steps,
                       rho_aug=rho_aug, floor=violation_floor, merit=merit, accuracy=accuracy, cache=cache,
                       hessians=hessians)
    else:
        out = _penalty_steps(system, plan0, goals, lam, state, free=free, limits=limits if limited else None,
                             tol=tol, max_steps=max_steps, rho_aug=rho_aug, start=start, floor=violation_floor)
    pt, T, lam, active, status, steps, evals, decrement = (out.point, out.T, out.lam, out.active, out.status,
                                                           out.steps, out.evals, out.decrement)
    rows = sum(v.size for v in lam[:npts])  # the goal rows (pt.c goes on with the limits' working set)
    violation = float(np.max(np.abs(pt.c[:rows]), initial=0.0))
    problem, x, C, J = pt.problem, pt.x, pt.C, pt.J
    mesh = problem.mesh
    slope = pt.F - weight
    opt = OptimizeResult(x=x, fun=J, grad=_reduced_gradient(pt, lam), status=status, iterations=steps,
                         n_evals=evals,
                         n_precond=steps, decrement=decrement,
                         message="warm replan: " + ("converged" if status is Status.CONVERGED
                                                    else f"{steps} Newton steps"))
    enforced = None
    if limited:
        check = out.check if out.check is not None else check_limits(system, limits, mesh, C)
        working, rho_l, penalty = (state[0], state[3], pt.pv) if active is None else _row_outcome(
            system, limits, pt.rows, C, active, lam[npts], plan0.limits)
        enforced = EnforceResult(status="converged" if status is Status.CONVERGED else "not_converged",
                                 message=opt.message, inner=opt, x=x, J=J, outer_iterations=steps, rho=rho_l,
                                 check=check, working=working, rows=pt.rows, penalty=penalty)
    used = GoalTerms(mesh, problem.points, lam[:npts], rho if rho > 0 else 10.0 * max(abs(J), 1e-6))
    plan = GoalResult(mesh=mesh, coeffs=C, J=J, optimizer=opt, G=G, quadrature_change=math.nan,
                      wall_time_s=time.perf_counter() - start, problem=problem, limits=enforced, terms=used,
                      violation=violation, outer_iterations=steps, goals=goals,
                      newton_factor=getattr(out, "factor", None), newton_hessians=getattr(out, "hessians", None))
    if status is not Status.CONVERGED and fallback:  # from the previous plan: the steps may have wandered off
        return _finish(system, plan0 if violation > 1e-6 else plan, goals, free, limits, d2, start)
    return ReplanResult(plan=plan, T=T, dJ_dT=slope, curvature=d2, steps=steps, fallback=False,
                        wall_time_s=time.perf_counter() - start)


def _reduced_gradient(pt, lam: list) -> np.ndarray:
    """The stationarity residual (P,) reported as the plan's gradient: the gradient of the cost (with the limits'
    penalty terms, if any) minus its least-squares fit by the rows' gradients, g − Dᵀw with w = argmin ‖g − Dᵀw‖
    over the goal rows and the working set's rows D; zero at a constrained optimum.
    """
    D = pt.D
    if not D.size:
        return pt.g
    g = pt.g - D.T @ np.concatenate(lam)
    w = np.linalg.lstsq(D.T, g, rcond=None)[0]
    return g - D.T @ w


def _penalty_steps(system, plan0, goals: Goals, lam: list, state, *, free, limits, tol: float, max_steps: int,
                   rho_aug: float, start: float, floor: float = VIOLATION_FLOOR) -> QPReplan:
    """The Newton steps with the limits as augmented-Lagrangian terms at fixed multipliers (``state``:
    [working, μ_lo, μ_hi, ρ], updated in place) and their multiplier rounds at inner optima: the steps
    of plans whose effort limits bind (module docstring).
    """
    mesh0, problem0 = plan0.mesh, plan0.problem
    order, N, G, cost = mesh0.order, mesh0.N, plan0.G, problem0.cost
    fractions = mesh_fractions(mesh0)  # a non-uniform mesh scales with T
    q0, dq0 = problem0.boundary[:2]
    T = mesh0.T
    C = np.array(plan0.coeffs)
    limited = limits is not None
    weight = free.weight if free is not None else 0.0
    split = np.cumsum([v.size for v in lam])[:-1]
    status = Status.MAX_ITER
    steps = evals = 0
    violation = decrement = math.inf

    def at(T_, C_, lam_):
        return evaluate_point(system, order, N, T_, C_, q0, dq0, goals, cost, G, lam_, limits if limited else None,
                              state, weight, free is not None, cache, fractions=fractions)

    cache: dict = {}
    pt, fresh, updated = at(T, C, lam), False, True  # the previous plan's multipliers are its optimum's
    for _ in range(3 * max_steps + 1):  # the steps, the final test, the limits' multiplier updates
        problem, x, C = pt.problem, pt.x, pt.C
        evals += 1
        violation = float(np.max(np.abs(pt.c), initial=0.0))
        extra = pt.lt.newton_blocks(C) if pt.lt is not None else None
        blocks = None
        if problem.points:
            # W + ρDᵀD is positive definite where W alone is not (q at T is held by the rows only); the
            # step is the same (the multiplier step absorbs −ρc)
            blocks = GoalTerms(problem.mesh, problem.points, lam, rho_aug).newton_blocks(C, indefinite=True, res=pt.res)
            extra = blocks if extra is None else extra + blocks
        try:
            W = problem.newton(pt.ev, extra=extra)
        except NumericalError:  # away from the optimum: the rows' curvature without its negative part
            if blocks is None:
                break
            try:
                extra = extra - blocks + GoalTerms(problem.mesh, problem.points, lam, rho_aug).newton_blocks(C, res=pt.res)
                W = problem.newton(pt.ev, extra=extra)
            except NumericalError:
                break
        A = np.vstack([pt.g[None], pt.D])  # W⁻¹ on g and the rows together
        Z = solve_many(W, A.T)
        w, Y = Z[:, 0], Z[:, 1:]
        decrement = 0.5 * float(pt.g @ w)
        at_bound = free is not None and ((T >= free.max and pt.F < 0) or (T <= free.min and pt.F > 0))
        t_done = free is None or at_bound or abs(pt.F) <= SLOPE_RTOL * (abs(pt.J) / T + weight)
        x_done = decrement <= tol * max(abs(pt.J), 1.0)
        if _log.isEnabledFor(logging.DEBUG):
            _log.debug(f"step {steps} T {T:.9f} J {pt.J:.12g} dec {decrement:.2e} viol {violation:.1e} "
                  f"F' {pt.F:.2e} t {1e3 * (time.perf_counter() - start):.1f} ms")
        if x_done and violation <= EQ_ACCEPT and t_done and not fresh:
            newly = None
            if limited:
                check = check_limits(system, limits, problem.mesh, C)
                newly = ((check.hi_excess > 0) | (check.lo_excess > 0)).any(axis=1)
            if newly is None or not newly.any():
                status = Status.CONVERGED
                break
            state[0] = state[0] | newly
        if x_done and not updated and limited:  # the limits' multiplier update at an inner optimum (and the rows
            if pt.pv is not None:  # that joined), then a step at the new multipliers before the next test
                state[1], state[2] = pt.pv.mu_lo, pt.pv.mu_hi
            pt, fresh, updated = at(T, C, lam), True, True
            continue
        fresh = updated = False
        if steps == max_steps:
            break
        steps += 1
        DY = pt.D @ Y
        Dw = pt.D @ w
        r = pt.c.size
        dT = 0.0
        if free is not None and not at_bound:
            # the T row: b = ∂∇ℒ/∂T (P,), h = ∂²ℒ/∂T², c_T = ∂c/∂T at fixed s-domain coefficients, by a
            # forward difference of the exact gradient, F and c at T + δ
            delta = 1e-6 * T
            ph = at(T + delta, rescale(C, T, T + delta), lam)
            evals += 1
            scale = problem.layout.pack(rescale(np.ones_like(C), T, T + delta))
            b = (scale * ph.g - pt.g) / delta
            h = (ph.F - pt.F) / delta
            cT = (ph.c - pt.c) / delta
            b = b + rho_aug * pt.D.T @ cT
            h = h + rho_aug * float(cT @ cT)
            u = W.solve(b)
            Du = pt.D @ u
            K = np.zeros((r + 1, r + 1))
            K[0, 0] = h - b @ u
            K[0, 1:] = K[1:, 0] = cT - Du
            K[1:, 1:] = -DY
            rhs = np.concatenate([[-pt.F + b @ w], -pt.c + Dw])
            sol = np.linalg.lstsq(K, rhs, rcond=1e-12)[0]
            if K[0, 0] > 0 and free.min <= T + sol[0] <= free.max:
                dT, nu = sol[0], sol[1:]
            else:  # clipped: T moves to the bound (or by the curvature's sign) and the rows follow
                dT = float(np.clip(T + (sol[0] if K[0, 0] > 0 else -math.copysign(1e-3 * T, pt.F)),
                                   free.min, free.max) - T)
                nu = np.linalg.lstsq(-DY, -pt.c + Dw - (cT - Du) * dT, rcond=1e-12)[0] if r else np.zeros(0)
            dx = -w - u * dT - Y @ nu
        else:
            nu = np.linalg.lstsq(DY, pt.c - Dw, rcond=1e-12)[0] if r else np.zeros(0)  # rows may be dependent
            dx = -w - Y @ nu
        dlam = nu - rho_aug * pt.c

        def trial_at(alpha: float):
            T_a = T + alpha * dT
            lam_a = [lv + alpha * d for lv, d in zip(lam, np.split(dlam, split))]
            return T_a, at(T_a, rescale(problem.coefficients(x + alpha * dx), T, T_a), lam_a)

        trial, T_try, alpha, v_try = damped_trial(trial_at, r, violation, floor)
        if trial is None:
            break
        lam_try = [lv + alpha * d for lv, d in zip(lam, np.split(dlam, split))]
        if _log.isEnabledFor(logging.DEBUG):
            _log.debug(f"  dT {dT:.3e} alpha {alpha} |dx| {np.max(np.abs(dx)):.1e} v_try {v_try:.1e}")
        pt, T, lam = trial, T_try, lam_try
    return QPReplan(point=pt, T=T, lam=lam, active=None, status=status, steps=steps, evals=evals,
                    decrement=decrement)


def _row_outcome(system, limits, rows: LimitRows, C: np.ndarray, active: ActiveRows, mu: np.ndarray, previous):
    """(working pairs, ρ, ``PenaltyValue``) of a replan that held the limit rows as equalities."""
    pen = penalty_value(active, mu, all_rows(system, limits, rows, C), rows, limits.n)
    working = np.zeros((len(KINDS), limits.n), bool) if previous is None else previous.working.copy()
    for k in range(KINEMATIC):
        working[k] |= ((pen.mu_lo[k] > 0) | (pen.mu_hi[k] > 0)).reshape(-1, limits.n).any(axis=0)
    return working, (previous.rho if previous is not None and previous.rho else 1.0), pen


def _finish(system, plan: GoalResult, goals: Goals, free: TimeRange | None, limits, d2, start: float) -> ReplanResult:
    """The full solver from where the Newton steps got (``plan_goals``; the free-T search with a free T)."""
    mesh = plan.mesh
    q0, dq0 = plan.problem.boundary[:2]
    options = {"cost": plan.problem.cost, "G": plan.G}
    terms = dataclasses.replace(plan.terms, rho=0.0)
    if free is None:
        result = plan_goals(system, mesh, q0, dq0, goals, limits=limits, C_init=plan.coeffs, terms=terms,
                            continuation=False, **options)
        slope = plan_time_derivative(result, system, limits, goals=result.terms if result.problem.points else None)
        return ReplanResult(plan=result, T=mesh.T, dJ_dT=slope, curvature=d2, steps=plan.outer_iterations,
                            fallback=True, wall_time_s=time.perf_counter() - start)
    solver = goal_solver(system, mesh.order, mesh.N, q0, dq0, goals, limits=limits, fractions=mesh_fractions(mesh),
                         **options)
    seed = TimePoint(T=mesh.T, J=plan.J, dJ_dT=math.nan, result=plan)  # the warm start of the first solve

    def solve(T, nearest):
        return solver(T, nearest if nearest is not None else seed)

    ft = minimize_time(solve, free.min, free.max, guess=mesh.T, weight=free.weight)
    return ReplanResult(plan=ft.result, T=ft.T, dJ_dT=ft.dJ_dT, curvature=curvature_of(ft) or d2,
                        steps=plan.outer_iterations, fallback=True, wall_time_s=time.perf_counter() - start)
