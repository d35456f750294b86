"""Free final time: minimise J*(T) + weight·T over T ∈ [T_min, T_max], with the exact dJ*/dT.

J*(T) is the optimal cost of the fixed-T problem (``hoc_cli.planner.plan``, or the goal planner
of ``hoc_cli.goals``), limits and goals included. The time axis is scaled: with s = t/T ∈ [0, 1]
fixed, a Hermite coefficient of derivative order d (q, q̇, q̈ at a node) is (T₀/T)^d times its
s-domain value, so a plan for T₀ becomes a plan for T by ``rescale``, the warm start of the next
solve. Along this family (coefficients fixed by the task, such as x0's q̇, stay in the t domain)
the envelope theorem gives the derivative of J* as the partial derivative of the Lagrangian:

    dJ*/dT = (1/T) Σ_k w_k [L − ∂L/∂q̇·q̇ − 2 ∂L/∂q̈·q̈]                         (cost)
           + Σ μ ∂g/∂T  over the limit rows (∂V_r/∂T = −r V_r/T for d^r q/dt^r rows,
             ∂u/∂T = −(∂u/∂q̇·q̇ + 2 M q̈)/T for torque points)                 (limits)
           + Σ μ_e ∂c_e/∂T  over the goal rows (``hoc_cli.goals``)                (goals)
           + (1/T) Σ_{fixed, d ≥ 1} d·C[p, d]·∂ℒ/∂C[p, d]                       (fixed q̇, q̈)

with the samples k at the Gauss points (weights w_k [s]), L the integrand, μ the multipliers.
The outer problem is one-dimensional: its derivative F'(T) = dJ*/dT + weight is brought to
zero by a bracketing root finder (Brent) or the bound decides. Pure maths: no I/O.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from hoc_cli.constraints.augmented_lagrangian import MARGIN
from hoc_cli.constraints.penalty import EFFORT, effective_bounds

STEP = 1.25  # the search for a bracket moves T by this factor, growing ×1.25 a step up to 2


def rescale(C: np.ndarray, T_from: float, T_to: float) -> np.ndarray:
    """Coefficients (N+1, m, n) of the same s-domain trajectory on [0, T_to]: C[:, d] · (T_from/T_to)^d."""
    C = np.asarray(C, float)
    factor = (T_from / T_to) ** np.arange(C.shape[1])
    return C * factor[None, :, None]


def cost_time_derivative(problem, C: np.ndarray) -> tuple[float, np.ndarray]:
    """(∂J/∂T at fixed s-domain coefficients, ∂J/∂C (N+1, m, n) over every coefficient) for a ControlProblem."""
    op = problem.op
    q, dq, ddq = op.apply(C)
    s = problem.sample_gradients(q, dq, ddq, jacobians=False)
    w = op.w
    dT = float(np.dot(w, s.L - np.einsum("ki,ki->k", s.gdq, dq) - 2 * np.einsum("ki,ki->k", s.gddq, ddq)))
    W = w[:, None]
    return dT / problem.mesh.T, op.transpose(W * s.gq, W * s.gdq, W * s.gddq)


def limits_time_derivative(duals, system, limits, C: np.ndarray) -> tuple[float, np.ndarray]:
    """(Σ μ ∂g/∂T, Σ μ ∂g/∂C (N+1, m, n)) of the limit rows at coefficients C.

    ``duals``: a ``hoc_cli.constraints.prolong.Duals`` (the rows and their multipliers μ, e.g. an
    ``EnforceResult``'s ``duals()``), or None (no limits, or none imposed): zero.
    """
    G = np.zeros_like(np.asarray(C, float))
    if duals is None:
        return 0.0, G
    rows, pv = duals.rows, duals
    mesh = rows.mesh
    _, _, sig = effective_bounds(limits, MARGIN)
    loc = mesh.local_coefficients(C)
    gloc = np.zeros_like(loc)
    dT = 0.0
    for k in range(len(pv.mu_lo)):
        lam = (pv.mu_hi[k] - pv.mu_lo[k]) / sig[k]  # ∂(Σ μ g)/∂V
        if not np.any(lam):
            continue
        if k == EFFORT:
            X = rows.points.apply(C)
            _, gq, gdq, gddq = system.id_vjp(X[0], X[1], X[2], lam)
            dT -= float(np.sum(gdq * X[1]) + 2 * np.sum(gddq * X[2])) / mesh.T
            G += rows.points.transpose(np.stack([gq, gdq, gddq]))
        else:
            V = rows.apply(k, loc)
            dT -= k * float(np.sum(lam * V)) / mesh.T
            gloc += rows.transpose(k, lam)  # (with a non-uniform mesh's element scales)
    return dT, G + rows.to_coefficients(gloc)


def fixed_coefficient_correction(free: np.ndarray, C: np.ndarray, G: np.ndarray, T: float) -> float:
    """(1/T) Σ d·C[p, d]·G[p, d] over the fixed coefficients of derivative order d ≥ 1 (they keep their
    t-domain values while the scaled family would move them by −d·C/T). free (P,) bool, C, G (N+1, m, n).
    """
    d = np.arange(C.shape[1])[None, :, None] * np.ones_like(C)
    fixed = ~free.reshape(C.shape)
    return float(np.sum(np.where(fixed, d * C * G, 0.0))) / T


def fixed_coefficient_motion(free: np.ndarray, C: np.ndarray, T: float) -> tuple[np.ndarray, np.ndarray]:
    """(V1, V2) (N+1, m, n): the first and second T derivatives of C along the rescaled family minus those of the
    scaled family itself, nonzero at the fixed coefficients only: d·C/T and d(d−1)·C/T² there (a fixed coefficient of
    derivative order d keeps its t-domain value, i.e. its s-domain value C·T^d grows, while the family keeps every
    s-domain value). Applied by the t-domain operators at T, they give the samples' departures from the scaled
    family's motion (``cost_time_column``). free (P,) bool, C (N+1, m, n), T [s].
    """
    d = np.arange(C.shape[1], dtype=float)[None, :, None]
    fixed = ~np.asarray(free, bool).reshape(C.shape)
    return np.where(fixed, d * C / T, 0.0), np.where(fixed, d * (d - 1.0) * C / T**2, 0.0)


def cost_time_column(op, T: float, samples: tuple[np.ndarray, np.ndarray, np.ndarray], s, Hs: np.ndarray,
                     V1: np.ndarray, V2: np.ndarray) -> tuple[np.ndarray, float]:
    """(∂/∂T of ∂I/∂C (N+1, m, n), d²I/dT²) along the rescaled family (``rescale``: fixed s-domain free coefficients,
    the fixed coefficients at their t-domain values): the T column of I's Hessian in (x, T).

    With s = t/T, q = q̃(s), q̇ = q̃'(s)/T, q̈ = q̃''(s)/T² and the weights w_k = T·ŵ_k, I = T Σ ŵ_k L(z_k): along the
    family the samples z = (q, q̇, q̈) move by Δ = (0, −q̇/T, −2q̈/T) + op(V1) and z'' = op(V2) + (0, 2q̇/T² − 2 op(V1)₁/T,
    6q̈/T² − 4 op(V1)₂/T), so that

        ∂(∂I/∂C)/∂T = opᵀ(w·[∂L/∂q / T + (HΔ)_q,  (HΔ)_q̇,  (HΔ)_q̈ − ∂L/∂q̈ / T])          (the scaled shape functions
                                                                                      and weights, then H·Δ)
        d²I/dT² = Σ w [2 ∇L·Δ / T + Δᵀ H Δ + ∇L·z'']

    (the free coefficients' x-derivative is the t-domain gradient at T: the column of the Hessian in (x, T) of
    ``replan_qp``'s steps, whose x is scaled with T). op : the ``QuadratureOperator`` of the samples (K points,
    weights ``op.w`` [s]); samples : (q, q̇, q̈) (K, n) there; s : their ``SampleGradients`` (L, ∂L/∂q, ∂L/∂q̇, ∂L/∂q̈);
    Hs (K, 3n, 3n): the per-sample Hessians of L on the same samples (``ControlProblem.hessian_samples`` with
    ``op_h`` = op); V1, V2 : ``fixed_coefficient_motion``.
    """
    q, dq, ddq = samples
    n = q.shape[1]
    p = op.apply(V1)
    p2 = op.apply(V2)
    delta = np.concatenate([p[0], p[1] - dq / T, p[2] - 2.0 * ddq / T], axis=1)  # (K, 3n)
    curve = np.concatenate([p2[0], p2[1] + 2.0 * dq / T**2 - 2.0 * p[1] / T,
                            p2[2] + 6.0 * ddq / T**2 - 4.0 * p[2] / T], axis=1)
    grad = np.concatenate([s.gq, s.gdq, s.gddq], axis=1)
    Hd = np.einsum("kij,kj->ki", Hs, delta)
    w = op.w
    W = w[:, None]
    column = op.transpose(W * (s.gq / T + Hd[:, :n]), W * Hd[:, n:2 * n], W * (Hd[:, 2 * n:] - s.gddq / T))
    second = float(np.dot(w, 2.0 * np.einsum("ki,ki->k", grad, delta) / T + np.einsum("ki,ki->k", Hd, delta)
                          + np.einsum("ki,ki->k", grad, curve)))
    return column, second


def row_time_derivatives(values: np.ndarray, kind: np.ndarray, T: float, moved: np.ndarray,
                         moved2: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """(g', g'') of linear rows along the rescaled family: a row of the d^k q/dt^k of the s-domain trajectory scales
    as T^−k, so g' = −k·V/T + A·V1 and g'' = k(k+1)·V/T² − 2k·A·V1/T + A·V2 (the fixed coefficients' motion V1, V2
    of ``fixed_coefficient_motion``). values (a,) = A·C (without the rows' offsets); kind (a,) the derivative order
    k; moved, moved2 (a,) = A·V1, A·V2 (g'' is None without moved2).
    """
    k = np.asarray(kind, float)
    first = -k * values / T + moved
    if moved2 is None:
        return first, None
    return first, k * (k + 1.0) * values / T**2 - 2.0 * k * moved / T + moved2


def plan_time_derivative(result, system, limits=None, goals=None) -> float:
    """dJ*/dT of a ``PlanResult`` (its problem, coefficients, limits outcome; ``goals`` the goal terms
    with their multipliers, an object with ``time_derivative(C, T) -> (dT, G)``, or None).
    """
    problem, C = result.problem, result.coeffs
    dT, G = cost_time_derivative(problem, C)
    if result.limits is not None and limits is not None:
        dl, Gl = limits_time_derivative(result.limits.duals(), system, limits, C)
        dT, G = dT + dl, G + Gl
    if goals is not None:
        dg, Gg = goals.time_derivative(C, result.mesh.T)
        dT, G = dT + dg, G + Gg
    return dT + fixed_coefficient_correction(problem.layout.free, C, G, result.mesh.T)


@dataclass(frozen=True, eq=False)
class TimePoint:
    """One solve of the fixed-T problem: T [s], J*(T), dJ*/dT, and the solver's result."""

    T: float
    J: float
    dJ_dT: float
    result: object


@dataclass(frozen=True, eq=False)
class FreeTimeResult:
    """The optimal duration: T [s], J* at T, dJ*/dT there (≈ −weight at an interior optimum),
    the objective J* + weight·T, which bound is active ("min", "max" or None), every solve made;
    ``converged`` False when the search ended at a jump of dJ*/dT (|F'| > 1e-4 relative) instead of F' = 0.
    """

    T: float
    J: float
    dJ_dT: float
    objective: float
    weight: float
    bound: str | None
    point: TimePoint
    history: list[TimePoint] = field(default_factory=list)
    converged: bool = True

    @property
    def result(self):
        return self.point.result


class _Done(Exception):
    """Raised inside the root finder when |F'(T)| is already small enough."""

    def __init__(self, point: TimePoint) -> None:
        self.point = point


class _Exhausted(Exception):
    """Raised by the search's solve when it has made ``max_solves`` solves."""


def exhausted(result, message: str):
    """The plan ``result`` (``PlanResult`` or ``GoalResult``) marked as not converged with ``message``: its optimizer's
    status ``max_iter`` and its limits' outcome (when enforced) ``not_converged``, so that the summary says so.
    """
    import dataclasses

    from hoc_cli.optimize import Status

    changes = {}
    if getattr(result, "optimizer", None) is not None:
        changes["optimizer"] = dataclasses.replace(result.optimizer, status=Status.MAX_ITER, message=message)
    if getattr(result, "limits", None) is not None:
        changes["limits"] = dataclasses.replace(result.limits, status="not_converged", message=message)
    return dataclasses.replace(result, **changes)


def minimize_time(solve: Callable[[float, "TimePoint | None"], TimePoint], T_min: float, T_max: float,
                  guess: float | None = None, weight: float = 0.0, rtol: float = 1e-7,
                  max_solves: int = 40) -> FreeTimeResult:
    """Minimise over T ∈ [T_min, T_max] F(T) = J*(T) + weight·T from the derivative F' = dJ*/dT + weight.

    ``solve(T, nearest)`` solves the fixed-T problem (``nearest``: the solved point closest to T,
    for a warm start, or None) and returns a ``TimePoint``. From ``guess`` (default √(T_min·T_max))
    T grows or shrinks (by 1.25, then 1.56, … up to 2 a step; halfway back after a failed solve)
    until F' changes sign or a bound is reached (an active bound: F' < 0 at
    T_max or F' > 0 at T_min); Brent's method then finds the zero of F' in the bracket, stopping
    when |F'| <= rtol·(|J*|/T + |weight|) or the bracket is narrower than rtol·T. After ``max_solves`` solves
    without that, the search ends at the converged solve with the smallest |F'|, not converged, its plan's status
    ``max_iter`` (``exhausted``).
    """
    if not (0 < T_min <= T_max):
        raise ValueError(f"need 0 < T_min <= T_max, got {T_min}, {T_max}")
    history: list[TimePoint] = []

    def at(T: float) -> TimePoint:
        T = float(min(max(T, T_min), T_max))
        for p in history:
            if p.T == T:
                return p
        if len(history) >= max_solves:
            raise _Exhausted()
        nearest = min(history, key=lambda p: abs(math.log(p.T / T)), default=None)
        p = solve(T, nearest)
        history.append(p)
        return p

    def converged(p: TimePoint) -> bool:
        return bool(getattr(p.result, "converged", True))

    def slope(p: TimePoint) -> float:
        return p.dJ_dT + weight

    def small(p: TimePoint) -> bool:
        return abs(slope(p)) <= rtol * (abs(p.J) / p.T + abs(weight))

    def finish(p: TimePoint, bound: str | None) -> FreeTimeResult:
        ok = bound is not None or small(p) or abs(slope(p)) <= 1e-4 * (abs(p.J) / p.T + abs(weight))
        return FreeTimeResult(T=p.T, J=p.J, dJ_dT=p.dJ_dT, objective=p.J + weight * p.T, weight=weight,
                              bound=bound, point=p, history=history, converged=ok)

    T0 = math.sqrt(T_min * T_max) if guess is None else min(max(guess, T_min), T_max)
    try:
        return _search(at, T0, T_min, T_max, rtol, max_solves, slope, small, converged, finish)
    except _Exhausted:
        best = min((q for q in history if converged(q)), key=lambda q: abs(slope(q)), default=history[-1])
        message = f"free final time: no optimum within {max_solves} solves"
        point = TimePoint(T=best.T, J=best.J, dJ_dT=best.dJ_dT, result=exhausted(best.result, message))
        return FreeTimeResult(T=best.T, J=best.J, dJ_dT=best.dJ_dT, objective=best.J + weight * best.T, weight=weight,
                              bound=None, point=point, history=history, converged=False)


def _search(at, T0: float, T_min: float, T_max: float, rtol: float, max_solves: int, slope, small, converged,
            finish) -> FreeTimeResult:
    """``minimize_time``'s bracket and Brent's method on F' (its docstring), with its closures."""
    p = at(T0)
    if small(p):
        return finish(p, None)
    up = slope(p) < 0
    factor = STEP
    while True:
        if up and p.T >= T_max:
            return finish(p, "max")
        if not up and p.T <= T_min:
            return finish(p, "min")
        prev, p = p, at(p.T * factor if up else p.T / factor)
        for _ in range(3):  # a solve that failed (a far warm start): step back halfway
            if converged(p):
                break
            p = at(math.sqrt(prev.T * p.T))
        if small(p):
            return finish(p, None)
        if (slope(p) > 0) == up:  # the sign changed: a bracket
            lo, hi = (prev, p) if up else (p, prev)
            break
        factor = min(factor * STEP, 2.0)

    def f(T: float) -> float:
        q = at(T)
        if small(q):
            raise _Done(q)
        return slope(q)

    try:
        from scipy.optimize import brentq  # scipy.optimize costs 0.25 s to import: only when Brent runs

        root = brentq(f, lo.T, hi.T, xtol=rtol * lo.T, rtol=4 * np.finfo(float).eps, maxiter=max_solves, disp=False)
        best = at(root)
    except _Done as done:
        best = done.point
    return finish(best, None)


def constraint_start(result, factor: float) -> dict:
    """The warm start of a constraint's loop (``planner.plan``'s and ``goals.plan_goals``' ``constraint_warm`` and
    ``working``) from ``result``, a plan with a constraint in ``1/factor`` times the duration: its outcome's
    multipliers stretched to the new duration (``warm.stretched``) and its joint limits' working set; empty without
    a constraint. Without them the limits' rounds of the next plan start from zero multipliers at their first ρ and
    leave the warm start far from its limits (the lbr7 catch past a sphere: a fixed-T plan of minutes).
    """
    outcome = getattr(result, "constraint", None)
    if outcome is None or outcome.warm is None:
        return {}
    limits = getattr(result, "limits", None)
    return {"constraint_warm": outcome.warm.stretched(factor), "working": None if limits is None else limits.working}


def joint_goal_solver(system, order: str, N: int, q0, dq0, q1, dq1, *, limits=None,
                      **plan_options) -> Callable[[float, "TimePoint | None"], TimePoint]:
    """``solve(T, nearest)`` for ``minimize_time`` on a joint goal: ``hoc_cli.planner.plan`` on N elements
    of [0, T], warm-started from ``nearest`` rescaled to T, and ``plan_time_derivative``.
    """
    from hoc_cli.elements import HermiteMesh
    from hoc_cli.planner import plan

    def solve(T: float, nearest: TimePoint | None) -> TimePoint:
        C_init = None if nearest is None else rescale(nearest.result.coeffs, nearest.T, T)
        warm = {} if nearest is None else constraint_start(nearest.result, T / nearest.T)
        result = plan(system, HermiteMesh(order, T, N), q0, dq0, q1, dq1, C_init=C_init, limits=limits,
                      **warm, **plan_options)
        return TimePoint(T=T, J=result.J, dJ_dT=plan_time_derivative(result, system, limits), result=result)

    return solve
