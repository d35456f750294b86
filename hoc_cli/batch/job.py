"""One batch plan, as run on a Dask worker: the same path as ``hoc plan``, failures turned into a row.

``solve_job`` never raises for a bad plan (invalid task, missing URDF, numerical failure): it
returns a row with status "error" and the one-line message ``hoc plan`` would print. Per-plan
files are written atomically (``hoc_cli.report.outputs``) as ``DIR/plans/<id>.<kind>``.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING

from hoc_cli.batch.results import column_name
from hoc_cli.batch.spec import Job
from hoc_cli.errors import TaskError, naming_file
from hoc_cli.report.status import Status

if TYPE_CHECKING:
    from hoc_cli.report.summary import PlanReport

PLANS_DIR = "plans"


def solve_job(job: Job, out_dir: str | None = None, kinds: tuple[str, ...] = ()) -> dict:
    """Solve one job; returns its results row (see ``hoc_cli.batch.results.COLUMNS``)."""
    start = time.perf_counter()
    from hoc_cli.errors import Infeasible

    try:
        row = _solve(job, out_dir, kinds)
    except Infeasible as exc:  # proven before the solve: the row says so, as ``hoc plan`` does (exit 1)
        row = error_row(job, _message(exc)) | {"status": Status.INFEASIBLE.value}
    except Exception as exc:  # noqa: BLE001 - every failure of one plan becomes its row
        row = error_row(job, _message(exc))
    row["solve_time_s"] = time.perf_counter() - start
    return row


def solve_jobs(jobs: list[Job], out_dir: str | None = None, kinds: tuple[str, ...] = ()) -> list[dict]:
    """``solve_job`` for a few jobs in a row: one Dask task, so the engine's cost is shared by them."""
    return [solve_job(job, out_dir, kinds) for job in jobs]


def error_row(job: Job, message: str) -> dict:
    """The row of a plan that produced no result."""
    return {"id": job.id, "task": job.source, **swept_columns(job), "status": Status.ERROR.value, "converged": False,
            "error": message, "outputs": []}


def swept_columns(job: Job) -> dict:
    """The job's swept values under their results column names."""
    return {column_name(k): v for k, v in job.swept.items()}


def _message(exc: Exception) -> str:
    from hoc_cli.errors import HocError

    if isinstance(exc, HocError):
        return str(exc)
    first = (str(exc).strip().splitlines() or [""])[0][:200]
    return f"internal error ({type(exc).__name__}: {first})"


def _solve(job: Job, out_dir: str | None, kinds: tuple[str, ...]) -> dict:
    from hoc_cli.io.task import load_task, parse_task
    from hoc_cli.report.files import OutputTarget, output_transaction
    from hoc_cli.report.inputs import check_starts
    from hoc_cli.report.prepare import prepare
    from hoc_cli.strategy import solve

    source = Path(job.source)
    if job.doc is None:
        task = load_task(source, purpose="plan")  # raises the reason the file is not a task
    else:
        task = parse_task(job.doc, path=source, text=job.yaml_text(), purpose="plan")
    starts = task.solver.starts if job.starts is None else job.starts  # the spec's starts, else the task's
    seed = task.solver.seed if job.seed is None else job.seed
    check_starts(starts, seed, None, key="solver.starts" if job.starts is None else "starts")
    names = [f"{PLANS_DIR}/{job.id}.{kind}" for kind in kinds] if out_dir is not None else []
    targets = [OutputTarget(Path(out_dir) / name, kind) for name, kind in zip(names, kinds)] if names else []
    ready = prepare(task, targets, starts=starts)
    if ready.problem.has_goals and starts > 1:
        raise TaskError("multi-start applies to joint goals in a fixed T (the task has goals: docs/goals.md)",
                        file=task.path, key="solver.starts")
    ready.refuse_infeasible()  # a task no trajectory within the enforced limits can meet: proven before the solve
    options = ready.options(starts=starts, seed=seed, estimate_error=False)  # as ``hoc plan``, without its estimate
    planned = naming_file(lambda: solve(ready.problem, options), task.path)
    reported = ready.report(planned, seed=seed)  # a batch plan has no --init
    if targets:
        (Path(out_dir) / PLANS_DIR).mkdir(parents=True, exist_ok=True)
        traj = ready.sample(reported)
        with output_transaction():
            ready.write(targets, traj, reported.summary, planned.goals)
    return row_of(job, reported, names)


def row_of(job: Job, reported: PlanReport, outputs: list[str]) -> dict:
    """The results row of a solved plan from its report (the summary ``hoc plan --json`` prints)."""
    import json

    summary = reported.summary
    viol = summary["limit_violations"]
    row = {
        "id": job.id, "task": job.source, **swept_columns(job),
        "status": reported.status.value, "converged": reported.converged, "cost": float(summary["cost"]),
        "iterations": int(summary["iterations"]), "evaluations": int(summary["evaluations"]),
        "boundary_error": float(summary["boundary_error"]),
        "limits": "violated" if viol else "ok",
        "limit_violations": json.dumps(viol, sort_keys=True) if viol else None,
        "outputs": list(outputs), "error": None,
    }
    if summary.get("collision_mode", "off") != "off":  # a collision section: the mode in effect (a free T, N: auto or
        # multi-start plans with check where the section's default enforce cannot apply: hoc plan warns, the row says)
        row["collision_mode"] = str(summary["collision_mode"])
    if summary.get("min_clearance"):  # the certificate's smallest distance [m]
        row["min_clearance"] = float(summary["min_clearance"]["distance"])
    if "dJ_dT" in summary:  # a free T: the optimal duration [s] (not "T": a sweep over T has that column)
        row["T_optimal"] = float(summary["T"])
    if "starts" in summary:
        row["best_start"] = int(summary["best_start"])
        row["start_costs"] = [s["cost"] for s in summary["starts"]]
    return row
