"""A ``GoalResult`` from a plan's coefficients alone (e.g. read back from its MCAP), to start a warm replan.

``hoc_cli.goals.replan.replan`` starts from a previous plan: its mesh, coefficients, quadrature, cost and
the goal rows' multipliers λ. A plan file stores the mesh and coefficients but not λ; at an optimum of
the previous goals they satisfy ∇ₓI + Dᵀλ = 0 (x the free coefficients, I the cost, D = ∂c/∂x the goal
rows' Jacobian), so ``previous_plan`` estimates them by least squares, λ = argmin ‖∇ₓI + Dᵀλ‖, or
starts from zeros. Pure maths: no I/O.
"""
from __future__ import annotations

import math

import numpy as np

from hoc_cli.elements import HermiteMesh
from hoc_cli.goals.plan import RHO0, GoalProblem, GoalResult, Goals
from hoc_cli.goals.terms import GoalTerms
from hoc_cli.optimize import OptimizeResult, Status


def estimate_multipliers(problem: GoalProblem, C: np.ndarray, grad: np.ndarray) -> list[np.ndarray]:
    """λ per goal row point minimising ‖∇ₓI + Dᵀλ‖ (least squares) at coefficients C (N+1, m, n);
    ``grad`` (P,) the cost gradient over the free coefficients.
    """
    terms = GoalTerms.start(problem.mesh, problem.points)
    if not problem.points:
        return []
    c, dc = terms.jacobian(C)
    D = dc.reshape(len(c), -1)[:, problem.layout.free]
    lam = np.linalg.lstsq(D.T, -np.asarray(grad, float), rcond=None)[0]
    return np.split(lam, np.cumsum([p.residual.size for p in problem.points])[:-1])


def previous_plan(system, mesh: HermiteMesh, C: np.ndarray, q0, dq0, goals: Goals, *, cost: str = "covariant",
                  G: int | None = None, multipliers: str = "least-squares") -> GoalResult:
    """The plan with coefficients C (N+1, m, n) on ``mesh`` for ``goals`` as a ``GoalResult`` (a replan's
    ``previous``): J, the rows' violation, λ by ``multipliers`` ("least-squares" or "zeros"), no limits'
    state (the replan starts with an empty working set), ρ = 10·|J|. x0's and pinned vias' values
    replace C's there (the layout's fixed coefficients).
    """
    problem = GoalProblem(system, mesh, q0, dq0, goals, cost=cost, G=G)
    x = problem.layout.pack(np.asarray(C, float))
    C = problem.coefficients(x)
    ev = problem.evaluate(x)
    if multipliers == "least-squares":
        lam = estimate_multipliers(problem, C, ev.grad)
    elif multipliers == "zeros":
        lam = [np.zeros(p.residual.size) for p in problem.points]
    else:
        raise ValueError(f"multipliers must be 'least-squares' or 'zeros', got {multipliers!r}")
    terms = GoalTerms(mesh, problem.points, lam, RHO0 * max(abs(ev.J), 1e-6))
    opt = OptimizeResult(x=x, fun=ev.J, grad=ev.grad, status=Status.CONVERGED, iterations=0, n_evals=1,
                         n_precond=0, decrement=math.nan, message="read from a plan")
    return GoalResult(mesh=mesh, coeffs=C, J=ev.J, optimizer=opt, G=problem.G, quadrature_change=math.nan,
                      wall_time_s=0.0, problem=problem, limits=None, terms=terms,
                      violation=terms.violation(C) if problem.points else 0.0, goals=goals)
