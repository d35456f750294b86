"""Plans with goals beyond a joint state: a link pose at T (free final q), via points, a moving target.

``Goals`` says what is fixed and what is imposed: the final joint state (``q1``, ``dq1``) or a
``FrameResidual`` at T with the final q (and q̇ when it is free) released from the ``Layout``;
via points are ``GoalPoint`` rows, except joint vias whose time falls on a mesh node, which are
pinned in the ``Layout`` (met exactly; ``hoc_cli.goals.mesh`` builds meshes with every via time a
node, and the coarse levels of a non-uniform mesh keep them when they have the elements). Rows that
are not pinned are the term (``GoalTerm``) of the augmented Lagrangian ``constraints.auglag.minimize`` around the same
inner minimiser; with limits given, the limits' ``enforce`` runs that loop with the limits as its second term
(``GoalTerm``'s Φ is part of its base problem). Coarse to fine as
``hoc_cli.planner.plan``; the multipliers carry from level to level (the rows are fractions of T).
Pure maths: no I/O.
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from hoc_cli.constraints import auglag, enforce
from hoc_cli.constraints.auglag import RHO_RANGE, Measure, Penalized
from hoc_cli.elements import HermiteMesh
from hoc_cli.errors import NumericalError
from hoc_cli.goals.mesh import node_index, via_mesh
from hoc_cli.goals.residuals import FrameResidual, JointResidual
from hoc_cli.goals.terms import GoalPoint, GoalTerms
from hoc_cli.optimize import IterLog, OptimizeResult, Status, minimize
from hoc_cli.optimize.blas import one_thread
from hoc_cli.planner import QUADRATURE_RTOL, PlanResult, continuation_levels, resample
from hoc_cli.problem import ControlProblem, Layout, minimum_jerk_guess

EQ_TOL = 1e-12  # the outer loop stops when every goal row is met to this (m, rad, m/s)
EQ_COARSE = 1e-6  # … on the coarse levels of the continuation
EQ_ACCEPT = 1e-9  # a plan whose rows are met to this counts as converged
RHO0 = 10.0  # ρ = 10·|J| of the initial guess per unit c²: larger starts make curved rows stall the line search


@dataclass(frozen=True, eq=False)
class Goals:
    """What the plan must meet besides x0.

    q1, dq1 : (n,) a joint goal at T, or None with ``final`` a ``FrameResidual`` at T;
    final_dq : "zero" (rest at T, the default) or "free" (implied by ``final.match_velocity``);
    vias : ``GoalPoint`` rows at fractions s of T; q1_guess, dq1_guess : (n,) the final state of
    the initial trajectory when the final q is free (e.g. ``inverse_kinematics``).
    """

    q1: np.ndarray | None = None
    dq1: np.ndarray | None = None
    final: FrameResidual | None = None
    final_dq: str = "zero"
    vias: tuple[GoalPoint, ...] = ()
    q1_guess: np.ndarray | None = None
    dq1_guess: np.ndarray | None = None

    @property
    def free_dq1(self) -> bool:
        return self.final is not None and (self.final_dq == "free" or self.final.match_velocity)


def node_of(s: float, N: int, tol: float = 1e-9) -> int | None:
    """The interior node p (0 < p < N) at fraction s of a uniform mesh of N elements, or None when s·N is
    not an integer (any mesh: ``hoc_cli.goals.mesh.node_index``).
    """
    p = round(s * N)
    return p if abs(s * N - p) <= tol and 0 < p < N else None


class GoalProblem(ControlProblem):
    """A ``ControlProblem`` with the final q (and q̇) free for a link goal and joint vias on nodes pinned.

    ``points`` lists the rows left to the augmented Lagrangian (the link goal at s = 1, the vias
    off the nodes and every link via).
    """

    def __init__(self, system, mesh: HermiteMesh, q0, dq0, goals: Goals, cost: str = "covariant",
                 G: int | None = None) -> None:
        n = system.n
        pinned, points, values = [], [], []
        for gp in goals.vias:
            p = node_index(gp.s, mesh) if isinstance(gp.residual, JointResidual) else None
            if p is None:
                points.append(gp)
                continue
            pinned.append((p, 0))
            values.append((p, 0, gp.residual.q))
            if gp.residual.dq is not None:
                pinned.append((p, 1))
                values.append((p, 1, gp.residual.dq))
        if goals.final is not None:
            points.append(GoalPoint(1.0, goals.final, "x1"))
            q1 = goals.q1_guess if goals.q1_guess is not None else np.asarray(q0, float)
            dq1 = np.zeros(n) if goals.dq1_guess is None or not goals.free_dq1 else goals.dq1_guess
        else:
            q1, dq1 = goals.q1, goals.dq1
        layout = Layout.build(mesh, n, free_q1=goals.final is not None, free_dq1=goals.free_dq1,
                              pinned=tuple(pinned))
        super().__init__(system, mesh, q0, dq0, q1, dq1, cost=cost, G=G, layout=layout)
        for p, d, v in values:
            self.C_fixed[p, d] = v
        self.goals, self.points = goals, points

    def initial_guess(self) -> np.ndarray:
        C = minimum_jerk_guess(self.mesh, *self.boundary)
        return self.layout.pack(C)

    def with_quadrature(self, G: int) -> "GoalProblem":
        q0, dq0 = self.boundary[:2]
        return GoalProblem(self.system, self.mesh, q0, dq0, self.goals, cost=self.cost, G=G)


class GoalTerm:
    """The goal rows as the augmented Lagrangian's term (``auglag.Term``): equality rows, their multipliers and ρ in
    ``terms`` (``GoalTerms``, replaced at every update), met to ``eq`` when the inner solves run at ``tol_level`` and to
    ``max(eq, EQ_COARSE)`` when looser (a collision loop's early iterations: the stopping test of a loose solve
    cannot see a smaller violation, and ρ would grow without end); ρ at most ``rho_cap``, never called infeasible
    (a goal missed is the plan's ``violation``).

    Its Φ is part of the level's problem (``Penalized(problem, (term,))``, or the problem's ``terms`` under a
    ``constraint``): the limits' and a constraint's loops see it in their base problem.
    """

    rho0 = None
    stop_on_failure = False
    imposed = True

    def __init__(self, terms: GoalTerms, eq: float, tol_level: float, rho_cap: float) -> None:
        self.terms, self.eq, self.tol_level, self.rho_cap = terms, eq, tol_level, rho_cap

    @property
    def rho(self) -> float:
        return self.terms.rho

    @rho.setter
    def rho(self, value: float) -> None:
        self.terms = dataclasses.replace(self.terms, rho=value)

    def evaluate(self, C: np.ndarray, grad: bool = True) -> tuple[float, np.ndarray | None]:
        return self.terms.evaluate(C, grad=grad)

    def newton_blocks(self, C: np.ndarray) -> np.ndarray:
        return self.terms.newton_blocks(C)

    def begin(self, base, x: np.ndarray) -> None:
        pass

    def problem(self, base):
        return base

    def measure(self, base, x: np.ndarray, res, tol: float) -> Measure:
        """The worst |c| (m, rad, m/s); met after a converged inner solve with every row within the tolerance."""
        violation = self.terms.violation(base.coefficients(x))
        within = violation <= (self.eq if tol <= self.tol_level else max(self.eq, EQ_COARSE))
        return Measure(violation, within, within and res.converged)

    def update(self, base, x: np.ndarray, measure: Measure) -> None:
        self.terms = dataclasses.replace(self.terms, lam=self.terms.multipliers(base.coefficients(x)))

    def feasible_start(self, base, x: np.ndarray) -> bool:
        return self.terms.violation(base.coefficients(x)) <= self.eq


@dataclass(eq=False)
class GoalResult(PlanResult):
    """A ``PlanResult`` with the goal rows: ``terms`` (their final multipliers), ``violation`` max |c|;
    ``newton_factor``: a replan's last Newton matrix (dense upper Cholesky factor on the free coefficients),
    the first step of the next replan from this plan (``hoc_cli.goals.replan_qp``); ``newton_hessians``: the cost's
    sample Hessians it was made of (``replan_qp._newton``'s pair).
    """

    terms: GoalTerms | None = None
    violation: float = 0.0
    outer_iterations: int = 0
    goals: Goals = field(default_factory=Goals)
    newton_factor: np.ndarray | None = field(default=None, repr=False)
    newton_hessians: tuple | None = field(default=None, repr=False)

    @property
    def converged(self) -> bool:
        return PlanResult.converged.fget(self) and self.violation <= EQ_ACCEPT


def _level_mesh(mesh: HermiteMesh, N: int, goals: Goals) -> HermiteMesh:
    """A coarse level of ``mesh`` on N elements: uniform, or for a non-uniform mesh with the via times as
    nodes when N has room for them (else uniform: the vias are rows there).
    """
    if mesh.uniform:
        return HermiteMesh(mesh.order, mesh.T, N)
    try:
        return via_mesh(mesh.order, mesh.T, N, [gp.s for gp in goals.vias])
    except ValueError:
        return HermiteMesh(mesh.order, mesh.T, N)


@one_thread()  # one BLAS thread while solving (hoc_cli/optimize/blas.py)
def plan_goals(system, mesh: HermiteMesh, q0, dq0, goals: Goals, *, cost: str = "covariant",
               method: str = "pr-cg", tol: float = 1e-10, max_iter: int = 5000, C_init: np.ndarray | None = None,
               G: int | None = None, limits=None, continuation: bool = True,
               callback: Callable[[IterLog], None] | None = None, terms: GoalTerms | None = None,
               eq_tol: float = EQ_TOL, max_outer: int = 30, constraint=None, constraint_warm=None,
               working: np.ndarray | None = None) -> GoalResult:
    """Solve the optimal-control problem with ``goals`` on ``mesh`` (see the module docstring).

    ``terms`` warm-starts the multipliers and ρ (e.g. from the plan of a nearby T; ρ <= 0: the
    default ρ = 10·|J| of the starting trajectory). The outer
    loop stops when every row is met to ``eq_tol`` after a converged inner solve; ρ grows ×10
    whenever max |c| did not fall to a quarter.

    With ``constraint`` (e.g. ``hoc_cli.collision.enforce.CollisionConstraint``, as ``hoc_cli.planner.plan`` takes
    it) every level's solve runs inside its outer loop, the goal rows' loop being its inner minimisation (the rows
    stay in the problem's ``terms`` beside the constraint's: its polish and limits' rounds see them); the joint
    limits are then terms of the constraint's loop, and the finest level's outcome is ``GoalResult.constraint``.
    ``constraint_warm``: the constraint's multipliers for the first level's loop (its ``warm``, e.g. the plan of a
    nearby T's, stretched to this T), with ``working`` (K, n) the joint limits' pairs imposed from the start.
    """
    start = time.perf_counter()
    totals = {"it": 0, "ev": 0, "pre": 0, "restarts": 0, "outer": 0}
    history: list[IterLog] = []
    limited = limits is not None and limits.any
    carry: dict = {"working": working, "spent": 0, "warm": constraint_warm, "outcome": None}

    def inner(problem, x0: np.ndarray, tol_level: float) -> OptimizeResult:
        failures: list[NumericalError] = []

        def evaluate(x):
            try:
                ev = problem.evaluate(x)
            except NumericalError as exc:
                failures.append(exc)
                return math.inf, np.full(x.shape, np.nan), None
            return ev.J, ev.grad, ev

        def report(log: IterLog) -> None:
            if callback is not None:
                callback(dataclasses.replace(log, iteration=totals["it"] + log.iteration,
                                             n_evals=totals["ev"] + log.n_evals, level=problem.mesh.N))

        def newton(ev):
            try:
                return problem.newton(ev)
            except ValueError as exc:  # scipy's banded factorisation of a matrix beyond the floating-point range
                if "infs or NaNs" not in str(exc):
                    raise
                raise NumericalError(f"the Newton matrix is not finite (cost {ev.J:.3g}): the goal plan diverged") from exc

        res = minimize(evaluate, x0, precondition=newton, method=method, tol=tol_level,
                       max_iter=max(max_iter - totals["it"] + carry["spent"], 0), callback=report, noise=lambda ev: ev.noise)
        if res.status is Status.NOT_FINITE and res.iterations == 0 and failures:
            raise failures[0]
        for key, v in (("it", res.iterations), ("ev", res.n_evals), ("pre", res.n_precond), ("restarts", res.restarts)):
            totals[key] += v
        history.extend(dataclasses.replace(h, level=problem.mesh.N) for h in res.history)
        return res

    def solve_level(problem: GoalProblem, x: np.ndarray, tol_level: float, terms: GoalTerms, eq_level: float,
                    full: bool = True):
        """One mesh: the augmented Lagrangian around ``inner`` with the goal rows (``term``) and, when limited, the limits
        as its terms (``enforce``); under a ``constraint``, the goal rows' loop is its inner minimisation.
        """
        term = GoalTerm(terms.on(problem.mesh), eq_level, tol_level, rho_max) if problem.points else None
        pen = Penalized(problem, (term,)) if problem.points else problem

        def goal_inner(p, x: np.ndarray, tol_inner: float) -> OptimizeResult:
            """The goal rows' loop (``auglag.minimize``, at most ``max_outer`` inner solves); the result counts the
            iterations and evaluations of all its inner solves.
            """
            if term is None:
                totals["outer"] += 1
                return inner(p, x, tol_inner)
            out = auglag.minimize(p, (term,), x, tol_inner, inner, max_outer)
            totals["outer"] += out.outer
            return dataclasses.replace(out.res, x=out.x, iterations=out.iterations, n_evals=out.n_evals)

        er = None
        if constraint is not None:
            def each(p, x: np.ndarray, tol_inner: float) -> OptimizeResult:  # each inner solve has its own budget
                carry["spent"] = totals["it"]
                return goal_inner(p, x, tol_inner)

            problem.terms = (term,) if problem.points else ()
            try:
                res, _, er, carry["outcome"] = constraint.solve(
                    problem, x, tol_level, each, warm=carry["warm"], full=full, system=system,
                    limits=limits if limited else None, working=carry["working"])
            finally:
                problem.terms = ()
            carry["warm"] = carry["outcome"].warm
            if er is not None:
                carry["working"] = er.working
        elif limited:  # the goal rows and the limits: two terms of one augmented-Lagrangian loop
            def counted(p, x: np.ndarray, tol_inner: float) -> OptimizeResult:
                totals["outer"] += 1
                return inner(p, x, tol_inner)

            er = enforce(pen, system, limits, x, tol_level, counted, working=carry["working"],
                         duals=carry.pop("duals", None), terms=(term,) if problem.points else ())
            carry["working"] = er.working
            res = dataclasses.replace(er.inner, x=er.x)
        else:
            res = goal_inner(pen, x, tol_level)
        return res.x, res, er, term.terms if problem.points else terms

    def build(level: HermiteMesh, G_level: int | None) -> GoalProblem:
        return GoalProblem(system, level, q0, dq0, goals, cost=cost, G=G_level)

    probe = build(mesh, G)
    if terms is None or terms.rho <= 0:
        J0 = probe.value(probe.initial_guess() if C_init is None else probe.layout.pack(C_init))
        rho = RHO0 * max(abs(J0), 1e-6)
        if terms is None and C_init is not None and (probe.points or limited):
            # a plan (e.g. of another mesh): its goal multipliers and its limits' working set and multipliers, so
            # that the first inner solve does not leave its optimum (unconstrained, it would run to another one)
            lam, state = _warm_state(system, probe, C_init, limits if limited else None)
            terms = GoalTerms(mesh, probe.points, lam, rho) if probe.points else None
            if state is not None:
                carry["working"], carry["duals"] = state.working, state.penalty
        terms = GoalTerms.start(mesh, probe.points, rho) if terms is None else dataclasses.replace(terms, rho=rho)
    rho_max = RHO_RANGE * terms.rho  # the goal rows' ρ at most (``RHO_RANGE``)
    if C_init is None and continuation:
        coarse_mesh, C_coarse = None, None
        for N in continuation_levels(mesh.N)[:-1]:
            level = _level_mesh(mesh, N, goals)
            problem = build(level, G)
            x0 = problem.initial_guess() if C_coarse is None else problem.layout.pack(resample(coarse_mesh, C_coarse, level))
            x, _, _, terms = solve_level(problem, x0, max(tol, 1e-6), terms, max(eq_tol, EQ_COARSE), full=False)
            coarse_mesh, C_coarse = level, problem.coefficients(x)
        if coarse_mesh is not None:
            C_init = resample(coarse_mesh, C_coarse, mesh)
    while True:
        problem = build(mesh, G)
        x0 = problem.initial_guess() if C_init is None else problem.layout.pack(C_init)
        x, res, er, terms = solve_level(problem, x0, tol, terms, eq_tol)
        C = problem.coefficients(x)
        J = problem.value(x)
        J4 = problem.with_quadrature(problem.G + 4).value(x)
        change = abs(J4 - J) / max(abs(J4), 1e-300)
        noise = problem.last.noise if problem.last is not None else 0.0
        if change <= QUADRATURE_RTOL or abs(J4 - J) <= 4 * noise or not res.converged or problem.G >= 32:
            break
        G, C_init = problem.G + 4, C
    res = dataclasses.replace(res, iterations=totals["it"], n_evals=totals["ev"], n_precond=totals["pre"],
                              restarts=totals["restarts"], history=tuple(history))
    violation = terms.on(mesh).violation(C) if problem.points else 0.0
    return GoalResult(mesh=mesh, coeffs=C, J=J, optimizer=res, G=problem.G, quadrature_change=change,
                      wall_time_s=time.perf_counter() - start, problem=problem, limits=er, terms=terms,
                      violation=violation, outer_iterations=totals["outer"], goals=goals, constraint=carry["outcome"])


def _warm_state(system, problem: GoalProblem, C: np.ndarray, limits) -> tuple[list[np.ndarray], object]:
    """(the goal rows' multipliers λ, the limits' estimated state or None) at coefficients C (N+1, m, n) of a plan,
    by least squares on the stationarity ∇ₓJ + Dᵀλ + Σμ∇g = 0 over the goal rows and the limit rows near their bound
    (``hoc_cli.goals.warm.estimate_state``).
    """
    from hoc_cli.goals.warm import estimate_state

    x = problem.layout.pack(np.asarray(C, float))
    lam, state = estimate_state(system, problem, problem.coefficients(x), problem.evaluate(x).grad, limits)
    return [np.asarray(v, float) for v in lam], state


def _pose_rows(residual: FrameResidual, q: np.ndarray, T: float) -> tuple[np.ndarray, np.ndarray]:
    """IK rows: (p − p̄(T), vec(R − R̄)) (3 or 12,) and their Jacobian; smooth, zero only at the pose,
    and with a nonzero Jacobian even half a turn away (where any function of the angle is stationary).
    """
    from hoc_cli.dynamics import frame_jacobian
    from hoc_cli.goals.residuals import GENERATORS

    p, R = residual.pose(q)
    J = frame_jacobian(residual.model, q, residual.link)
    rows, jac = [p - residual.target(T)[0]], [J[:3]]
    if residual.orientation is not None:
        rows.append((R - residual.orientation).ravel())
        dR = np.einsum("kij,jl->kil", GENERATORS, R).reshape(3, 9)  # vec([e_k]× R)
        jac.append(dR.T @ J[3:])
    return np.concatenate(rows), np.vstack(jac)


def inverse_kinematics(residual: FrameResidual, q_seed, T: float, lower=None, upper=None,
                       max_iter: int = 200, tol: float = 1e-12) -> np.ndarray:
    """A joint position q (n,) with the link at the residual's pose at time T (position, orientation).

    Damped least squares (Levenberg-Marquardt with a fixed damping 1e-6·‖J‖²) on ``_pose_rows`` from
    ``q_seed``, at most 0.5 rad per step, clipped to [lower, upper]; returns the last iterate (check
    its residual: the pose may be out of reach).
    """
    q = np.array(q_seed, float)
    n = q.size
    lo = np.full(n, -np.inf) if lower is None else np.asarray(lower, float)
    hi = np.full(n, np.inf) if upper is None else np.asarray(upper, float)
    for _ in range(max_iter):
        c, J = _pose_rows(residual, q, T)
        if np.max(np.abs(c)) <= tol:
            break
        damping = 1e-6 * float(np.sum(J * J)) + 1e-12
        step = np.linalg.solve(J.T @ J + damping * np.eye(n), J.T @ c)
        scale = min(1.0, 0.5 / max(np.max(np.abs(step)), 1e-300))
        q = np.clip(q - scale * step, lo, hi)
    return q
