"""``hoc catch``: the closed-loop catch of a thrown ball (``hoc_cli.realtime``) from a scenario file.

Plans the task's nominal catch (``hoc_cli.solve``), then simulates the loop: noisy observations, the ballistic
estimate, one replanner update per cycle, the arm on the plan in force. Prints the summary (a table on stderr,
or ``--json`` on stdout), writes the run to MCAP with ``-o run.mcap``. Exit 0 when the ball was caught, 1 when not.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from hoc_cli.commands.common import EXIT_OK, EXIT_UNMET
from hoc_cli.errors import OutputError
from hoc_cli.io.robot import load_model
from hoc_cli.report.console import stderr_console
from hoc_cli.report.inputs import read_urdf_text
from hoc_cli.report.jsonio import json_ready, print_json


def run(scenario_path: Path, *, as_json: bool = False, seed: int | None = None, noise: float | None = None,
        output: Path | None = None, quiet: bool = False) -> int:
    from hoc_cli.io.scenario import load_scenario
    from hoc_cli.io.task import resolve
    from hoc_cli.io.task.problem import check_jerk_order, problem_from_task, task_limits
    from hoc_cli.realtime.loop import run_catch
    from hoc_cli.report.files import atomic_output, refuse_inputs
    from hoc_cli.strategy import solve

    sc = load_scenario(scenario_path)
    if seed is not None:
        if seed < 0:
            raise OutputError(f"expected an integer >= 0, got {seed}", key="--seed")
        sc = dataclasses.replace(sc, observer=dataclasses.replace(sc.observer, seed=seed))
    if noise is not None:
        if not noise >= 0:
            raise OutputError(f"expected a standard deviation >= 0 m, got {noise}", key="--noise")
        sc = dataclasses.replace(sc, observer=dataclasses.replace(sc.observer, noise=noise))
    if output is not None:
        if output.suffix.lower() != ".mcap":
            raise OutputError("expected an .mcap file", key="--output")
        if not output.parent.is_dir():
            raise OutputError(f"the directory {str(output.parent)!r} does not exist", key="--output")
        from hoc_cli.report.files import OutputTarget

        refuse_inputs([OutputTarget(path=output, kind="mcap")],
                      {"the scenario": sc.path, "the task": sc.task.path, "the URDF": sc.task.robot})
    task = sc.task
    model = load_model(task)
    states = resolve(task, model.joint_names)
    limits = task_limits(model, states.limits)
    check_jerk_order(task, limits, task.order)
    problem = problem_from_task(task, model, states, limits if task.limits.mode == "enforce" else None)
    console = stderr_console(quiet=quiet)
    if not quiet:
        console.print(f"planning the nominal catch ({task.path.name}, N = {task.N}) ...")
    plan = solve(problem)
    run_ = run_catch(problem, plan, sc.throw, sc.observer, sc.cycle)
    summary = catch_summary(run_, sc, plan)
    if output is not None:
        from hoc_cli.io.catch_mcap import write_catch_mcap
        from hoc_cli.realtime.replanner import Target

        goal = problem.link_goal
        nominal = Target(goal.position, goal.velocity, goal.acceleration)
        with atomic_output(output) as fh:
            write_catch_mcap(fh, run_, sc.throw, model=model, system=problem.system, link=goal.link,
                             urdf_text=read_urdf_text(task.robot), scenario_text=sc.text,
                             summary=json.dumps(summary, sort_keys=True, default=float), nominal=nominal)
    if as_json:
        print_json(summary)
    elif not quiet:
        _table(console, summary)
    return EXIT_OK if run_.caught else EXIT_UNMET


def catch_summary(run, sc, plan) -> dict:
    """The JSON summary of a closed-loop run (README: "Catching in real time")."""
    recs = run.records
    steps = [r.plan.steps for r in recs]
    last = recs[-1] if recs else None
    return json_ready({
        "caught": run.caught,
        "status": run.status,
        "position_error": run.position_error,
        "relative_speed": run.relative_speed,
        "T": run.T,
        "closest_approach": {"distance": run.closest, "t": run.closest_t},
        "cycle_ms": run.cycle_ms,
        "cpu_ms": run.cpu_ms,
        "budget_ms": 1e3 * sc.cycle.budget,
        "overruns": run.overruns,
        "skipped": run.skipped,
        "abandoned": run.abandoned,
        "feedback": sum(r.kind == "feedback" for r in recs),
        "cycles": run.cycles,
        "steps": {"total": int(sum(steps)), "max_per_cycle": int(max(steps, default=0))},
        "held": sum(r.plan.status == "held" for r in recs),
        "guarded": sum(r.plan.guarded for r in recs),
        "final": None if last is None else {
            "t_start": last.t_start, "status": last.plan.status, "violation": last.plan.violation,
            "stationarity": last.plan.stationarity, "estimate_position_error": last.position_error,
            "estimate_velocity_error": last.velocity_error, "observations": last.observations},
        "nominal": {"T": plan.T, "J": plan.J},
        "updates": [{"t": r.t_start, "steps": r.plan.steps, "status": r.plan.status, "violation": r.plan.violation,
                     "stationarity": r.plan.stationarity, "wall_ms": 1e3 * r.plan.wall_time_s, "cpu_ms": 1e3 * r.cpu_s,
                     "late": r.late, "kind": r.kind, "estimate_error": r.position_error} for r in recs],
        "seed": sc.observer.seed,
        "noise": sc.observer.noise,
    })


def _table(console, s: dict) -> None:
    from rich.table import Table

    t = Table(title="hoc catch", show_header=False)
    ms = s["cycle_ms"]
    rows = [
        ("status", s["status"]),
        ("position error", f"{1e3 * s['position_error']:.2f} mm (caught within 5 mm)"),
        ("relative speed", f"{s['relative_speed']:.4f} m/s (caught below 0.05 m/s)"),
        ("catch time T", f"{s['T']:.4f} s"),
        ("closest approach", f"{1e3 * s['closest_approach']['distance']:.2f} mm at {s['closest_approach']['t']:.4f} s"),
        ("updates", f"{s['cycles'] - s['feedback']} SQP, {s['feedback']} corrections; {s['overruns']} over budget "
                    f"and discarded, {s['skipped']} skipped, {s['abandoned']} abandoned, {s['held']} held"),
        ("cycle wall ms", f"median {ms['median']:.1f}, p95 {ms['p95']:.1f}, p99 {ms['p99']:.1f}, max {ms['max']:.1f}"),
        ("cycle CPU ms", f"median {s['cpu_ms']['median']:.1f}, p99 {s['cpu_ms']['p99']:.1f}"),
        ("SQP steps", f"{s['steps']['total']} in all, at most {s['steps']['max_per_cycle']} per cycle"),
    ]
    for k, v in rows:
        t.add_row(k, v)
    console.print(t)


