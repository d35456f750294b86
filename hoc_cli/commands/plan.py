"""``hoc plan``: load the task and robot, solve, sample, check limits, write outputs, summarise."""
from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from hoc_cli.accuracy import AUTO_MAX_ELEMENTS, AUTO_START
from hoc_cli.commands.common import EXIT_OK, EXIT_UNMET, refuse_urdf_task
from hoc_cli.elements import HermiteMesh
from hoc_cli.errors import Infeasible, InputFileError, OutputError, TaskError, naming_file
from hoc_cli.io.task import Task, apply_overrides, load_task
from hoc_cli.optimize import check_gradient
from hoc_cli.problem import ControlProblem
from hoc_cli.report.collision import (
    collision_markers,
    sampled_clearance,
    warn_collisions,
)
from hoc_cli.report.console import stderr_console, warn, warn_limit_violations
from hoc_cli.report.files import output_transaction, parse_outputs, refuse_inputs
from hoc_cli.report.jsonio import json_ready, print_json, validate_json
from hoc_cli.report.prepare import prepare
from hoc_cli.report.status import unmet_line
from hoc_cli.report.workload import WARN_SECONDS, Heartbeat, check_workload
from hoc_cli.strategy import Plan, WarmStart, node_fractions, solve
from hoc_cli.system import RobotSystem

GRADIENT_RTOL = 1e-6  # --check-gradient fails above this (measured on the shipped tasks: <= 3e-9)
GRADIENT_MAX_COORDINATES = 1000  # beyond this a fixed random subset is checked (2 cost evaluations each)


def run(task_path: Path, *, outputs: list[str] | None = None, as_json: bool = False, quiet: bool = False,
        progress: bool = False, overrides: dict | None = None, init: Path | None = None,
        gradient_check: bool = False, starts: int | None = None, seed: int | None = None) -> int:
    from hoc_cli.commands.starts import check_plan_starts, starts_pool

    refuse_urdf_task(task_path)
    task = apply_overrides(load_task(task_path, purpose="plan"), **(overrides or {}))
    starts_key = "--starts" if starts is not None else "solver.starts"  # the option wins over the task's key
    starts = task.solver.starts if starts is None else starts
    seed = task.solver.seed if seed is None else seed
    check_plan_starts(starts, seed, init, key=starts_key)
    if gradient_check and outputs:
        raise OutputError("--check-gradient only checks the gradient and writes no outputs", key="--output")
    targets = parse_outputs(outputs, task.stem)
    refuse_inputs(targets, {"the task": task.path, "the URDF": task.robot, "--init": init})
    if as_json and any(t.path is None for t in targets):
        raise OutputError("'-o -' (CSV on stdout) cannot be combined with --json (JSON on stdout)", key="--output")
    console = stderr_console(quiet=quiet, progress=progress)
    show = not quiet and (progress or console.is_terminal)
    ready = prepare(task, targets, starts=starts, explicit_collision=(overrides or {}).get("collision") is not None,
                    console=console)
    model, states, problem = ready.model, ready.states, ready.problem
    has_goals = problem.has_goals  # a link goal, vias or a free T
    auto = task.N is None
    mesh = HermiteMesh(task.order, task.T, AUTO_START if auto else task.N)
    if has_goals and not auto:
        from hoc_cli.goals.mesh import scaled_mesh  # the goal solvers load only for a task with goals

        mesh = _with_file(task, lambda: scaled_mesh(task.order, task.T, task.N, node_fractions(problem)))
    warm = None
    if init is not None and not auto:
        if has_goals and task.time.free is not None:  # a warm replan from the plan's T and coefficients
            warm = WarmStart(*_init_plan(init, model.joint_names))
            if problem.constraint is not None:  # (strategy: the search over fixed-T plans with it, from scratch)
                warn("--init is not used for a free T with collision enforcement: planned from the task's guess")
        else:
            warm = WarmStart(mesh, _warm_start(init, mesh, model.joint_names))
    if auto and init is not None:
        raise OutputError("--init needs a fixed N (the task has N: auto; give -N)", key="--init")
    if auto and starts > 1:
        raise OutputError("multi-start needs a fixed N (the task has N: auto; give -N)", key=starts_key)
    if has_goals and starts > 1:
        raise OutputError("multi-start applies to joint goals in a fixed T (the task has goals: docs/goals.md)",
                          key=starts_key)
    if gradient_check and has_goals:
        return _check_goal_gradient(task, model, states, problem, console, as_json)
    if gradient_check:
        return _check_gradient(task, model, states, mesh, None if warm is None else warm.coeffs, console, as_json)
    if not has_goals:
        _refuse_nonfinite_cost(task, model, states, mesh, None if warm is None else warm.coeffs)
    try:  # after every input check: a task no trajectory within the enforced limits can meet exits 1 at once
        ready.refuse_infeasible()  # (constraints/feasibility.py)
    except Infeasible as exc:
        if as_json:
            print_json(json_ready(exc.summary))
        raise
    cores = 1
    if starts > 1:
        from hoc_cli.batch.engine import available_cores

        cores = available_cores()
    work = check_workload(task, model.n, targets, N=mesh.N, starts=starts, cores=cores)  # warns before a long run

    start = time.perf_counter()
    # a progress line at least every 3 s with --progress; a warning at 10 s if the estimate promised less
    beat = Heartbeat(console, show, start=start, overdue=None if work.heavy else WARN_SECONDS)

    def report(log) -> None:
        beat.tick(f"solving (after iteration {log.iteration} on N = {log.level})")
        if show:
            console.print(f"iter {log.iteration:4d}  N {log.level:4d}  J {log.J:<18.12g} |g| {log.grad_norm:.1e}  "
                          f"dec {log.decrement:.1e}  evals {log.n_evals:4d} {time.perf_counter() - start:6.2f}s",
                          highlight=False, soft_wrap=True)

    def report_start(o) -> None:
        beat.tick(f"solving (after start {o.index})")
        if show:
            console.print(f"start {o.index:3d}  J {o.J:<18.12g} {o.status:<12s} iterations {o.iterations:5d} "
                          f"{time.perf_counter() - start:6.2f}s", highlight=False, soft_wrap=True)

    options = ready.options(starts=starts, seed=seed, estimate_error=not has_goals, callback=report,
                            on_start=report_start, on_phase=beat.say, client=starts_pool if starts > 1 else None)
    with beat:
        planned: Plan = _with_file(task, lambda: solve(problem, options, warm))
    found = planned.auto
    with beat.phase("sampling the plan and checking its limits"):
        reported = ready.report(planned, seed=seed, warm=warm is not None)
        result, summary = reported.result, reported.summary
        traj = ready.sample(reported)
        validate_json(summary)  # before any output is written
    writing = f"writing {', '.join(t.label for t in targets)} ({traj.t.size} samples)" if targets else None
    with output_transaction(), beat.phase(writing):  # every output is replaced, or none
        summary["outputs"] = ready.write(targets, traj, summary, planned.goals,
                                         scene=collision_markers(ready.collision, model, targets),
                                         clearance=sampled_clearance(ready.collision, model, traj.q, targets))
    warn_limit_violations(summary["limit_violations"])
    warn_collisions(summary.get("collisions") or [])
    if as_json:
        print_json(summary)
    if show:
        from hoc_cli.report.table import summary_table

        console.print(summary_table(summary))
    written = "was written" if targets else "was not written (-o none)"
    if auto and result.converged and not found.reached:
        console.print(f"hoc: accuracy not reached: estimated relative error of J {planned.error.relative:.2g} > "
                      f"{task.accuracy:g} at N = {result.mesh.N} (N: auto stops at {AUTO_MAX_ELEMENTS} elements); "
                      f"the plan {written}", highlight=False, markup=False, soft_wrap=True)
        return EXIT_UNMET
    if not reported.converged:  # a missed goal too (goal_miss)
        console.print(unmet_line(reported.status, summary["message"], written),
                      highlight=False, markup=False, soft_wrap=True)
        return EXIT_UNMET
    return EXIT_OK


def _with_file(task: Task, fn):
    """``fn()``, with the task file named in a ``HocError`` that names a task key but no file (the maths
    names the key only); a numerical failure, which names neither, is left as it is.
    """
    return naming_file(fn, task.path)


def _starting_point(task: Task, model, states, mesh: HermiteMesh, C_init) -> tuple[ControlProblem, np.ndarray]:
    """The joint-goal problem of ``task`` on ``mesh`` and where its solve starts: the free coefficients of the
    minimum-jerk guess, or of ``C_init`` (N+1, m, n: --init's plan).
    """
    problem = ControlProblem(RobotSystem(model), mesh, states.q0, states.dq0, states.q1, states.dq1, cost=task.cost)
    return problem, problem.initial_guess() if C_init is None else problem.layout.pack(C_init)


def _check_gradient(task: Task, model, states, mesh: HermiteMesh, C_init, console, as_json: bool) -> int:
    """``--check-gradient``: the cost gradient at the initial guess against central differences."""
    from hoc_cli.commands.gradient_goals import checked_coordinates

    problem, x = _starting_point(task, model, states, mesh, C_init)
    with np.errstate(all="ignore"):
        check = check_gradient(problem.value, x, problem.evaluate(x).grad,
                               coordinates=checked_coordinates(x.size, GRADIENT_MAX_COORDINATES))
    passed = check.passed(GRADIENT_RTOL)
    worst, where = None, "no free coefficients (every coefficient is fixed by x0 and x1)"
    if check.coordinates.size:
        p, d, i = (int(v) for v in np.unravel_index(np.flatnonzero(problem.layout.free)[check.worst[1]],
                                                      (mesh.N + 1, mesh.m, problem.n)))
        worst = {"node": p, "t": float(mesh.nodes[p]), "derivative": ("q", "dq", "ddq")[d],
                 "joint": model.joint_names[i]}
        where = f"worst {worst['derivative']} of {worst['joint']} at node {p} (t = {worst['t']:.6g} s)"
    if as_json:
        print_json({"gradient_check": {"max_rel_error": check.max_rel_error, "rtol": GRADIENT_RTOL, "passed": passed,
                                       "coordinates": int(check.coordinates.size), "of": int(x.size),
                                       "step": check.step, "worst": worst, "cost_type": task.cost, "N": mesh.N,
                                       "order": mesh.order}})
    console.print(f"hoc: gradient check ({task.cost} cost, {mesh.order} N = {mesh.N}, at the initial guess): "
                  f"max relative error {check.max_rel_error:.2e} over {check.coordinates.size} of {x.size} "
                  f"coefficients, {where}; {'passed' if passed else 'FAILED'} (threshold {GRADIENT_RTOL:g})",
                  highlight=False, markup=False, soft_wrap=True)
    return EXIT_OK if passed else EXIT_UNMET


def _check_goal_gradient(task: Task, model, states, problem, console, as_json: bool) -> int:
    """``--check-gradient`` on a task with goals (``hoc_cli.commands.gradient_goals``) at the initial trajectory."""
    from hoc_cli.commands.gradient_goals import goal_gradient_checks, report

    goals, fractions = _with_file(task, lambda: (problem.goals(), node_fractions(problem)))
    checks = goal_gradient_checks(model, task.order, task.T, task.N, fractions, states.q0,
                                  states.dq0, goals, cost=task.cost, free_time=task.time.free is not None,
                                  max_coordinates=GRADIENT_MAX_COORDINATES)
    return report(checks, GRADIENT_RTOL, console, as_json, cost=task.cost, order=task.order, N=task.N)


def _refuse_nonfinite_cost(task: Task, model, states, mesh: HermiteMesh, C_init) -> None:
    """TaskError (exit 2) when the cost is not finite where the solve starts (the minimum-jerk guess, or
    --init's plan): values of the task (or its URDF) far beyond physical size; one cost evaluation.
    """
    problem, x = _starting_point(task, model, states, mesh, C_init)
    with np.errstate(all="ignore"):  # the torques and ½ Σ w uᵀu: a singular M is the solve's to report (exit 1)
        q, dq, ddq = problem.op.apply(problem.coefficients(x))
        u = problem.system.inverse_dynamics(q, dq, ddq)
        finite = bool(np.all(np.isfinite(u))) and math.isfinite(float(np.dot(problem.op.w, np.sum(u * u, axis=1))))
    if not finite:
        raise TaskError(f"the {task.cost} cost is not finite at the start of the solve (expected T, x0, x1, gravity "
                        "and the URDF's masses and lengths of physical size)", file=task.path)


def _init_plan(path: Path, joints) -> tuple[HermiteMesh, np.ndarray, int | None]:
    """(mesh, coefficients (N+1, m, n), Gauss points per element or None) of an earlier plan's MCAP."""
    import json

    from hoc_cli.io.mcap import read_plan

    plan_file = read_plan(path)
    tr = plan_file.trajectory
    if tuple(tr.joints) != tuple(joints):
        raise InputFileError(f"plan joints {list(tr.joints)} differ from the task's {list(joints)}", file=path,
                             key="--init")
    if tr.mesh is None or tr.coeffs is None:
        raise InputFileError("has no Hermite coefficients (expected an MCAP written by 'hoc plan')", file=path,
                             key="--init")
    try:
        G = json.loads(plan_file.metadata.get("summary", "{}")).get("gauss_points")
    except (ValueError, AttributeError):
        G = None
    return tr.mesh, np.array(tr.coeffs), G if isinstance(G, int) and G >= 1 else None


def _warm_start(path: Path, mesh: HermiteMesh, joints) -> np.ndarray:
    """Coefficients (N+1, m, n) from an earlier plan's MCAP, resampled at this mesh's nodes if needed."""
    mesh0, C0, _ = _init_plan(path, joints)
    if not math.isclose(mesh0.T, mesh.T, rel_tol=1e-12):
        raise InputFileError(f"plan duration T = {mesh0.T:g} s differs from the task's T = {mesh.T:g} s",
                             file=path, key="--init")
    if mesh0 == mesh:  # the same order and node times
        return C0
    t = mesh.nodes
    cols = [mesh0.evaluate(C0, t, r) for r in range(mesh.m)]
    return np.stack(cols, axis=1)
