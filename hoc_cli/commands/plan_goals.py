"""``hoc plan``'s goals: the task's link goal, vias and free T as ``Goals``, the solve, the summary keys.

The maths is in ``hoc_cli.goals`` and ``hoc_cli.free_time``; this module reads the task (link names
against the model, joint values in model order), builds the mesh with every via time a node
(``hoc_cli.goals.mesh``), picks the solver (with ``--init`` and a free T: a warm replan) and reports ``T``,
``dJ_dT``, ``final_q``, ``reached`` (the link's pose, and velocity for a moving target), ``vias`` and
``warm_start`` (docs/goals.md).
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from hoc_cli.dynamics import frame_jacobian, link_poses, link_velocity
from hoc_cli.elements import HermiteMesh
from hoc_cli.errors import HocError, TaskError
from hoc_cli.free_time import joint_goal_solver, minimize_time, rescale
from hoc_cli.goals import (
    FrameResidual,
    GoalPoint,
    Goals,
    JointResidual,
    inverse_kinematics,
    plan_goals,
    quaternion_matrix,
    rotation_angle,
)
from hoc_cli.goals.free_time_sqp import minimize_time_sqp
from hoc_cli.goals.mesh import scaled_mesh, via_fractions
from hoc_cli.goals.replan import TimeRange, replan
from hoc_cli.goals.residuals import reach
from hoc_cli.goals.time_solver import goal_solver
from hoc_cli.goals.warm import previous_plan
from hoc_cli.io.task import Task
from hoc_cli.io.task.checks import Checker
from hoc_cli.io.task.goals import LinkGoal
from hoc_cli.io.task.resolve import joint_vector
from hoc_cli.planner import resample
from hoc_cli.system import RobotSystem


class UnreachableGoal(HocError):
    """A link goal beyond the arm's reach at every admissible T: infeasible (exit 1, nothing solved)."""

    exit_code = 1


def check_reach(task: Task, model, goals: Goals) -> None:
    """Raise ``UnreachableGoal`` when a link goal (x1 or a via) lies beyond the reach of its chain
    (``hoc_cli.goals.residuals.reach``) at every T of the task (for a free T, at 400 times in [min, max]).
    """
    free = task.time.free
    times = np.linspace(free.min, free.max, 400) if free is not None else np.array([task.T])
    points = [("x1", 1.0, goals.final)] if goals.final is not None else []
    points += [(gp.label, gp.s, gp.residual) for gp in goals.vias if isinstance(gp.residual, FrameResidual)]
    for key, s, res in points:
        ball = reach(model, res.link)
        if ball is None:
            continue
        o, r = ball
        dist = np.array([np.linalg.norm(res.target(s * T)[0] - o) for T in times])
        if np.all(dist > r * (1 + 1e-9)):
            where = "" if free is None else f" for every T in [{free.min:g}, {free.max:g}] s"
            raise UnreachableGoal(f"infeasible: the goal of {res.link} is {dist.min():.4g} m from the first joint "
                                  f"of its chain{where}, beyond the arm's reach {r:.4g} m (the sum of its link lengths)",
                                  file=task.path, key=key)


def has_goals(task: Task) -> bool:
    """Whether the task needs more than ``hoc_cli.planner.plan``: a link goal, vias or a free T."""
    return isinstance(task.x1, LinkGoal) or bool(task.via) or task.time.free is not None


def _frame(task: Task, model, link: str, key: str, position, orientation, target=None,
           match: bool = False) -> FrameResidual:
    if link not in model.link_names:
        raise TaskError(f"unknown link {link[:60]!r} (links: {', '.join(model.link_names)})", file=task.path, key=key)
    R = None if orientation is None else quaternion_matrix(orientation)
    if target is not None:
        return FrameResidual(model, link, np.array(target.position), R, np.array(target.velocity),
                             np.array(target.acceleration), match_velocity=match)
    return FrameResidual(model, link, np.array(position, float), R)


def task_goals(task: Task, model, states) -> Goals | None:
    """The task's goals in model joint order, or None for a joint goal in a fixed T (plain ``plan``).

    A link goal's initial final state comes from inverse kinematics at T (from x0, within the
    position limits); with ``match_velocity`` its q̇ is the least-squares joint rate of the target's velocity.
    """
    if not has_goals(task):
        return None
    c = Checker(task.path)
    joints = tuple(model.joint_names)
    T = task.T
    vias = []
    for i, v in enumerate(task.via):
        s = v.s if v.s is not None else v.t / T
        if v.q is not None:
            dq = joint_vector(c, v.dq, f"via[{i}].dq", joints)
            vias.append(GoalPoint(s, JointResidual(joint_vector(c, v.q, f"via[{i}].q", joints), dq), f"via[{i}]"))
        else:
            vias.append(GoalPoint(s, _frame(task, model, v.link, f"via[{i}].link", v.position, v.orientation),
                                  f"via[{i}]"))
    if not isinstance(task.x1, LinkGoal):
        return Goals(q1=states.q1, dq1=states.dq1, vias=tuple(vias))
    g = task.x1
    final = _frame(task, model, g.link, "x1.link", g.position, g.orientation, g.target, g.match_velocity)
    q1 = inverse_kinematics(final, states.q0, T, model.lower, model.upper)
    dq1 = None
    if g.match_velocity:
        dq1 = np.linalg.pinv(frame_jacobian(model, q1, g.link)[:3]) @ final.target(T)[1]
    return Goals(final=final, final_dq=g.dq, vias=tuple(vias), q1_guess=q1, dq1_guess=dq1)


def node_fractions(task: Task, goals: Goals) -> np.ndarray | None:
    """The s-domain node fractions (N + 1,) of the plan's mesh with every via time a node
    (``hoc_cli.goals.mesh.via_fractions``), None for N equal elements; TaskError when N is too small.
    """
    try:
        return via_fractions(task.N, [gp.s for gp in goals.vias])
    except ValueError as exc:
        raise TaskError(f"{exc} (every via time is a node of the mesh)", file=task.path, key="N") from None


def goal_mesh(task: Task, goals: Goals) -> HermiteMesh:
    """The mesh of a task with goals at the task's T (with a free T: the start of the search)."""
    return scaled_mesh(task.order, task.T, task.N, node_fractions(task, goals))


def solve(task: Task, model, states, goals: Goals, limits, callback=None, C_init=None, init=None):
    """(PlanResult, summary keys) for a task with goals: ``plan_goals`` at T (from ``C_init`` when given,
    ``--init``), or a free T (``minimize_time_sqp``: a plan at the guess, then Newton steps in x and T; the
    search over fixed-T solves for joint goals), or with ``init`` (the
    mesh and coefficients of an earlier plan, ``--init`` with a free T) a warm replan from it.
    """
    check_reach(task, model, goals)
    system = RobotSystem(model)
    options = {"cost": task.cost, "method": task.method, "tol": task.tol, "max_iter": task.max_iter,
               "callback": callback}
    plain = goals.final is None and not goals.vias
    free = task.time.free
    if free is None:
        result = plan_goals(system, goal_mesh(task, goals), states.q0, states.dq0, goals,
                            limits=limits, C_init=C_init, **options)
        return result, {}
    if init is not None:
        return warm_replan(task, system, states, goals, limits, *init, options=options)
    if plain:
        solver = joint_goal_solver(system, task.order, task.N, states.q0, states.dq0, states.q1, states.dq1,
                                   limits=limits, **options)
    else:
        fractions = node_fractions(task, goals)
        solver = goal_solver(system, task.order, task.N, states.q0, states.dq0, goals, limits=limits,
                             fractions=fractions, **options)
    start = time.perf_counter()
    if plain:  # the replan's steps take goal plans (not the plain joint-goal solver's)
        ft = minimize_time(solver, free.min, free.max, guess=free.guess, weight=free.weight)
    else:  # a plan at the guess, then Newton steps in x and T (the search if they do not converge)
        ft = minimize_time_sqp(solver, system, goals, free.min, free.max, guess=free.guess, weight=free.weight,
                               limits=limits)
    result = dataclasses.replace(ft.result, wall_time_s=time.perf_counter() - start)  # every solve of the search
    return result, _search_summary(ft, free.weight)


def _search_summary(ft, weight: float) -> dict:
    """The free-T search's summary keys (``FreeTimeResult``)."""
    solves = [p.result.optimizer for p in ft.history]  # `iterations` is the last solve's; these, the search's
    return {"dJ_dT": ft.dJ_dT, "T_weight": weight, "T_objective": ft.objective,
            "T_bound": ft.bound, "T_solves": len(ft.history), "T_converged": ft.converged,
            "T_iterations": sum(o.iterations for o in solves), "T_evaluations": sum(o.n_evals for o in solves)}


def warm_replan(task: Task, system, states, goals: Goals, limits, mesh0: HermiteMesh, C0: np.ndarray,
                G: int | None, options: dict) -> tuple:
    """``--init`` with a free T: ``replan`` from the earlier plan (mesh0, C0 (N+1, m, n), its Gauss points G)
    with its T (clipped to [min, max]) as the start, resampled to the task's mesh at that T; the goal
    rows' multipliers by least squares (``previous_plan``). ``warm_start`` in the summary says "replan"
    (with ``replan_steps``, the Newton steps, and ``replan_fallback``, whether the full search finished);
    with vias off the uniform nodes the mesh's nodes scale with T. ``options``: ``plan_goals``'s.
    """
    free = task.time.free
    fractions = node_fractions(task, goals)
    mesh = scaled_mesh(task.order, mesh0.T, task.N, fractions)
    C = C0 if mesh == mesh0 else resample(mesh0, C0, mesh)
    T = min(max(mesh0.T, free.min), free.max)
    if T != mesh0.T:
        C, mesh = rescale(C, mesh0.T, T), scaled_mesh(task.order, T, task.N, fractions)
    previous = previous_plan(system, mesh, C, states.q0, states.dq0, goals, cost=task.cost, G=G, limits=limits)
    start = time.perf_counter()
    done = replan(system, previous, goals, free=TimeRange(free.min, free.max, free.weight), limits=limits)
    result = dataclasses.replace(done.plan, wall_time_s=time.perf_counter() - start)
    slope = done.dJ_dT + free.weight
    T = result.mesh.T
    bound = "max" if T >= free.max and slope < 0 else "min" if T <= free.min and slope > 0 else None
    return result, {"dJ_dT": done.dJ_dT, "T_weight": free.weight, "T_objective": result.J + free.weight * T,
                    "T_bound": bound, "T_converged": done.converged, "warm_start": "replan",
                    "replan_steps": done.steps, "replan_fallback": done.fallback}


def goal_summary(model, result, goals: Goals | None) -> dict:
    """``final_q`` and, per link goal or via, the reached pose and its error (m, rad, m/s)."""
    if goals is None:
        return {}
    mesh, C = result.mesh, result.coeffs
    names = list(model.joint_names)
    out: dict = {"final_q": dict(zip(names, (float(v) for v in C[-1, 0])))}

    def reached(res: FrameResidual, q, dq) -> dict:
        P = link_poses(model, q)[res.link]
        p, v = res.target(mesh.T)
        d = {"link": res.link, "position": [float(x) for x in P[:3, 3]],
             "position_error": float(np.max(np.abs(P[:3, 3] - p)))}
        if res.orientation is not None:
            d["orientation_error"] = rotation_angle(P[:3, :3], res.orientation)
        if res.match_velocity:
            V = link_velocity(model, q, dq, res.link)[:3]
            d["velocity"] = [float(x) for x in V]
            d["velocity_error"] = float(np.max(np.abs(V - v)))
        return d

    if goals.final is not None:
        out["reached"] = reached(goals.final, C[-1, 0], C[-1, 1])
    vias = []
    for gp in goals.vias:
        t = gp.s * mesh.T
        q, dq = (mesh.evaluate(C, np.array([t]), r)[0] for r in (0, 1))
        if isinstance(gp.residual, JointResidual):
            err = float(np.max(np.abs(gp.residual(q, dq, mesh.T)[0])))
            vias.append({"t": float(t), "error": err})
        else:
            vias.append({"t": float(t), **reached(gp.residual, q, dq)})
    if vias:
        out["vias"] = vias
    return out
