"""A plan at the output rate, written to the requested outputs (CSV, MCAP, CSV on stdout), each atomically."""
from __future__ import annotations

import io
import json
import sys
from typing import TYPE_CHECKING

from hoc_cli.report.files import OutputTarget, atomic_output
from hoc_cli.trajectory import Trajectory, sample_times

if TYPE_CHECKING:
    from hoc_cli.planner import PlanResult
    from hoc_cli.system import RobotSystem


def write_outputs(targets: list[OutputTarget], traj: Trajectory, *, model, urdf_text: str, task_text: str,
                  metadata: dict[str, str], goals=None, scene=None, clearance=None) -> list[str]:
    """Write ``traj`` to every target; returns the labels written ("-" for stdout).

    ``metadata``: the MCAP's ``hoc`` metadata record beside ``task`` and ``joints`` (``summary_metadata``
    of a plan, the ``simulation`` summary of a replay).
    ``goals`` (``hoc_cli.goals.Goals`` or None): link goals shown on an MCAP's /goal_marker.
    ``scene`` (a MarkerArray message, ``hoc_cli.io.mcap_obstacles``, or None): an MCAP's /collision_scene.
    ``clearance`` ((K,) m or None): an MCAP's /collision_clearance, the smallest pair distance at each sample.
    Each file goes to a temporary file beside its target and is renamed into place only when
    complete, so an interrupted or failed run leaves existing files as they were.
    """
    written = []
    for target in targets:  # each format's writer imported when a file of it is written
        from hoc_cli.io.csv import write_csv

        if target.path is None:
            buf = io.StringIO()
            write_csv(buf, traj)
            sys.stdout.write(buf.getvalue())
            sys.stdout.flush()
        elif target.kind == "csv":
            with atomic_output(target.path) as fh:
                write_csv(fh, traj)
        else:
            from hoc_cli import dynamics
            from hoc_cli.io.mcap import write_mcap

            with atomic_output(target.path) as fh:
                write_mcap(fh, traj, urdf_text=urdf_text, task_text=task_text, metadata=metadata,
                           link_poses=lambda q: dynamics.link_poses(model, q), markers=_markers(goals, urdf_text, traj),
                           locked=model.locked, scene=scene, clearance=clearance)
        written.append(target.label)
    return written


def summary_metadata(summary: dict) -> dict[str, str]:
    """A plan's MCAP metadata: ``summary``, its JSON summary without wall-clock times (``reproducible_summary``)."""
    return {"summary": json.dumps(summary, sort_keys=True, default=float, allow_nan=False)}


def _markers(goals, urdf_text: str, traj: Trajectory) -> list:
    """The /goal_marker tracks of ``goals`` at the samples, in the URDF's root link frame."""
    if goals is None:
        return []
    from hoc_cli.io.mcap import urdf_tf_parents
    from hoc_cli.io.mcap_markers import goal_tracks

    parents = urdf_tf_parents(urdf_text)
    roots = sorted(set(parents.values()) - set(parents))
    return goal_tracks(goals, roots[0] if roots else "", traj.t)


def sample_plan(system: RobotSystem, result: PlanResult, joints, rate: float) -> Trajectory:
    """The plan at the output rate [Hz]: q, q̇, q̈ (K, n) from the Hermite coefficients, u (K, n) by inverse dynamics."""
    t = sample_times(result.mesh.T, rate)
    q, dq, ddq = result.mesh.evaluate_all(result.coeffs, t)
    u = system.inverse_dynamics(q, dq, ddq)
    return Trajectory(joints=tuple(joints), t=t, q=q, dq=dq, ddq=ddq, u=u, mesh=result.mesh, coeffs=result.coeffs)
