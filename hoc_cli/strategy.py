"""``hoc_cli.solve(problem, options, warm=None) -> Plan``: the one entry point, which chooses the solver for a problem.

Which solver runs when (docs/design.md, "Which solver runs when"):

| problem | solver |
| --- | --- |
| joint goal, fixed T, fixed N | ``planner.plan`` (coarse to fine; limits by the SQP / augmented Lagrangian), then |
|                              | the error estimate of J on 2N and N/2 elements; ``starts`` > 1: the best seeded start |
| joint goal, fixed T, ``N=None`` | ``accuracy.plan_auto``: refine until the estimate meets ``accuracy`` |
| link goal or vias, fixed T | with enforced limits ``goals.free_time_sqp.plan_fixed_time`` (SQP steps from the |
|                            | initial trajectory), else or when they fail ``goals.plan_goals``; every via a node |
| free T, joint goal | ``free_time.minimize_time`` over fixed-T solves (Brent on dJ*/dT) |
| free T with a link goal or vias | ``goals.free_time_sqp``: the plan at the guess, then Newton steps in (x, T) |
| free T with ``warm`` | ``goals.replan``: Newton steps from the earlier plan |
| free T with a collision constraint | ``free_time.minimize_time`` over fixed-T plans with it (``warm`` not used) |

The CLI (``hoc plan``) and ``hoc batch`` call this; so can any Python program (docs/api.md).
Errors are ``HocError`` subclasses naming the key at fault (no file: the caller adds it).
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from hoc_cli.elements import HermiteMesh
from hoc_cli.errors import HocError, TaskError
from hoc_cli.ocp.problem import Fixed, Free, OptimalControlProblem

ESTIMATE_MIN_ITER = 50  # the error estimate's iteration budget: the plan's own iterations, at least this
COLLISION_T_RTOL = 1e-5  # a free T with the collision constraint: |dJ/dT + weight| within this (relative), or the
# bracket this narrow (the fixed-T plans with the constraint are converged to their certificate, which leaves dJ*/dT
# uncertain by far more than the plain search's 1e-7: two-link around a ball, dJ/dT −1.00 against −0.84 from J*(T))
REACH_SAMPLES = 400  # the free-T span is checked for reach at this many T


class UnreachableGoal(HocError):
    """A link goal beyond the arm's reach at every admissible T: infeasible (exit 1, nothing solved)."""

    exit_code = 1


@dataclass(frozen=True)
class SolveOptions:
    """How to solve (the problem says what).

    method : "pr-cg" | "newton"; tol : relative stopping tolerance of the decrement; max_iter : per solve;
    starts, seed : multi-start (joint goals in a fixed T and N); estimate_error : the error estimate of J
    after a fixed-N plan; callback : called with each iteration's ``IterLog``; on_start : with each
    start's outcome; on_phase : with a short description of each phase ("estimating the error …");
    client : where the starts after the first run (``multistart.solve_starts``).
    """

    method: str = "pr-cg"
    tol: float = 1e-10
    max_iter: int = 5000
    starts: int = 1
    seed: int = 0
    estimate_error: bool = True
    callback: Callable | None = None
    on_start: Callable | None = None
    on_phase: Callable[[str], None] | None = None
    client: Any = None


@dataclass(frozen=True, eq=False)
class WarmStart:
    """An earlier plan: its mesh, coefficients C (N+1, m, n) and Gauss points per element (or None).

    With a fixed T its coefficients must be on the problem's mesh (``planner.resample``); with a free T
    the plan is the start of a warm replan from its own T.
    """

    mesh: HermiteMesh
    coeffs: np.ndarray
    G: int | None = None


@dataclass(frozen=True, eq=False)
class Plan:
    """The outcome of ``solve``.

    result : the ``PlanResult`` (mesh, coefficients, J, optimizer outcome, limits outcome);
    details : solver facts for the summary (a free T's ``dJ_dT``, ``T_bound``, … ; a replan's steps);
    error : the estimate of J's discretisation error (None where not made); auto : ``N: auto``'s
    ``AutoResult``; multi : a multi-start's ``MultiStartResult``; goals : the goal rows solved for;
    wall_time_s : the whole solve [s] (every start, mesh and T tried; the error estimate's own time is
    ``error.wall_time_s``).
    """

    result: Any
    details: dict = field(default_factory=dict)
    error: Any = None
    auto: Any = None
    multi: Any = None
    goals: Any = None
    wall_time_s: float = 0.0

    @property
    def mesh(self) -> HermiteMesh:
        return self.result.mesh

    @property
    def coeffs(self) -> np.ndarray:
        return self.result.coeffs

    @property
    def J(self) -> float:
        return self.result.J

    @property
    def T(self) -> float:
        return self.result.mesh.T

    @property
    def converged(self) -> bool:
        return self.result.converged


def solve(problem: OptimalControlProblem, options: SolveOptions | None = None,
          warm: WarmStart | None = None) -> Plan:
    """Plan ``problem`` (the module docstring says which solver runs)."""
    options = options or SolveOptions()
    if options.starts > 1 and (problem.has_goals or problem.N is None):
        raise TaskError("multi-start applies to joint goals in a fixed T and a fixed N", key="solver.starts")
    if problem.constraint is not None and (problem.N is None or options.starts > 1):
        raise TaskError("collision enforcement plans in a fixed N with one start (use "
                        "--collision check to plan without it and report the clearance)", key="collision.mode")
    from hoc_cli.optimize.blas import one_thread

    start = time.perf_counter()
    # one BLAS thread (hoc_cli/optimize/blas.py), also when numpy was loaded with more before hoc;
    # NaN and inf are detected and reported (exit 1), not warned about
    with one_thread(), np.errstate(all="ignore"):
        if problem.has_goals:
            plan = _solve_goals(problem, options, warm)
        elif problem.N is None:
            plan = _solve_auto(problem, options)
        else:
            plan = _solve_fixed(problem, options, warm)
    spent = time.perf_counter() - start
    if plan.error is not None and plan.auto is None:  # the fixed-N plan's estimate is timed on its own
        spent -= plan.error.wall_time_s
    return dataclasses.replace(plan, wall_time_s=spent)


def _common(problem: OptimalControlProblem, options: SolveOptions) -> dict:
    return {"cost": problem.cost, "method": options.method, "tol": options.tol, "max_iter": options.max_iter}


def _solve_fixed(problem: OptimalControlProblem, options: SolveOptions, warm: WarmStart | None) -> Plan:
    from hoc_cli.accuracy import estimate
    from hoc_cli.planner import plan

    mesh = HermiteMesh(problem.order, problem.T, problem.N)
    common = _common(problem, options) | {"limits": problem.limits}
    bc = (problem.q0, problem.dq0, problem.q1, problem.dq1)
    multi = None
    if options.starts <= 1:
        more = {} if problem.constraint is None else {"constraint": problem.constraint}
        result = plan(problem.system, mesh, *bc, C_init=None if warm is None else warm.coeffs,
                      callback=options.callback, **common, **more)
    else:
        from hoc_cli.multistart import solve_starts

        multi = solve_starts(problem.system, mesh, *bc, starts=options.starts, seed=options.seed,
                             client=options.client, on_start=options.on_start, **common)  # (a callback would travel to the workers)
        result = multi.best
    error = None
    if options.estimate_error and problem.constraint is None:  # the estimate's solves do not take the constraint
        # the estimate's solves may take as many iterations as the plan did (each costs about twice as
        # much on 2N elements), so it at most about doubles the time; else it reports null
        budget = min(options.max_iter, max(ESTIMATE_MIN_ITER, result.optimizer.iterations))
        if options.on_phase is not None:
            options.on_phase(f"estimating the error of J (solves on {2 * result.mesh.N} elements)")
        error = estimate(problem.system, result, **(common | {"max_iter": budget}))
    return Plan(result=result, error=error, multi=multi)


def _solve_auto(problem: OptimalControlProblem, options: SolveOptions) -> Plan:
    from hoc_cli.accuracy import DEFAULT_ACCURACY, plan_auto

    found = plan_auto(problem.system, problem.order, problem.T, problem.q0, problem.dq0, problem.q1, problem.dq1,
                      accuracy=problem.accuracy if problem.accuracy is not None else DEFAULT_ACCURACY,
                      limits=problem.limits, callback=options.callback, **_common(problem, options))
    return Plan(result=found.plan, error=found.error, auto=found)


def node_fractions(problem: OptimalControlProblem) -> np.ndarray | None:
    """The s-domain node fractions (N + 1,) with every via a node (None: N equal elements); TaskError (key N)
    when N is too small to hold them.
    """
    from hoc_cli.goals.mesh import via_fractions

    try:
        return via_fractions(problem.N, [gp.s for gp in problem.vias])
    except ValueError as exc:
        raise TaskError(f"{exc} (every via time is a node of the mesh)", key="N") from None


def check_reach(problem: OptimalControlProblem, goals) -> None:
    """``UnreachableGoal`` when a link goal (at T or a via) lies beyond the reach of its chain
    (``goals.residuals.reach``) at every admissible T (a free T: at ``REACH_SAMPLES`` times in [min, max]).
    """
    from hoc_cli.goals.residuals import FrameResidual, reach

    free = problem.free_time
    times = np.linspace(free.min, free.max, REACH_SAMPLES) if free is not None else np.array([problem.T])
    points = [("x1", 1.0, goals.final)] if goals.final is not None else []
    points += [(gp.label, gp.s, gp.residual) for gp in goals.vias if isinstance(gp.residual, FrameResidual)]
    for key, s, res in points:
        ball = reach(problem.system.model, res.link)
        if ball is None:
            continue
        o, r = ball
        dist = np.linalg.norm(res.target((s * times)[:, None])[0] - o, axis=1)  # the targets (k, 3) at once
        if np.all(dist > r * (1 + 1e-9)):
            where = "" if free is None else f" for every T in [{free.min:g}, {free.max:g}] s"
            raise UnreachableGoal(f"infeasible: the goal of {res.link} is {dist.min():.4g} m from the first joint "
                                  f"of its chain{where}, beyond the arm's reach {r:.4g} m (the sum of its link lengths)",
                                  key=key)


def _solve_goals(problem: OptimalControlProblem, options: SolveOptions, warm: WarmStart | None) -> Plan:
    from hoc_cli.goals import plan_goals
    from hoc_cli.goals.mesh import scaled_mesh

    goals = problem.goals()
    check_reach(problem, goals)
    fractions = node_fractions(problem)
    common = _common(problem, options) | {"callback": options.callback}
    if isinstance(problem.time, Fixed):
        if problem.constraint is None and problem.limits is not None and problem.limits.any:
            result = _fixed_time_sqp(problem, goals, fractions, warm)
            if result is not None:
                return Plan(result=result, goals=goals)
        C_init = None if warm is None else warm.coeffs
        more = {} if problem.constraint is None else {"constraint": problem.constraint}
        result = plan_goals(problem.system, scaled_mesh(problem.order, problem.T, problem.N, fractions), problem.q0,
                            problem.dq0, goals, limits=problem.limits, C_init=C_init, **common, **more)
        return Plan(result=result, goals=goals)
    if warm is not None and problem.constraint is None:
        return _warm_replan(problem, goals, fractions, warm, common)
    return _solve_free_time(problem, goals, fractions, common)


def _fixed_time_sqp(problem: OptimalControlProblem, goals, fractions, warm: WarmStart | None):
    """A goal plan in a fixed T within enforced limits by SQP steps from the initial trajectory
    (``goals.free_time_sqp.plan_fixed_time``) or from ``warm`` (``replan_fixed_time``, its multipliers and working
    set by least squares), or None when they do not converge (``plan_goals`` then solves).
    """
    from hoc_cli.goals.free_time_sqp import plan_fixed_time, replan_fixed_time
    from hoc_cli.goals.mesh import scaled_mesh
    from hoc_cli.goals.warm import initial_plan, previous_plan

    mesh = scaled_mesh(problem.order, problem.T, problem.N, fractions)
    if warm is not None:
        previous = previous_plan(problem.system, mesh, warm.coeffs, problem.q0, problem.dq0, goals, cost=problem.cost,
                                 G=warm.G, limits=problem.limits)
        return replan_fixed_time(problem.system, previous, goals, problem.limits)
    start = initial_plan(problem.system, mesh, problem.q0, problem.dq0, goals, cost=problem.cost)
    return plan_fixed_time(problem.system, start, goals, problem.limits)


def _solve_free_time(problem: OptimalControlProblem, goals, fractions, common: dict) -> Plan:
    free: Free = problem.time  # type: ignore[assignment]
    system = problem.system
    if problem.constraint is not None:
        plain = _solve_free_time(dataclasses.replace(problem, constraint=None), goals, fractions, common)
        if plain.converged and _clear(problem.constraint, plain.result):  # the constraint inactive: its optimum
            return dataclasses.replace(plain, details={**plain.details, "collision_active": False})
        # else the search over fixed-T plans with the constraint (dJ/dT with its rows' part)
        from hoc_cli.collision.time_derivative import with_collision_slope
        from hoc_cli.free_time import joint_goal_solver, minimize_time
        from hoc_cli.goals.time_solver import goal_solver

        more = common | {"limits": problem.limits, "constraint": problem.constraint}
        if goals.final is None and not goals.vias:
            solver = joint_goal_solver(system, problem.order, problem.N, problem.q0, problem.dq0, problem.q1,
                                       problem.dq1, **more)
        else:
            solver = goal_solver(system, problem.order, problem.N, problem.q0, problem.dq0, goals, fractions=fractions,
                                 **more)
        ft = minimize_time(with_collision_slope(solver, problem.constraint), free.min, free.max, guess=free.guess,
                           weight=free.weight, rtol=COLLISION_T_RTOL)
    elif goals.final is None and not goals.vias:  # a joint goal: the search over fixed-T solves
        from hoc_cli.free_time import joint_goal_solver, minimize_time

        solver = joint_goal_solver(system, problem.order, problem.N, problem.q0, problem.dq0, problem.q1,
                                   problem.dq1, limits=problem.limits, **common)
        ft = minimize_time(solver, free.min, free.max, guess=free.guess, weight=free.weight)
    else:  # a plan at the guess, then Newton steps in x and T (the search if they do not converge)
        from hoc_cli.goals.free_time_sqp import minimize_time_sqp
        from hoc_cli.goals.time_solver import goal_solver

        solver = goal_solver(system, problem.order, problem.N, problem.q0, problem.dq0, goals, limits=problem.limits,
                             fractions=fractions, **common)
        ft = minimize_time_sqp(solver, system, goals, free.min, free.max, guess=free.guess, weight=free.weight,
                               limits=problem.limits)
    solves = [p.result.optimizer for p in ft.history]  # `iterations` is the last solve's; these, the search's
    details = {"dJ_dT": ft.dJ_dT, "T_weight": free.weight, "T_objective": ft.objective,
               "T_bound": ft.bound, "T_solves": len(ft.history), "T_converged": ft.converged,
               "T_iterations": sum(o.iterations for o in solves), "T_evaluations": sum(o.n_evals for o in solves)}
    if problem.constraint is not None:
        details["collision_active"] = True
    return Plan(result=ft.result, details=details, goals=goals)


def _clear(constraint, result) -> bool:
    """Whether the plan ``result`` keeps ``constraint``'s margin on its whole trajectory (its certificate)."""
    from hoc_cli.collision.certify import certify

    return certify(constraint.model, constraint.scene, result.mesh, result.coeffs).certified


def _warm_replan(problem: OptimalControlProblem, goals, fractions, warm: WarmStart, common: dict) -> Plan:
    """A free T from an earlier plan: ``replan`` from its T (clipped to [min, max]) and coefficients resampled
    to the problem's mesh at that T; the goal rows' multipliers by least squares (``previous_plan``).
    """
    from hoc_cli.free_time import rescale
    from hoc_cli.goals.mesh import scaled_mesh
    from hoc_cli.goals.replan import TimeRange, replan
    from hoc_cli.goals.warm import previous_plan
    from hoc_cli.planner import resample

    free: Free = problem.time  # type: ignore[assignment]
    mesh0, C0 = warm.mesh, warm.coeffs
    mesh = scaled_mesh(problem.order, mesh0.T, problem.N, fractions)
    C = C0 if mesh == mesh0 else resample(mesh0, C0, mesh)
    T = min(max(mesh0.T, free.min), free.max)
    if T != mesh0.T:
        C, mesh = rescale(C, mesh0.T, T), scaled_mesh(problem.order, T, problem.N, fractions)
    previous = previous_plan(problem.system, mesh, C, problem.q0, problem.dq0, goals, cost=problem.cost, G=warm.G,
                             limits=problem.limits)
    done = replan(problem.system, previous, goals, free=TimeRange(free.min, free.max, free.weight),
                  limits=problem.limits)
    slope = done.dJ_dT + free.weight
    T = done.plan.mesh.T
    bound = "max" if T >= free.max and slope < 0 else "min" if T <= free.min and slope > 0 else None
    details = {"dJ_dT": done.dJ_dT, "T_weight": free.weight, "T_objective": done.plan.J + free.weight * T,
               "T_bound": bound, "T_converged": done.converged, "warm_start": "replan",
               "replan_steps": done.steps, "replan_fallback": done.fallback}
    return Plan(result=done.plan, details=details, goals=goals)
