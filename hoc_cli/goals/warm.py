"""A ``GoalResult`` from a plan's coefficients alone (e.g. read back from its MCAP), to start a warm replan.

``hoc_cli.goals.replan.replan`` starts from a previous plan: its mesh, coefficients, quadrature, cost and
the goal rows' multipliers λ. A plan file stores the mesh and coefficients but not λ; at an optimum of
the previous goals they satisfy ∇ₓI + Dᵀλ = 0 (x the free coefficients, I the cost, D = ∂c/∂x the goal
rows' Jacobian), so ``previous_plan`` estimates them by least squares, λ = argmin ‖∇ₓI + Dᵀλ‖, or
starts from zeros. With limits the rows near their bound join with multipliers μ ≥ 0 (the limits'
working set and multipliers, which the plan file does not store either). Pure maths: no I/O.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hoc_cli.elements import HermiteMesh
from hoc_cli.goals.plan import RHO0, GoalProblem, GoalResult, Goals
from hoc_cli.goals.terms import GoalTerms
from hoc_cli.optimize import OptimizeResult, Status


@dataclass(frozen=True, eq=False)
class EstimatedLimits:
    """The limits' state of a plan estimated from its coefficients, read by ``replan`` as it reads an
    ``EnforceResult``: ``working`` (K, n) the (kind, joint) pairs with rows near their bound, ``penalty``
    their multipliers μ ≥ 0 (a ``Duals``), ``rho`` the penalty to continue with, ``status``.
    """

    working: np.ndarray
    penalty: object
    rho: float
    status: str = "converged"


def _limit_columns(system, limits, rows, C: np.ndarray, free: np.ndarray, near: float):
    """The limit rows within ``near`` of their bound at C (g > −near, dimensionless) and their gradients.

    Returns (candidates [(kind, side, index)], A (P, c)): column i is ∂(±V/σ)/∂x of candidate i (+ for an
    upper bound, − for a lower), the penalty gradient per unit multiplier (``LimitTerms.evaluate``).
    """
    from hoc_cli.constraints.augmented_lagrangian import MARGIN
    from hoc_cli.constraints.penalty import EFFORT, KINDS, LimitTerms, effective_bounds

    n = limits.n
    zeros = tuple(np.zeros(rows.shape(k, n)) for k in range(len(KINDS)))
    every = np.ones((len(KINDS), n), bool)
    pv = LimitTerms(system, limits, rows, every, zeros, zeros, 1.0, MARGIN).evaluate(C, grad=False)
    _, _, sig = effective_bounds(limits, MARGIN)
    X = rows.points.apply(C) if np.any(pv.g_lo[EFFORT] > -near) or np.any(pv.g_hi[EFFORT] > -near) else None
    candidates, columns = [], []
    for k in range(len(KINDS)):
        for side, g in ((-1.0, pv.g_lo[k]), (1.0, pv.g_hi[k])):
            for idx in zip(*np.nonzero(g > -near)):
                dV = np.zeros(rows.shape(k, n))
                dV[idx] = side / sig[k][idx[-1]]
                if k == EFFORT:
                    _, gq, gdq, gddq = system.id_vjp(X[0], X[1], X[2], dV)
                    G = rows.points.transpose(np.stack([gq, gdq, gddq]))
                else:
                    G = rows.to_coefficients(rows.transpose(k, dV))
                candidates.append((k, side, idx))
                columns.append(G.reshape(-1)[free])
    A = np.array(columns).T if columns else np.zeros((int(free.sum()), 0))
    return candidates, A


def estimate_state(system, problem: GoalProblem, C: np.ndarray, grad: np.ndarray, limits=None,
                   near: float = 1e-3, J: float | None = None) -> tuple[list[np.ndarray], object]:
    """(λ per goal row point, the limits' state or None) at a plan's coefficients C (N+1, m, n).

    Least squares on the stationarity ∇ₓJ + Dᵀλ + Σ μ ∂(±V/σ)/∂x = 0 over the goal rows (λ free) and the
    limit rows within ``near`` of their bound (μ ≥ 0; ``scipy.optimize.lsq_linear``). The limits' state is
    what ``replan`` reads from a plan's ``limits``: ``working`` (K, n) the kinds and joints of those rows,
    ``penalty.mu_lo``/``mu_hi`` the multipliers, ``rho`` the penalty's start (ρ0 of the limits' loop; ``J``: the
    problem's objective at C when known, else evaluated).
    """
    from scipy.optimize import lsq_linear

    from hoc_cli.constraints.augmented_lagrangian import RHO_START
    from hoc_cli.constraints.penalty import KINDS, LimitRows
    from hoc_cli.constraints.prolong import Duals

    free = problem.layout.free
    D = np.zeros((0, int(free.sum())))
    if problem.points:
        c, dc = GoalTerms.start(problem.mesh, problem.points).jacobian(C)
        D = dc.reshape(len(c), -1)[:, free]
    limited = limits is not None and limits.any
    rows = LimitRows.build(problem.mesh, free, limits.n) if limited else None
    candidates, A = _limit_columns(system, limits, rows, C, free, near) if limited else ([], np.zeros((D.shape[1], 0)))
    r = D.shape[0]
    M = np.hstack([D.T, A])
    sol = np.zeros(M.shape[1])
    if M.shape[1] and not candidates:
        sol = np.linalg.lstsq(M, -np.asarray(grad, float), rcond=None)[0]
    elif M.shape[1]:
        lower = np.concatenate([np.full(r, -np.inf), np.zeros(len(candidates))])
        sol = lsq_linear(M, -np.asarray(grad, float), bounds=(lower, np.inf), method="bvls", tol=1e-14).x
    lam = np.split(sol[:r], np.cumsum([p.residual.size for p in problem.points])[:-1]) if problem.points else []
    if not limited:
        return lam, None
    n = limits.n
    mu = {side: [np.zeros(rows.shape(k, n)) for k in range(len(KINDS))] for side in (-1.0, 1.0)}
    working = np.zeros((len(KINDS), n), bool)
    for (k, side, idx), value in zip(candidates, sol[r:]):
        mu[side][k][idx] = value
        working[k, idx[-1]] = True
    J = problem.value(problem.layout.pack(C)) if J is None else J
    rho = RHO_START * max(abs(J), 1e-6) / problem.mesh.T
    return lam, EstimatedLimits(working=working, penalty=Duals(rows, tuple(mu[-1.0]), tuple(mu[1.0])), rho=rho)


def previous_plan(system, mesh: HermiteMesh, C: np.ndarray, q0, dq0, goals: Goals, *, cost: str = "covariant",
                  G: int | None = None, multipliers: str = "least-squares", limits=None) -> GoalResult:
    """The plan with coefficients C (N+1, m, n) on ``mesh`` for ``goals`` as a ``GoalResult`` (a replan's
    ``previous``): J, the rows' violation, ρ = 10·|J|, and by ``multipliers``: "least-squares" λ and, with
    ``limits``, the limits' state (``estimate_state``; its ``limits``), or "zeros" (λ = 0, no limits'
    state: the replan starts with an empty working set; J alone is evaluated, the optimizer's ``grad`` None, the
    replan's first point has its own). x0's and pinned vias' values replace C's there
    (the layout's fixed coefficients).
    """
    if multipliers not in ("least-squares", "zeros"):
        raise ValueError(f"multipliers must be 'least-squares' or 'zeros', got {multipliers!r}")
    problem = GoalProblem(system, mesh, q0, dq0, goals, cost=cost, G=G)
    x = problem.layout.pack(np.asarray(C, float))
    C = problem.coefficients(x)
    ev = problem.evaluate(x, grad=multipliers == "least-squares")  # the same J without the gradient (zeros: unused)
    state = None
    if multipliers == "least-squares":
        lam, state = estimate_state(system, problem, C, ev.grad, limits, J=ev.J)
    else:
        lam = [np.zeros(p.residual.size) for p in problem.points]
    terms = GoalTerms(mesh, problem.points, lam, RHO0 * max(abs(ev.J), 1e-6))
    opt = OptimizeResult(x=x, fun=ev.J, grad=ev.grad, status=Status.CONVERGED, iterations=0, n_evals=1,
                         n_precond=0, decrement=math.nan, message="read from a plan")
    return GoalResult(mesh=mesh, coeffs=C, J=ev.J, optimizer=opt, G=problem.G, quadrature_change=math.nan,
                      wall_time_s=0.0, problem=problem, limits=state, terms=terms,
                      violation=terms.violation(C) if problem.points else 0.0, goals=goals)


def initial_plan(system, mesh: HermiteMesh, q0, dq0, goals: Goals, *, cost: str = "covariant",
                 G: int | None = None) -> GoalResult:
    """The initial trajectory of ``plan_goals`` on ``mesh`` (minimum jerk from x0 to the goal's final state
    or its guess, ``Goals.q1_guess``) as a ``GoalResult`` with zero multipliers and no limits' state: the
    start of a replan's Newton steps from scratch (``hoc_cli.goals.free_time_sqp``).
    """
    problem = GoalProblem(system, mesh, q0, dq0, goals, cost=cost, G=G)
    C = problem.coefficients(problem.initial_guess())
    return previous_plan(system, mesh, C, q0, dq0, goals, cost=cost, G=G, multipliers="zeros")
