"""Plan: minimise I(q_h) over the free Hermite coefficients and check the quadrature.

``plan`` ties ``ControlProblem`` (cost, gradient, Newton matrix) to the optimiser
(preconditioned PR+ CG by default) and returns a ``PlanResult``. Pure maths: no I/O.
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from hoc_cli.constraints import EnforceResult, JointLimits, enforce
from hoc_cli.constraints.augmented_lagrangian import PenalizedProblem
from hoc_cli.elements import HermiteMesh
from hoc_cli.errors import NumericalError
from hoc_cli.optimize import IterLog, OptimizeResult, Status, minimize
from hoc_cli.problem import ControlProblem
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
    limits: EnforceResult | None = None

    @property
    def converged(self) -> bool:
        if self.limits is not None:
            return self.limits.status == "converged"
        return self.optimizer.converged


def _cost_with(system: System, mesh: HermiteMesh, boundary, cost: str, G: int, C: np.ndarray) -> float:
    p = ControlProblem(system, mesh, *boundary, cost=cost, G=G)
    return p.value(p.layout.pack(C))


def continuation_levels(N: int, factor: int = 4, coarsest: int = 2) -> list[int]:
    """Element counts of the coarse-to-fine sequence ending at N: …, ⌈N/16⌉, ⌈N/4⌉, N, none below ``coarsest``.

    E.g. 36 → [3, 9, 36], 16 → [4, 16], 8 → [2, 8], 3 → [3].
    """
    levels = [N]
    while -(-levels[-1] // factor) >= coarsest:
        levels.append(-(-levels[-1] // factor))
    return levels[::-1]


def resample(mesh_from: HermiteMesh, C: np.ndarray, mesh_to: HermiteMesh) -> np.ndarray:
    """Coefficients on ``mesh_to`` taking q, q̇ (, q̈) of the trajectory (mesh_from, C) at its nodes; (N+1, m, n)."""
    t = mesh_to.nodes
    return np.stack([mesh_from.evaluate(C, t, r) for r in range(mesh_to.m)], axis=1)


def plan(system: System, mesh: HermiteMesh, q0, dq0, q1, dq1, *, cost: str = "covariant", method: str = "pr-cg",
         tol: float = 1e-10, max_iter: int = 5000, C_init: np.ndarray | None = None, G: int | None = None,
         precondition: bool = True, continuation: bool = True,
         callback: Callable[[IterLog], None] | None = None, limits: JointLimits | None = None) -> PlanResult:
    """Solve the optimal-control problem on ``mesh`` from the minimum-jerk guess (or ``C_init``).

    Coarse to fine (``continuation``, unless ``C_init`` is given): the problem is first solved on
    ⌈N/16⌉, ⌈N/4⌉, … elements to a relative tolerance max(tol, 1e-6), each solution resampled at
    the next mesh's nodes as its starting point; most iterations then happen where an evaluation
    is cheap, and the fine mesh needs a few Newton steps. After convergence on the fine mesh the
    cost is recomputed with 4 more Gauss points per element; while it changes by more than 1e-12
    relative (and by more than the rounding level of J), G grows by 4 and the solve continues.

    With ``limits`` (a ``JointLimits`` with at least one finite bound) every level is solved within
    the limits by ``hoc_cli.constraints.enforce`` (an augmented Lagrangian around the same inner
    minimiser); the working set of limits found binding carries over from level to level.
    """
    start = time.perf_counter()
    totals = {"it": 0, "ev": 0, "pre": 0, "restarts": 0}
    history: list[IterLog] = []

    def solve(problem: ControlProblem, x0: np.ndarray, tol_level: float) -> OptimizeResult:
        failures: list[NumericalError] = []

        def evaluate(x: np.ndarray):
            try:
                ev = problem.evaluate(x)
            except NumericalError as exc:  # NaN/inf cost or singular M at a trial point: the line search steps back
                failures.append(exc)
                return math.inf, np.full(x.shape, np.nan), None
            return ev.J, ev.grad, ev

        def report(log: IterLog) -> None:  # cumulative counts across levels, tagged with the level's N
            if callback is not None:
                callback(dataclasses.replace(log, iteration=totals["it"] + log.iteration,
                                             n_evals=totals["ev"] + log.n_evals, level=problem.mesh.N))

        # With limit penalties the objective is only once differentiable (its curvature jumps where a
        # row becomes active): Newton steps (β = 0) and a loose curvature condition accept more unit
        # steps there (measured: 20-25 % fewer evaluations on lbr7_swing; docs/limits.md).
        penalized = isinstance(problem, PenalizedProblem) and precondition
        res = minimize(evaluate, x0, precondition=problem.newton if precondition else None,
                       method="newton" if penalized else method, c2=0.9 if penalized else 0.1,
                       tol=tol_level, max_iter=max(max_iter - totals["it"], 0), callback=report,
                       noise=lambda ev: ev.noise)
        if res.status is Status.NOT_FINITE and res.iterations == 0 and failures:
            raise failures[0]  # the starting trajectory itself cannot be evaluated
        totals["it"] += res.iterations
        totals["ev"] += res.n_evals
        totals["pre"] += res.n_precond
        totals["restarts"] += res.restarts
        history.extend(dataclasses.replace(h, iteration=h.iteration + totals["it"] - res.iterations,
                                           level=problem.mesh.N) for h in res.history)
        return res

    limited = limits is not None and limits.any
    carry: dict = {"working": None}

    def solve_level(problem: ControlProblem, x0: np.ndarray, tol_level: float):
        """(inner result with the plan's x, J without penalty, EnforceResult or None) of one level."""
        if not limited:
            res = solve(problem, x0, tol_level)
            return res, res.fun, None
        er = enforce(problem, system, limits, x0, tol_level, solve, working=carry["working"])
        carry["working"] = er.working
        return dataclasses.replace(er.inner, x=er.x), er.J, er

    if C_init is None and continuation and precondition:
        coarse_mesh, C_coarse = None, None
        for N in continuation_levels(mesh.N)[:-1]:
            level = HermiteMesh(mesh.order, mesh.T, N)
            problem = ControlProblem(system, level, q0, dq0, q1, dq1, cost=cost, G=G)
            x0 = problem.initial_guess() if C_coarse is None else problem.layout.pack(resample(coarse_mesh, C_coarse, level))
            res, _, _ = solve_level(problem, x0, max(tol, 1e-6))
            coarse_mesh, C_coarse = level, problem.coefficients(res.x)
        if coarse_mesh is not None:
            C_init = resample(coarse_mesh, C_coarse, mesh)

    while True:
        problem = ControlProblem(system, mesh, q0, dq0, q1, dq1, cost=cost, G=G)
        x0 = problem.initial_guess() if C_init is None else problem.layout.pack(C_init)
        res, J, er = solve_level(problem, x0, tol)
        C = problem.coefficients(res.x)
        J4 = _cost_with(system, mesh, problem.boundary, cost, problem.G + 4, C)
        change = abs(J4 - J) / max(abs(J4), 1e-300)
        noise = problem.last.noise if problem.last is not None else 0.0
        resolved = change <= QUADRATURE_RTOL or abs(J4 - J) <= 4 * noise  # else: truncation, refine
        if resolved or not res.converged or problem.G >= 32:
            break
        G, C_init = problem.G + 4, C
    res = dataclasses.replace(res, iterations=totals["it"], n_evals=totals["ev"], n_precond=totals["pre"],
                              restarts=totals["restarts"], history=tuple(history))
    return PlanResult(mesh=mesh, coeffs=C, J=J, optimizer=res, G=problem.G, quadrature_change=change,
                      wall_time_s=time.perf_counter() - start, problem=problem, limits=er)
