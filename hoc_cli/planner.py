"""Plan: minimise I(q_h) over the free Hermite coefficients and check the quadrature.

``plan`` ties ``ControlProblem`` (cost, gradient, Newton matrix) to the optimiser
(preconditioned PR+ CG by default) and returns a ``PlanResult``. Pure maths: no I/O.

Continuation levels nest: each coarse level's element count divides the next, so the next level
starts from a trajectory its own space holds exactly (``resample`` is then exact) and J does not
rise from level to level. Above 16 elements an even N is reached through N/2, solved as a plan
of its own: the plan at 2N starts from the plan at N, and J(2N) <= J(N) up to the solver
tolerance (one optimum followed across meshes).
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from hoc_cli.constraints import EnforceResult, JointLimits, enforce
from hoc_cli.constraints.auglag import Penalized
from hoc_cli.elements import HermiteMesh
from hoc_cli.errors import NumericalError
from hoc_cli.optimize import IterLog, OptimizeResult, Status, minimize
from hoc_cli.problem import ControlProblem, default_gauss_points
from hoc_cli.system import System

QUADRATURE_RTOL = 1e-12
#: outer (augmented-Lagrangian) iterations at a coarse level of the continuation: it only has to give
#: the next level a start near the limited optimum (measured: 6 halves the torque-cost reach's time)
COARSE_MAX_OUTER = 6
BASE_LEVEL = 16  # above this, an even N is planned as the plan at N/2 refined once
#: with a ``constraint`` (collision) the full levels start at the default Gauss points plus this many: every
#: Panda plan of benchmarks/bench_collision.py failed the quadrature check at the default and was solved again,
#: a whole outer loop with its certificate
CONSTRAINT_EXTRA_G = 4
COARSE_TOL = 1e-6  # relative tolerance of the coarse continuation levels (at least the plan's tol)


@dataclass(frozen=True)
class Level:
    """One level of a plan's continuation: N elements, J at its end, and whether it was solved to
    the plan's tolerance with the quadrature check (``full``) or to ``COARSE_TOL`` only.
    """

    N: int
    J: float
    full: bool


@dataclass(eq=False)
class PlanResult:
    """The optimal coefficients and how they were found.

    coeffs : (N+1, m, n) Hermite coefficients; J : cost at the solution;
    G : Gauss points per element used; quadrature_change : |J(G+4) − J(G)| / |J| at the solution;
    wall_time_s : the solve alone [s]; levels : the continuation levels solved, coarse to fine;
    coarser : the plan on N/2 elements this one was refined from (full levels only), else None.
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
    levels: tuple[Level, ...] = ()
    coarser: PlanResult | None = None
    constraint: object | None = None  # the outcome of ``plan``'s ``constraint`` on this level (status, message, …)

    @property
    def converged(self) -> bool:
        if self.constraint is not None and self.constraint.status != "converged":
            return False
        if self.limits is not None:
            return self.limits.status == "converged"
        return self.optimizer.converged


def _cost_with(system: System, mesh: HermiteMesh, boundary, cost: str, G: int, C: np.ndarray) -> float:
    p = ControlProblem(system, mesh, *boundary, cost=cost, G=G)
    return p.value(p.layout.pack(C))


def full_levels(N: int) -> list[int]:
    """The levels solved as plans of their own: N, N/2, N/4, … while above ``BASE_LEVEL`` and even; coarse to fine.

    E.g. 64 → [16, 32, 64], 48 → [12, 24, 48], 16 → [16], 36 → [9, 18, 36], 17 → [17].
    """
    levels = [N]
    while levels[-1] > BASE_LEVEL and levels[-1] % 2 == 0:
        levels.append(levels[-1] // 2)
    return levels[::-1]


def coarse_levels(N: int, factor: int = 4, coarsest: int = 2) -> list[int]:
    """Coarse levels below N, each dividing the next: the largest divisor of N in [coarsest, ⌈N/factor⌉], repeatedly.

    When N has no such divisor (N prime), ⌈N/factor⌉ is used (as before nesting; its trajectory is
    then interpolated into the next level, not represented exactly). E.g. 16 → [4], 36 → [3, 9],
    8 → [2], 10 → [2], 3 → [], 17 → [2, 5].
    """
    levels = [N]
    while True:
        cap = -(-levels[-1] // factor)
        if cap < coarsest:
            break
        d = next((d for d in range(cap, coarsest - 1, -1) if levels[-1] % d == 0), cap)
        levels.append(d)
    return levels[:0:-1]


def continuation_levels(N: int) -> list[int]:
    """Every level of the plan on N elements, coarse to fine: ``coarse_levels`` of the base, then ``full_levels``.

    E.g. 16 → [4, 16], 8 → [2, 8], 32 → [4, 16, 32], 64 → [4, 16, 32, 64], 36 → [3, 9, 18, 36].
    """
    full = full_levels(N)
    return coarse_levels(full[0]) + full


def resample(mesh_from: HermiteMesh, C: np.ndarray, mesh_to: HermiteMesh) -> np.ndarray:
    """Coefficients on ``mesh_to`` taking q, q̇ (, q̈) of the trajectory (mesh_from, C) at its nodes; (N+1, m, n).

    Exact (the same piecewise polynomial) when ``mesh_to.N`` is a multiple of ``mesh_from.N``.
    """
    t = mesh_to.nodes
    return np.stack([mesh_from.evaluate(C, t, r) for r in range(mesh_to.m)], axis=1)


def _first_step(problem) -> Callable | None:
    """The Newton iteration's first trial step (``collision.step.model_step``: the step's model with the rows it
    would activate, the collision rows' and the joint limits') when ``problem`` (a ControlProblem, or
    ``Penalized`` layers round one) has terms with rows (``step_rows``: the collision constraint), else None
    (the unit step).
    """
    from hoc_cli.constraints.penalty import LimitTerms

    terms, base = [], problem
    while True:
        terms.extend(getattr(base, "terms", ()))
        if not isinstance(base, Penalized):
            break
        base = base.base
    rows = [t for t in terms if hasattr(t, "step_rows")]
    if not rows:
        return None
    limits = [t.terms for t in terms if isinstance(getattr(t, "terms", None), LimitTerms)]
    from hoc_cli.collision.step import limit_rows, model_step

    def first(ev, d: np.ndarray, slope: float) -> float:
        C = base.coefficients(ev.x)
        dC = base.layout.unpack(d, np.zeros_like(C))
        got = [t.step_rows(C, dC) for t in rows] + [limit_rows(t, C, dC) for t in limits]
        return model_step(slope, *(np.concatenate([r[i] for r in got]) for i in range(3)))
    return first


class _Session:
    """The solves of one plan: iteration counts and history across levels, the limits' working set."""

    def __init__(self, system: System, boundary, *, cost: str, method: str, max_iter: int, precondition: bool,
                 callback: Callable[[IterLog], None] | None, limits: JointLimits | None,
                 working: np.ndarray | None, constraint=None, constraint_warm=None) -> None:
        self.system, self.boundary, self.cost, self.method = system, boundary, cost, method
        self.max_iter, self.precondition, self.callback = max_iter, precondition, callback
        self.limits = limits if limits is not None and limits.any else None
        self.working = working
        self.duals = None  # the last converged level's multipliers (``Duals``): the next solve's warm start
        self.constraint = constraint  # an outer loop of its own around each level's solve (``plan``)
        self.constraint_warm = constraint_warm  # ... and what it hands to the next level
        self.outcome = None  # ... and its outcome on the last level
        self.spent = 0  # iterations not counted against max_iter (each of the constraint's inner solves has its own)
        self.totals = {"it": 0, "ev": 0, "pre": 0, "restarts": 0}
        self.history: list[IterLog] = []
        self.levels: list[Level] = []
        self.current_N = 0
        # the SQP skips the first solve on a new mesh after the previous mesh's SQP handed over, crawled
        # (or was skipped): far from a limited optimum whose Newton matrix is strongly indefinite (torque
        # cost) it fails again, and where it crawled it crawls again, at the cost of its attempt; a
        # re-solve on the same mesh tries it again
        self.sqp_mesh, self.sqp_failed = 0, False

    def solve(self, problem, x0: np.ndarray, tol_level: float) -> OptimizeResult:
        """The unconstrained minimiser on ``problem`` from x0 (the inner solve of ``enforce`` too)."""
        failures: list[NumericalError] = []
        totals, callback = self.totals, self.callback

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

        # With limit (or other: ``ControlProblem.terms``) penalties the objective is only once differentiable (its curvature jumps where a
        # row becomes active): Newton steps (β = 0) and a loose curvature condition accept more unit
        # steps there (measured: 20-25 % fewer evaluations on lbr7_swing; docs/limits.md).
        penalized = self.precondition and (isinstance(problem, Penalized) or bool(getattr(problem, "terms", ())))
        res = minimize(evaluate, x0, precondition=problem.newton if self.precondition else None,
                       method="newton" if penalized else self.method, c2=0.9 if penalized else 0.1,
                       tol=tol_level, max_iter=max(self.max_iter - totals["it"] + self.spent, 0),
                       callback=report, noise=lambda ev: ev.noise, first_step=_first_step(problem))
        if res.status is Status.NOT_FINITE and res.iterations == 0 and failures:
            raise failures[0]  # the starting trajectory itself cannot be evaluated
        totals["it"] += res.iterations
        totals["ev"] += res.n_evals
        totals["pre"] += res.n_precond
        totals["restarts"] += res.restarts
        self.history.extend(dataclasses.replace(h, iteration=h.iteration + totals["it"] - res.iterations,
                                                level=problem.mesh.N) for h in res.history)
        return res

    def record(self, res: OptimizeResult) -> None:
        """Add a solve made outside ``solve`` (the limits' SQP) to the totals and history."""
        totals = self.totals
        for h in res.history:
            log = dataclasses.replace(h, iteration=h.iteration + totals["it"], n_evals=h.n_evals + totals["ev"],
                                      level=self.current_N)
            self.history.append(log)
            if self.callback is not None:
                self.callback(log)
        totals["it"] += res.iterations
        totals["ev"] += res.n_evals
        totals["pre"] += res.n_precond

    def solve_level(self, problem: ControlProblem, x0: np.ndarray, tol_level: float, max_outer: int = 40,
                    full: bool = True):
        """(inner result with the plan's x, J without penalty, EnforceResult or None) of one level."""
        if self.constraint is None:
            return self._limited(problem, x0, tol_level, max_outer)
        def minimize(p, x, t):
            self.spent = self.totals["it"]
            self.current_N = p.mesh.N
            return self.solve(p, x, t)

        res, J, er, self.outcome = self.constraint.solve(problem, x0, tol_level, minimize, warm=self.constraint_warm,
                                                         full=full, system=self.system, limits=self.limits,
                                                         working=self.working)
        self.constraint_warm = self.outcome.warm
        if er is not None:
            self.working = er.working
        return res, J, er

    def _limited(self, problem: ControlProblem, x0: np.ndarray, tol_level: float, max_outer: int):
        """``solve_level`` without ``constraint``: the plain solve, or within the joint limits."""
        self.current_N = problem.mesh.N
        if self.limits is None:
            res = self.solve(problem, x0, tol_level)
            return res, res.fun, None
        use_sqp = self.precondition and self.constraint is None and not (self.sqp_failed and problem.mesh.N != self.sqp_mesh)
        er = enforce(problem, self.system, self.limits, x0, tol_level, self.solve, working=self.working,
                     max_outer=max_outer, use_sqp=use_sqp, record=self.record, duals=self.duals)
        self.working = er.working
        self.duals = er.duals() if er.status == "converged" else None  # only a converged level's multipliers carry over
        failed = er.sqp in ("handed_over", "crawled") or (self.precondition and not use_sqp)
        self.sqp_mesh, self.sqp_failed = problem.mesh.N, failed
        return dataclasses.replace(er.inner, x=er.x), er.J, er

    def problem(self, mesh: HermiteMesh, G: int | None) -> ControlProblem:
        return ControlProblem(self.system, mesh, *self.boundary, cost=self.cost, G=G)

    def coarse(self, mesh: HermiteMesh, C_start: np.ndarray | None, tol: float, G: int | None) -> np.ndarray:
        """One coarse level to max(tol, ``COARSE_TOL``); returns its coefficients."""
        problem = self.problem(mesh, G)
        x0 = problem.initial_guess() if C_start is None else problem.layout.pack(C_start)
        res, J, _ = self.solve_level(problem, x0, max(tol, COARSE_TOL), max_outer=COARSE_MAX_OUTER, full=False)
        self.levels.append(Level(mesh.N, float(J), False))
        return problem.coefficients(res.x)

    def full(self, mesh: HermiteMesh, C_start: np.ndarray | None, tol: float, G: int | None,
             start: float, coarser: PlanResult | None) -> PlanResult:
        """One level to ``tol``; while 4 more Gauss points change J by more than 1e-12 relative
        (and by more than the rounding level of J), G grows by 4 and the solve continues.
        """
        while True:
            problem = self.problem(mesh, G)
            x0 = problem.initial_guess() if C_start is None else problem.layout.pack(C_start)
            res, J, er = self.solve_level(problem, x0, tol)
            C = problem.coefficients(res.x)
            J4 = _cost_with(self.system, mesh, problem.boundary, self.cost, problem.G + 4, C)
            change = abs(J4 - J) / max(abs(J4), 1e-300)
            noise = problem.last.noise if problem.last is not None else 0.0
            resolved = change <= QUADRATURE_RTOL or abs(J4 - J) <= 4 * noise  # else: truncation, refine
            failed = self.outcome is not None and self.outcome.status != "converged"  # the constraint's outer loop
            if resolved or not res.converged or failed or problem.G >= 32:
                break
            G, C_start = problem.G + 4, C
        self.levels.append(Level(mesh.N, float(J), True))
        t = self.totals
        res = dataclasses.replace(res, iterations=t["it"], n_evals=t["ev"], n_precond=t["pre"],
                                  restarts=t["restarts"], history=tuple(self.history))
        return PlanResult(mesh=mesh, coeffs=C, J=J, optimizer=res, G=problem.G, quadrature_change=change,
                          wall_time_s=time.perf_counter() - start, problem=problem, limits=er,
                          levels=tuple(self.levels), coarser=coarser, constraint=self.outcome)


def plan(system: System, mesh: HermiteMesh, q0, dq0, q1, dq1, *, cost: str = "covariant", method: str = "pr-cg",
         tol: float = 1e-10, max_iter: int = 5000, C_init: np.ndarray | None = None, G: int | None = None,
         precondition: bool = True, continuation: bool = True,
         callback: Callable[[IterLog], None] | None = None, limits: JointLimits | None = None,
         working: np.ndarray | None = None, constraint=None, constraint_warm=None) -> PlanResult:
    """Solve the optimal-control problem on ``mesh`` from the minimum-jerk guess (or ``C_init``).

    Coarse to fine (``continuation``, unless ``C_init`` is given), over ``continuation_levels(N)``:
    the coarse levels (about N/16, N/4 of the base level, each dividing the next) are solved to a
    relative tolerance max(tol, 1e-6), each solution resampled exactly at the next mesh's nodes as
    its starting point; most iterations then happen where an evaluation is cheap. The full levels
    (``full_levels``: the base level, then doubling to N) are each solved to ``tol``, with the
    quadrature check: after convergence the cost is recomputed with 4 more Gauss points per
    element; while it changes by more than 1e-12 relative (and by more than the rounding level of
    J), G grows by 4 and the solve continues. A full level's plan is kept in ``coarser`` of the next.

    With ``limits`` (a ``JointLimits`` with at least one finite bound) every level is solved within
    the limits by ``hoc_cli.constraints.enforce`` (the unconstrained solve, then an SQP on the
    kinematic rows, an augmented Lagrangian for effort); the working set of limits found binding carries over from level to level, and
    starts from ``working`` (K, n) bool when given (e.g. a coarser plan's); so do a converged level's
    multipliers (``Duals``, prolonged onto the next mesh: the warm start of its SQP, and of the
    augmented Lagrangian on the same mesh).

    With ``constraint`` (e.g. ``hoc_cli.collision.enforce.CollisionConstraint``) every level's solve
    runs inside its outer loop: ``constraint.solve(problem, x0, tol, minimize, warm=…, full=…, system=…,
    limits=…, working=…)`` returns (result, J without its terms, limits outcome, outcome); ``minimize`` is
    the unconstrained solve, the joint limits are terms of the constraint's own loop, the outcome's
    ``warm`` starts the next level (the first from ``constraint_warm`` when given: e.g. the plan of a nearby T's,
    stretched to this T), and the finest level's outcome is ``PlanResult.constraint``. Without ``G`` its
    full levels start at ``CONSTRAINT_EXTRA_G`` more Gauss points than the default (the quadrature check goes on).
    """
    start = time.perf_counter()
    session = _Session(system, (q0, dq0, q1, dq1), cost=cost, method=method, max_iter=max_iter,
                       precondition=precondition, callback=callback, limits=limits, working=working,
                       constraint=constraint, constraint_warm=constraint_warm)
    full = [mesh.N]
    prev_mesh, C_prev = None, None
    if C_init is None and continuation and precondition:
        full = full_levels(mesh.N)
        for N in coarse_levels(full[0]):
            level = HermiteMesh(mesh.order, mesh.T, N)
            C_start = None if C_prev is None else resample(prev_mesh, C_prev, level)
            prev_mesh, C_prev = level, session.coarse(level, C_start, tol, G)
    result = None
    if constraint is not None and G is None:
        G = default_gauss_points(mesh.order) + CONSTRAINT_EXTRA_G
    for N in full:
        level = mesh if N == mesh.N else HermiteMesh(mesh.order, mesh.T, N)
        C_start = C_init if C_prev is None else resample(prev_mesh, C_prev, level)
        result = session.full(level, C_start, tol, G, start, result)
        prev_mesh, C_prev, G = level, result.coeffs, result.G
    assert result is not None
    return result
