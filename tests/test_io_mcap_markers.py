"""/goal_marker: a catch's target read back from the MCAP (mcap reader + ROS 2 decoder) is at
p0 + v0·t + ½a·t² at every sample stamp; a link via's marker stays at its position; no goals, no topic."""
from __future__ import annotations

import numpy as np

from hoc_cli.goals import FrameResidual, GoalPoint, Goals
from hoc_cli.io.mcap_markers import TOPIC_GOAL_MARKER, goal_tracks
from tests.test_io_mcap import decoded, synthetic, write

P0, V0, A = np.array([0.6, -0.1, 0.2]), np.array([-0.2, 0.3, 3.0]), np.array([0.0, 0.0, -9.81])


def test_the_target_marker_follows_the_ballistic_path_at_every_stamp():
    traj = synthetic(np.random.default_rng(11))
    goals = Goals(final=FrameResidual(None, "tool", P0, velocity=V0, acceleration=A, match_velocity=True),
                  vias=(GoalPoint(0.5, FrameResidual(None, "l2", np.array([0.1, 0.2, 0.3])), "via[0]"),))
    data = write(traj, markers=goal_tracks(goals, "base", traj.t))
    msgs = decoded(data, TOPIC_GOAL_MARKER)
    assert len(msgs) == 2 * traj.K
    x1 = [(t, m) for t, _, m in msgs if m.ns == "x1"]
    via = [m for _, _, m in msgs if m.ns == "via[0]"]
    assert len(x1) == len(via) == traj.K
    for (log_time, m), t in zip(x1, traj.t):
        assert m.header.frame_id == "base" and m.type == 2
        assert m.header.stamp.sec * 10**9 + m.header.stamp.nanosec == log_time
        p = np.array([m.pose.position.x, m.pose.position.y, m.pose.position.z])
        assert np.max(np.abs(p - (P0 + V0 * t + 0.5 * A * t**2))) <= 1e-12
    assert all((m.pose.position.x, m.pose.position.y, m.pose.position.z) == (0.1, 0.2, 0.3) for m in via)


def test_no_goals_no_marker_topic():
    traj = synthetic(np.random.default_rng(12))
    assert decoded(write(traj), TOPIC_GOAL_MARKER) == []
    assert goal_tracks(None, "base", traj.t) == []
