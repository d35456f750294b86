"""``hoc simulate SOURCE``: integrate the motion forward from x0 under a torque history.

SOURCE is a task YAML or a plan's MCAP file (written by ``hoc plan``).

Torque history, first that applies:
1. ``--torque FILE``: a plan's CSV (``u.<joint>`` columns, interpolated in time by a C² cubic
   spline, not-a-knot) or MCAP (its exact Hermite coefficients when attached, u(t) = ID(q_h, q̇_h,
   q̈_h); else its ``effort`` samples, interpolated as for CSV). The file must cover [0, T] and
   name the task's joints (any column order).
2. An MCAP SOURCE's own plan, as in 1.
3. The task's ``torque:`` key (``zero`` or one constant per joint).

``--integrator hermite`` (default): the paper's collocation integrator with the task's N and order
(``hoc_cli.simulate.simulate_hermite``; an element whose Newton iteration fails is solved as 2, 4, …
sub-elements and the summary's ``subdivided`` says so); ``--integrator rk``: scipy's DOP853,
rtol = atol = 1e-12. ``--tol`` sets the Newton tolerance (hermite) or rtol = atol (rk), ``--max-iter``
the Newton iterations per element (hermite); the task's ``solver:`` keys are the planner's and are not
used. ``--method`` is the deprecated spelling of ``--integrator``.

Outputs as for ``hoc plan``: ``-o`` CSV/MCAP (default, for every SOURCE: ``<source stem>-sim.mcap``
and ``<source stem>-sim.csv``, so a plan's ``<stem>.mcap``/``.csv`` is never overwritten; an output
that is the same file as an input is refused), samples at ``output.rate``; ``u`` is the applied
torque u(t). The MCAP carries the simulation's Hermite
coefficients (hermite method) and a ``simulation`` metadata entry (the JSON summary).

``--json`` summary: ``integrator`` (and ``method``, the same, for one release), ``joints``, ``N``, ``order``, ``T``, ``torque`` (its source),
``final_state`` {q, dq} at T, ``final_error`` (max |x(T) − x1|, when the task has x1; else null),
``check`` (with ``--check``): {tol, miss (= final_error), explained (the miss the replay's own Newton
tolerance, rounding and torque representation can cause, carried to T by its linearisation), bound
(tol + explained), resolved (explained within the linearisation's reach, ``LINEAR_LIMIT``), passed
(resolved and miss <= bound), amplification (max ‖Φ(T, t)‖∞), explained_parts,
linearised_about (plan | replay)}, ``converged``, ``iterations`` (Newton steps or RK
steps), ``subdivided`` (hermite: [{element, t, sub_elements}]), ``evaluations`` (dynamics calls), ``wall_time_s`` (the integration alone), ``max_abs_u``,
``limit_violations``, ``outputs``. Exit 1 when ``--check TOL`` is given and final_error > TOL + explained, or the
replay cannot resolve x1.
"""
from __future__ import annotations

import json
import math
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from hoc_cli.commands.common import EXIT_OK, EXIT_UNMET, refuse_urdf_task
from hoc_cli.errors import InputFileError, OutputError, TaskError
from hoc_cli.io.robot import load_model
from hoc_cli.io.task import Task, apply_overrides, load_task, load_yaml, parse_task, resolve, yaml_error_detail
from hoc_cli.report.console import stderr_console, warn, warn_limit_violations
from hoc_cli.report.files import output_transaction, parse_outputs, refuse_inputs
from hoc_cli.report.inputs import check_columns, check_sample_times, read_urdf_text
from hoc_cli.report.jsonio import json_ready, print_json, validate_json
from hoc_cli.report.outputs import write_outputs

METHODS = ("hermite", "rk")


def run(
    source: Path,
    outputs: list[str] | None = None,
    as_json: bool = False,
    quiet: bool = False,
    progress: bool = False,
    overrides: dict | None = None,
    integrator: str | None = None,
    torque: Path | None = None,
    check: float | None = None,
    tol: float | None = None,
    max_iter: int | None = None,
    method: str | None = None,
) -> int:
    from hoc_cli import simulate as sim
    from hoc_cli import torque as torque_sources
    from hoc_cli.elements import HermiteMesh
    from hoc_cli.reference_integrator import simulate_reference
    from hoc_cli.system import RobotSystem
    from hoc_cli.trajectory import sample_times

    source = Path(source)
    method = _integrator(integrator, method)
    if tol is not None and not (math.isfinite(tol) and tol > 0):
        raise TaskError(f"expected a tolerance > 0, got {tol!r}", key="--tol")
    if max_iter is not None and max_iter < 1:
        raise TaskError(f"expected an integer >= 1, got {max_iter!r}", key="--max-iter")
    if max_iter is not None and method != "hermite":
        raise TaskError("sets the Newton iterations of --integrator hermite; rk has none (expected no --max-iter "
                        "with --integrator rk)", key="--max-iter")
    if check is not None and not (math.isfinite(check) and check > 0):
        raise TaskError(f"expected a tolerance > 0, got {check!r}", key="--check")

    with tempfile.TemporaryDirectory(prefix="hoc-simulate-") as scratch:
        plan = None
        labels: dict[str, str] = {}
        if source.suffix.lower() == ".csv":
            raise InputFileError("a CSV cannot be the simulation source (expected a task YAML or a plan's MCAP); "
                                 "give a torque CSV with --torque", file=source)
        if source.suffix.lower() == ".mcap":
            from hoc_cli.io.mcap import read_plan

            plan = read_plan(source)
            task = _task_from_plan(plan, source, Path(scratch))
            urdf_text = plan.urdf_text
            labels = {"urdf_label": f"{source}: attachment robot.urdf", "task_label": f"{source}: attachment task.yaml"}
        else:
            refuse_urdf_task(source)
            task = load_task(source, purpose="simulate")
            urdf_text = ""
        task = apply_overrides(task, **(overrides or {}))
        if plan is None and task.time.free is not None and torque is not None \
                and Path(torque).suffix.lower() in (".csv", ".mcap"):
            # a free-T task replayed with a plan's torques: the plan's T (its mesh's, or the last sample time)
            task = apply_overrides(task, T=_torque_duration(Path(torque)))
        targets = parse_outputs(outputs, f"{source.stem}-sim")  # never a plan's <stem>.csv/.mcap
        refuse_inputs(targets, {"the simulation source": source, "the URDF": None if plan else task.robot,
                                "--torque": torque})
        if as_json and any(t.path is None for t in targets):
            raise OutputError("'-o -' writes CSV to standard output, which --json needs for the summary", key="--output")
        if check is not None and task.x1 is None:
            raise TaskError("--check needs a goal state x1 in the task", file=task.path, key="x1")
        check_sample_times(targets, task.T, task.rate, file=labels.get("task_label", task.path))
        if plan is None and any(t.kind == "mcap" for t in targets):
            urdf_text = read_urdf_text(task.robot)  # stored in MCAP outputs

        model = load_model(task, **labels)
        check_columns(targets, model.joint_names)
        system = RobotSystem(model)
        joints = tuple(model.joint_names)
        states = resolve(task, joints)

        if torque is not None:
            history, described = _torque_file(Path(torque), system, joints, task.T)
        elif plan is not None:
            history, described = _torque_from_plan(plan, source, system, joints, task.T)
        elif states.torque is not None:
            history = torque_sources.ConstantTorque(states.torque)
            described = "zero" if not np.any(states.torque) else "constant"
        else:
            raise TaskError("no torque history: give torque: (zero or a list) in the task, or --torque FILE",
                            file=task.path, key="torque")

        console = stderr_console(quiet=quiet, progress=progress)
        mesh = HermiteMesh(task.order, task.T, task.N)
        planned = plan.trajectory.mesh if plan is not None else None
        if planned is not None and not planned.uniform and (planned.order, planned.T, planned.N) == (
                mesh.order, mesh.T, mesh.N):
            mesh = planned  # replay an N: auto plan on its own non-uniform mesh
        if method == "hermite":
            with _progress(console, task.N, progress) as tick:
                result = sim.simulate_hermite(system, states.q0, states.dq0, history, mesh, callback=tick,
                                              xtol=sim.NEWTON_XTOL if tol is None else tol,
                                              max_iter=sim.NEWTON_MAX_ITER if max_iter is None else max_iter)
            iterations, evaluations = result.newton_iterations, result.evaluations
            tn = mesh.nodes
            subdivided = [{"element": e, "t": [float(tn[e]), float(tn[e + 1])], "sub_elements": k}
                          for e, k in result.subdivided]
        else:
            rtol = 1e-12 if tol is None else tol
            result = simulate_reference(system, states.q0, states.dq0, history, task.T, rtol=rtol, atol=rtol)
            iterations, evaluations = result.steps, result.nfev
            subdivided = []
        qT, dqT = result.final_state()
        traj = sim.sample(result, system, history, sample_times(task.T, task.rate), joints)

        final_error = None
        if states.q1 is not None:
            final_error = float(max(np.max(np.abs(qT - states.q1)), np.max(np.abs(dqT - states.dq1))))
        summary: dict[str, Any] = json_ready({
            "integrator": method,
            "method": method,
            "source": str(source),
            "torque": described,
            "joints": list(joints),
            "N": task.N if method == "hermite" else None,
            "order": task.order if method == "hermite" else None,
            "T": task.T,
            "converged": True,
            "iterations": iterations,
            "evaluations": evaluations,
            "subdivided": subdivided,
            "wall_time_s": result.wall_time_s,
            "message": result.message,
            "final_state": {"q": qT.tolist(), "dq": dqT.tolist()},
            "final_error": final_error,
            "max_abs_u": np.max(np.abs(traj.u), axis=0).tolist(),
            "limit_violations": _limit_violations(model, traj),
            "outputs": [t.label for t in targets],
        })  # a non-finite value (a diverged state) is null: the summary is always valid JSON
        passed = True
        if check is not None:
            summary["check"] = _check(check, final_error, system, mesh, result, history, plan, method, tol)
            passed = summary["check"]["passed"]
        validate_json(summary)  # before any output is written

        # no wall-clock time in the file: the same inputs give the same bytes
        stored = {k: v for k, v in summary.items() if k not in ("outputs", "wall_time_s")}
        with output_transaction():  # every output is replaced, or none
            write_outputs(targets, traj, model=model, urdf_text=urdf_text, task_text=task.text,
                          metadata={"simulation": json.dumps(stored, allow_nan=False)})
    warn_limit_violations(summary["limit_violations"])

    if as_json:
        print_json(summary)
    elif not quiet and (progress or console.is_terminal):
        _human(console, summary)
    if not passed:
        c = summary["check"]
        miss = "no x1" if final_error is None else f"{final_error:.3g}"
        if c.get("explained") is not None and not c["resolved"]:
            sys.stderr.write(f"hoc: check failed: the replay cannot resolve x1: its own errors could move the final "
                             f"state by {c['explained']:.3g} (the dynamics amplify them up to {c['amplification']:.3g} "
                             f"times); it misses x1 by {miss}\n")
        else:
            explained = "" if c.get("explained") is None else (
                f" + {c['explained']:.3g} (what the replay's own errors explain, amplified up to "
                f"{c['amplification']:.3g} times by the dynamics)")
            sys.stderr.write(f"hoc: check failed: the final state misses x1 by {miss} > {check:g}{explained}\n")
        return EXIT_UNMET
    return EXIT_OK


def _check(tol: float, miss: float | None, system, mesh, result, history, plan, method: str, newton_tol: float | None) -> dict:
    """``--check``: the miss beside what the replay's own errors explain (``hoc_cli.replay_sensitivity``).

    Passes when miss <= tol + explained: explained is the largest change of x(T) that the
    integrator's tolerance and rounding and the torque history's representation error can cause,
    carried to T by the replay's linearisation along the plan (or, without one, the replay itself).
    """
    from hoc_cli import simulate as sim
    from hoc_cli.replay_sensitivity import LINEAR_LIMIT, collocation_residuals, replay_sensitivity, representation_error

    out: dict[str, Any] = {"tol": tol, "miss": miss}
    if miss is None or not math.isfinite(miss):
        return {**out, "passed": False, "explained": None}
    tr = plan.trajectory if plan is not None else None
    if tr is not None and tr.mesh == mesh and tr.coeffs is not None:
        coeffs, reference = np.asarray(tr.coeffs, dtype=float), "plan"
    elif method == "hermite":
        coeffs, reference = result.coeffs, "replay"
    else:  # the RK solution at the nodes (q̈ from the forward dynamics for quintic elements)
        q, dq = result.state(mesh.nodes)
        nodes = [q, dq] + ([system.forward_dynamics(q, dq, history(mesh.nodes))] if mesh.m == 3 else [])
        coeffs, reference = np.stack(nodes, axis=1), "replay"
    points = result.points if method == "hermite" else sim.collocation_points(mesh.order)
    with np.errstate(all="ignore"):
        sens = replay_sensitivity(system, mesh, coeffs, points, history)
        parts = {"rounding": sens.rounding_bound(),
                 "torque_representation": sens.torque_bound(representation_error(history, mesh, points))}
        if method == "hermite":  # the residual Newton left; an element it subdivided: its stopping test
            split = np.array([e for e, _ in result.subdivided], dtype=int)
            residual = collocation_residuals(system, mesh, result.coeffs, points, history)
            residual[split] = 0.0
            parts["newton"] = sens.torque_bound(residual) + (
                sens.newton_bound(sim.NEWTON_XTOL if newton_tol is None else newton_tol, split) if split.size else 0.0)
        else:  # DOP853 keeps each step's local error near rtol (1 + |x|); steps spread over the elements
            rtol = 1e-12 if newton_tol is None else newton_tol
            size = np.max(np.abs(coeffs[1:, :2]), axis=(1, 2))
            parts["integration"] = sens.state_bound(rtol * (1.0 + size) * max(1.0, result.steps / mesh.N))
    explained = float(sum(parts.values()))
    if not math.isfinite(explained):
        return {**out, "passed": False, "explained": None}
    resolved = explained <= LINEAR_LIMIT * (1.0 + float(np.max(np.abs(coeffs[-1, :2]))))
    return {**out, "passed": bool(resolved and miss <= tol + explained), "explained": explained,
            "bound": tol + explained, "resolved": bool(resolved), "amplification": sens.amplification,
            "explained_parts": parts, "linearised_about": reference}


def _integrator(integrator: str | None, method: str | None) -> str:
    """The integrator from ``--integrator``, or from the deprecated ``--method`` (with a note on stderr)."""
    if method is not None:
        if integrator is not None and integrator != method:
            raise TaskError(f"--integrator {integrator} and the deprecated --method {method} disagree (expected "
                            "--integrator alone)", key="--method")
        warn("simulate --method is deprecated and will be removed in the next release; use --integrator "
             f"{method}")
    chosen = integrator if integrator is not None else (method if method is not None else "hermite")
    if chosen not in METHODS:
        raise TaskError(f"expected one of {', '.join(METHODS)}, got {chosen!r}",
                        key="--integrator" if integrator is not None else "--method")
    return chosen


# --------------------------------------------------------------------------- sources
def _task_from_plan(plan, source: Path, scratch: Path) -> Task:
    """The task stored in a plan's MCAP, with ``robot`` pointing at the URDF attached to it."""
    urdf = scratch / "robot.urdf"
    urdf.write_text(plan.urdf_text, encoding="utf-8")
    try:
        doc = load_yaml(plan.task_text)
    except yaml.YAMLError as exc:
        raise InputFileError(f"the task attached to this plan is not valid YAML{yaml_error_detail(exc)}",
                             file=source) from None
    if not isinstance(doc, dict):
        raise InputFileError("the task attached to this plan is not a mapping of task keys", file=source)
    doc = dict(doc, robot=str(urdf))
    tr = plan.trajectory
    if tr.mesh is not None and tr.coeffs is not None:
        # replay on the plan's own mesh (its T may have been free, its N auto or overridden with -N), and
        # where its goal was a link pose, check against the joint state the plan reached
        doc.pop("accuracy", None)
        doc.update(T=tr.mesh.T, N=tr.mesh.N, order=tr.mesh.order)
        if isinstance(doc.get("x1"), dict) and "link" in doc["x1"]:
            C = np.asarray(tr.coeffs)
            doc["x1"] = {"q": [float(v) for v in tr.mesh.evaluate(C, np.array([tr.mesh.T]), 0)[0]],
                         "dq": [float(v) for v in tr.mesh.evaluate(C, np.array([tr.mesh.T]), 1)[0]]}
    try:
        return parse_task(doc, path=source, text=plan.task_text, purpose="simulate")
    except TaskError as exc:
        raise InputFileError(f"the attached task is invalid: {exc.key or ''} {exc.detail}".strip(), file=source) from None


def _columns(file: Path, have: tuple[str, ...], joints: tuple[str, ...]) -> list[int]:
    """Index of each task joint among a file's joints; InputFileError when they differ."""
    if set(have) != set(joints):
        raise InputFileError(
            f"torque columns name joints {', '.join(have)}; the task's joints are {', '.join(joints)}", file=file
        )
    return [have.index(j) for j in joints]


def _torque_duration(file: Path) -> float:
    """The duration [s] of a torque CSV (its last sample time) or plan MCAP (its mesh's T, else its last sample
    time): a free-T task's duration when it is simulated with it.
    """
    if file.suffix.lower() == ".mcap":
        from hoc_cli.io.mcap import read_plan

        traj = read_plan(file).trajectory
        if traj.mesh is not None:
            return float(traj.mesh.T)
    else:
        from hoc_cli.io.csv import read_csv

        traj = read_csv(file)
    if traj.K < 2 or not traj.t[-1] > 0:
        raise InputFileError("needs at least 2 samples ending at t > 0 to give a free-T task its duration", file=file,
                             key="--torque")
    return float(traj.t[-1])


def _check_span(file: Path, t: np.ndarray, T: float) -> None:
    slack = 1e-9 * max(1.0, T)
    if t[0] > slack or t[-1] < T - slack:
        raise InputFileError(
            f"torque samples cover t = {t[0]:g} … {t[-1]:g} s; the simulation needs 0 … {T:g} s", file=file
        )


def _torque_file(file: Path, system, joints: tuple[str, ...], T: float):
    """A ``--torque`` CSV or MCAP as a torque source and a one-word description."""
    suffix = file.suffix.lower()
    if suffix == ".csv":
        from hoc_cli.io.csv import read_csv

        traj = read_csv(file)
        return _sampled_torque(traj, file, _columns(file, tuple(traj.joints), joints), T), "csv"
    if suffix == ".mcap":
        from hoc_cli.io.mcap import read_plan

        return _torque_from_plan(read_plan(file), file, system, joints, T)
    raise InputFileError(f"unknown torque file extension {suffix or '(none)'!r} (expected .csv or .mcap)", file=file,
                         key="--torque")


def _torque_from_plan(plan, file: Path, system, joints: tuple[str, ...], T: float):
    from hoc_cli import torque as torque_sources

    traj = plan.trajectory
    cols = _columns(file, tuple(traj.joints), joints)
    if traj.mesh is not None and traj.coeffs is not None:
        if traj.mesh.T < T * (1 - 1e-12):
            raise InputFileError(f"the plan lasts {traj.mesh.T:g} s; the simulation needs {T:g} s", file=file)
        return torque_sources.PlannedTorque(system, traj.mesh, np.asarray(traj.coeffs)[:, :, cols]), "plan (exact Hermite)"
    return _sampled_torque(traj, file, cols, T), "plan (sampled)"


def _sampled_torque(traj, file: Path, cols, T: float):
    """The torques u of a sampled trajectory's columns ``cols``, interpolated; at least 2 samples spanning [0, T]."""
    from hoc_cli import torque as torque_sources

    if traj.K < 2:
        raise InputFileError("needs at least 2 samples to interpolate a torque history", file=file)
    _check_span(file, traj.t, T)
    return torque_sources.SampledTorque(traj.t, traj.u[:, cols])


# --------------------------------------------------------------------------- outputs
def _limit_violations(model, traj) -> list[dict]:
    """URDF position, velocity and effort limits exceeded: joint, kind, worst value."""
    out = []
    checks = (("position", traj.q, model.lower, model.upper), ("velocity", traj.dq, -model.velocity_limit, model.velocity_limit),
              ("effort", traj.u, -model.effort_limit, model.effort_limit))
    for kind, x, lo, hi in checks:
        for i, joint in enumerate(model.joint_names):
            below, above = x[:, i] < lo[i], x[:, i] > hi[i]
            if below.any() or above.any():
                worst = x[:, i][np.argmax(np.where(above, x[:, i] - hi[i], lo[i] - x[:, i]))]
                out.append({"joint": joint, "kind": kind, "worst": float(worst)})
    return out


class _progress:
    """A rich progress bar over elements on standard error (terminal or ``--progress`` only)."""

    def __init__(self, console, total: int, force: bool) -> None:
        self.console, self.total = console, total
        self.enabled = not console.quiet and (force or console.is_terminal)
        self.bar = None

    def __enter__(self):
        if not self.enabled:
            return None
        from rich.progress import Progress

        self.bar = Progress(console=self.console, transient=True)
        self.bar.start()
        task = self.bar.add_task("simulating", total=self.total)
        return lambda e, N: self.bar.update(task, completed=e + 1)

    def __exit__(self, *exc) -> None:
        if self.bar is not None:
            self.bar.stop()


def _human(console, s: dict) -> None:
    """The human summary on standard error (terminal or ``--progress`` only, as the spec asks)."""
    def say(text: str) -> None:
        console.print(text, soft_wrap=True, markup=False, highlight=False)  # paths may hold [ ]

    what = f"{s['method']}" + (f", {s['N']} {s['order']} elements" if s["method"] == "hermite" else "")
    say(f"simulated {s['T']:g} s ({what}; torque: {s['torque']}) in {s['wall_time_s']:.3g} s: {s['message']}")
    say(f"final q  = {s['final_state']['q']}")
    say(f"final dq = {s['final_state']['dq']}")
    if s["final_error"] is not None:
        say(f"final error against x1: {s['final_error']:.3g}")
    c = s.get("check")
    if c and c.get("explained") is not None:
        say(f"check: miss {c['miss']:.3g} {'<=' if c['miss'] <= c['bound'] else '>'} {c['tol']:g} + {c['explained']:.3g} explained by the replay's own errors "
            f"(amplified up to {c['amplification']:.3g} times by the dynamics): {'passed' if c['passed'] else 'failed'}")
    for path in s["outputs"]:
        if path != "-":
            say(f"wrote {path}")
