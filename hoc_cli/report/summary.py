"""The JSON summary of a plan: what ``hoc plan --json`` prints, its MCAP stores and ``hoc batch`` tabulates.

``plan_report`` turns ``hoc_cli.solve``'s ``Plan`` into a ``PlanReport``: the plan as reported (its
wall time the whole solve's; a free-T plan solved from scratch says so), the summary (README,
Outputs: cost, status, limits, collision, starts, goals; JSON-ready) and its ``Status``. The
summary's keys come in one order, so equal plans give equal bytes.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from hoc_cli import __version__
from hoc_cli.accuracy import ErrorEstimate
from hoc_cli.elements import HermiteMesh
from hoc_cli.limits import dense_times, limit_violations
from hoc_cli.planner import PlanResult
from hoc_cli.report.collision import collision_summary
from hoc_cli.report.goals import cold, goal_miss, goal_summary
from hoc_cli.report.jsonio import json_ready
from hoc_cli.report.limits import limits_summary
from hoc_cli.report.status import Status
from hoc_cli.system import RobotSystem

#: summary keys that differ between runs of the same task (left out of the MCAP's copy)
TIMINGS = ("wall_time_s", "plan_solve_wall_time_s", "J_error_wall_time_s", "outputs")


@dataclass(frozen=True)
class PlanReport:
    """A solved plan as both reporters see it.

    result : the ``PlanResult`` reported (``wall_time_s`` the whole solve [s]); summary : the JSON summary
    (JSON-ready: an absent limit is None); status : ``summary["status"]``; converged : ``summary["converged"]``
    (false for a missed goal or a constraint loop that stopped short, whatever the status).
    """

    result: PlanResult
    summary: dict
    status: Status
    converged: bool


def plan_report(task, model, planned, states, *, limits, collision, collision_mode: str, seed: int,
                warm: bool = False) -> PlanReport:
    """The report of ``planned`` (``hoc_cli.strategy.Plan``) for ``task`` on ``model``.

    ``states`` the task's resolved boundary states; ``limits`` the ``JointLimits`` checked (enforced when
    ``task.limits.mode`` is "enforce"); ``collision`` the scene (None when off) and ``collision_mode`` the
    mode in effect; ``seed`` the multi-start seed; ``warm`` whether the solve was warm-started (--init).
    """
    result = dataclasses.replace(planned.result, wall_time_s=planned.wall_time_s)
    if task.time.free is not None and not warm:
        result = cold(result)  # its last solve says "warm replan": there was no --init
    auto = task.N is None
    summary = summarise(task, model, result, states)
    if planned.error is not None:  # goals: no estimate yet (docs/goals.md)
        summary.update(accuracy_summary(planned.error, task.accuracy, planned.auto.steps if auto else None))
    summary.update(limits_summary(task.limits.mode, limits, RobotSystem(model), result, states))
    summary.update(collision_summary(model, collision, collision_mode, result))
    summary.update(starts_summary(planned.multi, seed))
    if auto or planned.multi is not None:  # wall_time_s is the whole solve; the solve that gave the plan (the
        # last mesh, the best start) is under its own key
        summary.update(plan_solve_wall_time_s=planned.result.wall_time_s)
    summary.update(dict(planned.details) | goal_summary(model, result, planned.goals))
    summary.update(goal_miss(result, summary))  # "goal missed by X (key)", not "the stopping test held"
    summary = json_ready(summary)  # an absent limit (inf) is null
    for start in summary.get("starts", ()):
        Status.of(start["status"])  # every start's status is one of Status too
    return PlanReport(result=result, summary=summary, status=Status.of(summary["status"]),
                      converged=bool(summary["converged"]))


def summarise(task, model, result: PlanResult, states) -> dict:
    """The JSON summary's solver keys (README, Outputs): cost, status, counts, mesh, boundary error, max |u|,
    the limit check against the URDF's limits.
    """
    mesh, C = result.mesh, result.coeffs
    td = dense_times(mesh.T, mesh.N)
    q, dq, ddq = mesh.evaluate_all(C, td)
    u = RobotSystem(model).inverse_dynamics(q, dq, ddq)
    end = [np.abs(q[0] - states.q0), np.abs(dq[0] - states.dq0)]
    if states.q1 is not None:  # a link goal is reported by goal_summary
        end += [np.abs(q[-1] - states.q1), np.abs(dq[-1] - states.dq1)]
    end = np.concatenate(end)
    o = result.optimizer
    return {
        "cost": result.J,
        "cost_type": task.cost,
        "converged": result.converged,
        "status": Status.of(o.status).value,
        "message": o.message,
        "iterations": o.iterations,
        "evaluations": o.n_evals,
        "hessians": o.n_precond,
        "grad_norm": o.grad_norm,
        "decrement": o.decrement,
        "wall_time_s": result.wall_time_s,
        "method": task.method,
        "tol": task.tol,
        "joints": list(model.joint_names),
        "N": mesh.N,
        **mesh_summary(mesh),
        "order": mesh.order,
        "T": mesh.T,
        "gauss_points": result.G,
        "quadrature_change": result.quadrature_change,
        "boundary_error": float(end.max()),
        "max_abs_u": [float(v) for v in np.abs(u).max(axis=0)],
        "limit_violations": limit_violations(model.joint_names, model.lower, model.upper, model.velocity_limit,
                                             model.effort_limit, td, q, dq, u),
    }


def mesh_summary(mesh: HermiteMesh) -> dict:
    """``mesh``: "uniform" (N equal elements) or "nonuniform" (``N: auto`` split some), with ``nodes`` [s] then."""
    if mesh.uniform:
        return {"mesh": "uniform"}
    return {"mesh": "nonuniform", "nodes": [float(v) for v in mesh.nodes]}


def accuracy_summary(error: ErrorEstimate, accuracy: float | None, steps) -> dict:
    """``J_error_estimate`` (relative), ``J_error_basis`` (what it rests on), ``J_error_elements`` (per element)
    and the estimate's own cost; for N: auto also ``accuracy`` and ``N_auto`` (each mesh tried).
    """
    out = {"J_error_estimate": error.relative,
           "J_error_basis": error.basis,
           "J_error_elements": None if error.indicators is None else [float(v) for v in error.indicators],
           "J_error_wall_time_s": error.wall_time_s}
    if steps is not None:
        out |= {"accuracy": accuracy, "N_auto": list(steps)}
    return out


def starts_summary(multi, seed: int) -> dict:
    """Summary keys of a multi-start solve: the kept start and every start's J and status ({} for one start)."""
    if multi is None:
        return {}
    return {"seed": seed, "best_start": multi.best_index, "starts": [o.as_dict() for o in multi.outcomes]}


def reproducible_summary(summary: dict[str, Any]) -> dict[str, Any]:
    """The summary as stored in the MCAP: without wall-clock timings, so that equal inputs give equal bytes."""
    return {k: v for k, v in summary.items() if k not in TIMINGS} | {"hoc_version": __version__}
