"""A closed-loop catch (``hoc catch``) as an MCAP file: the arm's executed motion on /joint_states and /tf, the true
ball and its estimate as /goal_marker tracks ("ball", "estimate"), the scenario and the summary in the metadata.

The executed motion is sampled at ``SAMPLES_PER_SECOND`` from the plans in force (``CatchRun.executed``), its
torques by inverse dynamics; the writer is ``hoc_cli.io.mcap.write_mcap``.
"""
from __future__ import annotations

from typing import IO

import numpy as np

from hoc_cli.io.mcap import urdf_tf_parents, write_mcap
from hoc_cli.io.mcap_markers import MarkerTrack
from hoc_cli.realtime.replanner import Target
from hoc_cli.trajectory import Trajectory

SAMPLES_PER_SECOND = 400.0


def write_catch_mcap(fh: IO[bytes], run, throw, *, model, system, link: str, urdf_text: str, scenario_text: str,
                     summary: str, nominal: Target) -> None:
    """Write the run (``hoc_cli.realtime.loop.CatchRun``) of the true ``throw`` to the binary stream ``fh``."""
    from hoc_cli import dynamics

    t, q, dq, ddq = run.executed(per_cycle=1, rate=SAMPLES_PER_SECOND)
    u = system.inverse_dynamics(q, dq, ddq)
    traj = Trajectory(joints=tuple(model.joint_names), t=t, q=q, dq=dq, ddq=ddq, u=u)
    parents = urdf_tf_parents(urdf_text)
    roots = sorted(set(parents.values()) - set(parents))
    frame = roots[0] if roots else ""
    ball, _ = throw.states(t)
    markers = [MarkerTrack("ball", frame, np.asarray(ball)), MarkerTrack("estimate", frame, run.estimates(t, nominal))]
    write_mcap(fh, traj, urdf_text=urdf_text, task_text=scenario_text, metadata={"summary": summary},
               link_poses=lambda x: dynamics.link_poses(model, x), markers=markers, locked=model.locked)
