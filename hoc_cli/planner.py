"""Plan: minimise I(q_h) over the free Hermite coefficients and check the quadrature.

``plan`` ties ``ControlProblem`` (cost, gradient, Gauss-Newton matrix) to the optimiser
(preconditioned PR+ CG by default) and returns a ``PlanResult``. Pure maths: no I/O.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from hoc_cli.elements import HermiteMesh
from hoc_cli.errors import NumericalError
from hoc_cli.optimize import IterLog, OptimizeResult, Status, minimize
from hoc_cli.problem import ControlProblem, Evaluation
from hoc_cli.system import System

QUADRATURE_RTOL = 1e-12


@dataclass(eq=False)
class PlanResult:
    """The optimal coefficients and how they were found.

    coeffs : (N+1, m, n) Hermite coefficients; J : cost at the solution;
    G : Gauss points per element used; quadrature_change : |J(G+4) − J(G)| / |J| at the solution;
    wall_time_s : the solve alone [s].
    """

    mesh: HermiteMesh
    coeffs: np.ndarray
    J: float
    optimizer: OptimizeResult
    G: int
    quadrature_change: float
    wall_time_s: float
    problem: ControlProblem

    @property
    def converged(self) -> bool:
        return self.optimizer.converged


def _cost_with(system: System, mesh: HermiteMesh, boundary, cost: str, G: int, C: np.ndarray) -> float:
    p = ControlProblem(system, mesh, *boundary, cost=cost, G=G)
    return p.value(p.layout.pack(C))


def plan(system: System, mesh: HermiteMesh, q0, dq0, q1, dq1, *, cost: str = "covariant", method: str = "pr-cg",
         tol: float = 1e-10, max_iter: int = 5000, C_init: np.ndarray | None = None, G: int | None = None,
         precondition: bool = True, callback: Callable[[IterLog], None] | None = None) -> PlanResult:
    """Solve the optimal-control problem on ``mesh`` from the minimum-jerk guess (or ``C_init``).

    After convergence the cost is recomputed with 4 more Gauss points per element; while it changes
    by more than 1e-12 relative (and by more than the rounding level of J), G grows by 4 and the
    solve continues from the solution.
    """
    start = time.perf_counter()
    total_iters = total_evals = total_pre = 0
    history: list[IterLog] = []
    while True:
        problem = ControlProblem(system, mesh, q0, dq0, q1, dq1, cost=cost, G=G)
        x0 = problem.initial_guess() if C_init is None else problem.layout.pack(C_init)

        failures: list[NumericalError] = []

        def evaluate(x: np.ndarray):
            try:
                ev = problem.evaluate(x)
            except NumericalError as exc:  # NaN/inf cost or singular M at a trial point: the line search steps back
                failures.append(exc)
                return math.inf, np.full(x.shape, np.nan), None
            return ev.J, ev.grad, ev

        if precondition:
            # Gauss-Newton preconditioner while far from the optimum; the exact (banded) Newton matrix
            # once the decrement is below 1e-6·|J| and to confirm the stopping test
            pre, final = problem.gauss_newton, problem.newton
        else:
            pre = final = None
        res = minimize(evaluate, x0, precondition=pre, final_precondition=final, switch=1e-6, method=method,
                       tol=tol, max_iter=max_iter - total_iters, callback=callback, noise=lambda ev: ev.noise)
        if res.status is Status.NOT_FINITE and res.iterations == 0 and failures:
            raise failures[0]  # the starting trajectory itself cannot be evaluated
        total_iters += res.iterations
        total_evals += res.n_evals
        total_pre += res.n_precond
        history += res.history
        C = problem.coefficients(res.x)
        J4 = _cost_with(system, mesh, problem.boundary, cost, problem.G + 4, C)
        change = abs(J4 - res.fun) / max(abs(J4), 1e-300)
        noise = problem.last.noise if problem.last is not None else 0.0
        resolved = change <= QUADRATURE_RTOL or abs(J4 - res.fun) <= 4 * noise  # else: truncation, refine
        if resolved or not res.converged or problem.G >= 32:
            break
        G, C_init = problem.G + 4, C
    res.iterations, res.n_evals, res.n_precond, res.history = total_iters, total_evals, total_pre, history
    return PlanResult(mesh=mesh, coeffs=C, J=res.fun, optimizer=res, G=problem.G, quadrature_change=change,
                      wall_time_s=time.perf_counter() - start, problem=problem)
