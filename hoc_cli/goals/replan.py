"""Warm replanning: the plan after a small change of its goals, by Newton steps from the previous optimum.

A real-time user re-solves the same task when the target moves a little. ``replan`` starts from the
previous plan's coefficients, its T, the goal rows' multipliers λ, and the limits' working set,
multipliers μ and penalty (no coarse-to-fine continuation, no initial guess, no inverse kinematics,
no quadrature refinement: G stays the previous plan's). Each step, at the current T:

1. one Newton (SQP) step on the goal rows c = 0 with the Lagrangian ℒ = I + Φ_limits + λ·c: the KKT
   system W dx + Dᵀ dλ = −∇ℒ, D dx = −c (D = ∂c/∂x, W the block-banded Newton matrix of I + Φ plus
   Σλ∇²c and ρDᵀD, which makes W positive definite without changing dx), solved by the banded
   factorisation of W and the Schur complement D W⁻¹ Dᵀ on the r goal rows; the step is halved while
   it raises max|c| (down to 1/32);
2. when that step was converged (decrement ½ gᵀW⁻¹g ≤ ``tol``·|J|): the limits' multiplier update
   μ ← max(0, μ + ρg) and, with a free T, one Newton step on F'(T) = dJ*/dT + weight = 0:
   T ← T − F'/F'' with F'' the curvature d²J*/dT² of the previous search (a secant when none is
   known), clipped to the range; the coefficients are rescaled to the new T.

It stops when a step is converged, every goal row is met to 1e-9 (m, rad, m/s), |F'| ≤ 1e-7·(|J|/T +
weight) (or T sits at a bound it is pushed against) and the plan is within its limits
(``check_limits``; a limit that became active joins the working set). After ``max_steps`` steps
the full solver finishes (``plan_goals``, and the free-T search with a free T), from the previous
plan when the steps wandered off. Measured on the lbr7 catch (docs/goals.md): a step costs about
one cost-and-gradient evaluation plus one Newton matrix (15-40 ms at N = 8 on a loaded 2-core machine); a move of 1 mm takes
~25 steps with the free T (the T steps each need a converged x), a fixed-T replan ~11 (docs/goals.md).
Pure maths: no I/O.
"""
from __future__ import annotations

import dataclasses
import math
import os
import time
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from hoc_cli.constraints.augmented_lagrangian import MARGIN, EnforceResult, PenalizedProblem
from hoc_cli.constraints.check import check_limits
from hoc_cli.constraints.penalty import LimitRows, LimitTerms
from hoc_cli.elements import HermiteMesh
from hoc_cli.errors import NumericalError
from hoc_cli.free_time import (
    cost_time_derivative,
    fixed_coefficient_correction,
    limits_time_derivative,
    rescale,
)
from hoc_cli.goals.plan import EQ_ACCEPT, GoalProblem, GoalResult, Goals, plan_goals
from hoc_cli.goals.terms import GoalTerms
from hoc_cli.optimize import OptimizeResult, Status

_DEBUG = bool(os.environ.get("HOC_DEBUG_REPLAN"))
DECREMENT_TOL = 1e-12  # Newton decrement ½ gᵀH⁻¹g relative to |J|
RHO_AUG = 1e3  # ρ of the KKT matrix's W + ρDᵀD per unit |J| (measured on the lbr7 catch: 1e1 leaves W + ρDᵀD
# indefinite, 1e6 too ill-conditioned for the banded Cholesky factorisation)
SLOPE_RTOL = 1e-7  # |F'| relative to |J|/T + weight (as ``hoc_cli.free_time.minimize_time``)


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


def replan(system, previous, goals: Goals, *, free: TimeRange | None = None, limits=None,
           curvature: float | None = None, tol: float = DECREMENT_TOL, max_steps: int = 40,
           fallback: bool = True) -> ReplanResult:
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
    curvature : d²J*/dT² [cost units/s²] to use instead of the previous plan's.
    tol : the Newton decrement's tolerance relative to |J|.
    max_steps : Newton steps before the full solver takes over (``fallback``; else returned as is).

    Returns
    -------
    ReplanResult
    """
    start = time.perf_counter()
    plan0, d2 = _start(previous)
    d2 = curvature if curvature is not None else d2
    mesh0, problem0 = plan0.mesh, plan0.problem
    order, N, G, cost = mesh0.order, mesh0.N, plan0.G, problem0.cost
    q0, dq0 = problem0.boundary[:2]
    T, C = mesh0.T, np.array(plan0.coeffs)
    limited = limits is not None and limits.any
    lam, rho = (plan0.terms.lam, plan0.terms.rho) if plan0.terms is not None else (None, 0.0)
    working = mu_lo = mu_hi = None
    rho_l = 1.0
    if limited:
        lr = plan0.limits
        working = np.zeros((4, limits.n), bool) if lr is None else lr.working.copy()
        if lr is not None and lr.penalty is not None:
            mu_lo, mu_hi, rho_l = lr.penalty.mu_lo, lr.penalty.mu_hi, lr.rho or 1.0
    weight = free.weight if free is not None else 0.0
    rho_aug = RHO_AUG * max(abs(plan0.J), 1.0)
    slope = 0.0
    probe = None  # (T, F') of the last step whose x had converged, for a secant when d2 is unknown
    evals = 0
    status = Status.MAX_ITER
    steps = 0
    for steps in range(1, max_steps + 1):
        mesh = HermiteMesh(order, T, N)
        problem = GoalProblem(system, mesh, q0, dq0, goals, cost=cost, G=G)
        if lam is None or len(lam) != len(problem.points):
            lam = [np.zeros(p.residual.size) for p in problem.points]
            rho = rho if rho > 0 else 10.0 * max(abs(plan0.J), 1e-6)
        terms = GoalTerms(mesh, problem.points, lam, 0.0)  # ρ = 0: the Lagrangian's λ·c
        lt = rows = None
        full = problem
        if limited:
            rows = LimitRows.build(mesh, problem.layout.free, limits.n)
            if mu_lo is None or any(a.shape != rows.shape(k, limits.n) for k, a in enumerate(mu_lo)):
                mu_lo = mu_hi = tuple(np.zeros(rows.shape(k, limits.n)) for k in range(4))
            lt = LimitTerms(system, limits, rows, working, mu_lo, mu_hi, rho_l, MARGIN)
            if not lt.empty:
                full = PenalizedProblem(problem, lt)
        x = problem.layout.pack(C)
        ev = full.evaluate(x)
        evals += 1
        extra = lt.newton_blocks(C) if full is not problem else None
        grad = ev.grad
        c = np.zeros(0)
        if problem.points:
            c, dc = terms.jacobian(C)
            D = np.array([problem.layout.pack(row) for row in dc])  # (r, P)
            grad = grad + D.T @ np.concatenate(lam)
            # W + ρDᵀD is positive definite where W alone is not (q at T is held by the rows only); the
            # step is the same (the multiplier step absorbs −ρc), the curvature's μ = λ + ρc → λ
            blocks = GoalTerms(mesh, problem.points, lam, rho_aug).newton_blocks(C, indefinite=True)
            extra = blocks if extra is None else extra + blocks
        try:
            W = problem.newton(ev, extra=extra)
        except NumericalError:  # away from the optimum: the rows' curvature without its negative part
            try:
                extra = extra - blocks + GoalTerms(mesh, problem.points, lam, rho_aug).newton_blocks(C)
                W = problem.newton(ev, extra=extra)
            except NumericalError:
                break
        w = W.solve(grad)
        decrement = 0.5 * float(grad @ w)
        dx = -w
        if c.size:  # the KKT step: W dx + Dᵀ dλ = −∇ℒ, D dx = −c (Schur complement on the r rows)
            Y = np.stack([W.solve(row) for row in D], axis=1)  # W⁻¹ Dᵀ (P, r)
            dlam = np.linalg.lstsq(D @ Y, c - D @ w, rcond=1e-12)[0]  # rows may be dependent (a planar arm)
            dx = dx - Y @ dlam
            dlam = dlam - rho_aug * c
            split = np.cumsum([p.residual.size for p in problem.points])[:-1]
            lam = [lv + d for lv, d in zip(lam, np.split(dlam, split))]
        before = terms.violation(C) if problem.points else 0.0
        alpha = 1.0
        while True:  # damping: a step may not raise the goal rows' violation (far steps leave the model)
            C_try = problem.coefficients(x + alpha * dx)
            violation = GoalTerms(mesh, problem.points, lam, 0.0).violation(C_try) if problem.points else 0.0
            if violation <= max(before, 1e-6) or alpha < 0.05:
                break
            alpha *= 0.5
        x, C = x + alpha * dx, C_try
        if alpha < 1.0 and c.size:
            lam = [lv - (1.0 - alpha) * d for lv, d in zip(lam, np.split(dlam, split))]
        terms = GoalTerms(mesh, problem.points, lam, 0.0)
        pv = lt.evaluate(C, grad=False) if lt is not None else None
        if free is not None:
            dT, Gc = cost_time_derivative(problem, C)
            if pv is not None and not lt.empty:
                dl, Gl = limits_time_derivative(SimpleNamespace(rows=rows, penalty=pv), system, limits, C)
                dT, Gc = dT + dl, Gc + Gl
            if problem.points:
                dg, Gg = terms.time_derivative(C, T)
                dT, Gc = dT + dg, Gc + Gg
            slope = dT + fixed_coefficient_correction(problem.layout.free, C, Gc, T)
        J = problem.value(x)
        x_done = decrement <= tol * max(abs(J), 1.0) and alpha == 1.0
        if pv is not None and not lt.empty and x_done:  # the limits' outer update, at an inner optimum
            mu_lo, mu_hi = pv.mu_lo, pv.mu_hi
        F = slope + weight
        at_bound = free is not None and ((T >= free.max and F < 0) or (T <= free.min and F > 0))
        t_done = free is None or at_bound or abs(F) <= SLOPE_RTOL * (abs(J) / T + weight)
        if _DEBUG:
            print(f"rho_l {rho_l:.3g} step {steps} T {T:.9f} J {J:.12g} dec {decrement:.2e} dx {np.max(np.abs(dx)):.1e} a {alpha} viol {violation:.1e} "
                  f"F' {F:.2e} t {1e3 * (time.perf_counter() - start):.1f} ms")
        if x_done and violation <= EQ_ACCEPT and t_done:
            check = check_limits(system, limits, mesh, C) if limited else None
            newly = None
            if check is not None:
                newly = ((check.hi_excess > 0) | (check.lo_excess > 0)).any(axis=1)
            if newly is None or not newly.any():
                status = Status.CONVERGED
                break
            working = working | newly
            continue
        if free is not None and not t_done and x_done and violation <= EQ_ACCEPT:  # T steps from fixed-T optima
            if x_done and probe is not None and probe[0] != T:
                secant = (F - probe[1]) / (T - probe[0])
                d2 = secant if secant > 0 else d2
            if x_done:
                probe = (T, F)
            if d2 is None:
                if not x_done:
                    continue
                step = -math.copysign(1e-3 * T, F)  # a probe for the secant
            else:
                step = -F / d2
            T_new = min(max(T + step, free.min), free.max)
            C = rescale(C, T, T_new)
            T = T_new
    grad = np.zeros_like(x)
    opt = OptimizeResult(x=x, fun=J, grad=grad, status=status, iterations=steps, n_evals=evals, n_precond=steps,
                         decrement=decrement, message="warm replan: " + ("converged" if status is Status.CONVERGED
                                                                           else f"{steps} Newton steps"))
    enforced = None
    if limited:
        check = check_limits(system, limits, mesh, C)
        enforced = EnforceResult(status="converged" if status is Status.CONVERGED else "not_converged",
                                 message=opt.message, inner=opt, x=x, J=J, outer_iterations=steps, rho=rho_l,
                                 check=check, working=working, rows=rows, penalty=pv)
    used = GoalTerms(mesh, problem.points, lam, rho if rho > 0 else 10.0 * max(abs(J), 1e-6))
    plan = GoalResult(mesh=mesh, coeffs=C, J=J, optimizer=opt, G=G, quadrature_change=math.nan,
                      wall_time_s=time.perf_counter() - start, problem=problem, limits=enforced, terms=used,
                      violation=violation, outer_iterations=steps, goals=goals)
    if status is not Status.CONVERGED and fallback:  # from the previous plan: the steps may have wandered off
        return _finish(system, plan0 if violation > 1e-6 else plan, goals, free, limits, d2, start)
    return ReplanResult(plan=plan, T=T, dJ_dT=slope, curvature=d2, steps=steps, fallback=False,
                        wall_time_s=time.perf_counter() - start)


def _finish(system, plan: GoalResult, goals: Goals, free: TimeRange | None, limits, d2, start: float) -> ReplanResult:
    """The full solver from where the Newton steps got (``plan_goals``; the free-T search with a free T)."""
    from hoc_cli.free_time import goal_solver, minimize_time, plan_time_derivative

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
    solver = goal_solver(system, mesh.order, mesh.N, q0, dq0, goals, limits=limits, **options)
    seed = SimpleNamespace(T=mesh.T, result=plan)

    def solve(T, nearest):
        return solver(T, nearest if nearest is not None else seed)

    ft = minimize_time(solve, free.min, free.max, guess=mesh.T, weight=free.weight)
    return ReplanResult(plan=ft.result, T=ft.T, dJ_dT=ft.dJ_dT, curvature=curvature_of(ft) or d2,
                        steps=plan.outer_iterations, fallback=True, wall_time_s=time.perf_counter() - start)
