"""The /goal_marker topic of a plan's MCAP: where a goal is at each sample, as ROS 2
``visualization_msgs/msg/Marker`` spheres (the Humble definition) in the root frame (Foxglove's 3D panel shows them beside /tf).

A ``MarkerTrack`` is one goal: a label (the marker's namespace, e.g. "x1" or "via[0]"), the root
frame's name and the positions (K, 3) [m] at the plan's K sample times (a moving target:
p0 + v0·t + ½a·t²; a fixed goal: the same point at every sample). The writer is ``write_mcap``'s
``markers`` argument (``hoc_cli.io.mcap``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TOPIC_GOAL_MARKER = "/goal_marker"
MARKER_TYPE = "visualization_msgs/msg/Marker"
SPHERE, ADD = 2, 0  # Marker.type, Marker.action
DIAMETER = 0.05  # m
COLORS = ((1.0, 0.45, 0.0, 0.9), (0.1, 0.6, 1.0, 0.9))  # the final goal orange, vias blue


@dataclass(frozen=True, eq=False)
class MarkerTrack:
    """A goal's position at each sample: ``label`` (namespace), ``frame`` (root link), points (K, 3) [m]."""

    label: str
    frame: str
    points: np.ndarray


def marker_message(track: MarkerTrack, index: int, k: int, stamp: dict) -> dict:
    """The Marker (a dict for the ROS 2 writer) of ``track`` at sample k; ``index`` is the marker id."""
    x, y, z = (float(v) for v in track.points[k])
    r, g, b, a = COLORS[0 if track.label == "x1" else 1]
    return {
        "header": {"stamp": stamp, "frame_id": track.frame},
        "ns": track.label, "id": index, "type": SPHERE, "action": ADD,
        "pose": {"position": {"x": x, "y": y, "z": z}, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
        "scale": {"x": DIAMETER, "y": DIAMETER, "z": DIAMETER},
        "color": {"r": r, "g": g, "b": b, "a": a},
        "lifetime": {"sec": 0, "nanosec": 0}, "frame_locked": False, "points": [], "colors": [],
        "texture_resource": "", "texture": {"header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""}, "format": "", "data": b""},
        "uv_coordinates": [], "text": "", "mesh_resource": "", "mesh_file": {"filename": "", "data": b""},
        "mesh_use_embedded_materials": False,
    }


def goal_tracks(goals, frame: str, t: np.ndarray) -> list[MarkerTrack]:
    """One track per link goal of ``goals`` (``hoc_cli.goals.Goals``): x1's target at the sample times
    t (K,) [s] (its position p0 + v0·t + ½a·t²), each link via's fixed position.
    """
    t = np.asarray(t, float)
    tracks = []
    if goals is None:
        return tracks
    if goals.final is not None:
        tracks.append(MarkerTrack("x1", frame, np.stack([goals.final.target(ti)[0] for ti in t])))
    for gp in goals.vias:
        if hasattr(gp.residual, "link"):
            tracks.append(MarkerTrack(gp.label, frame, np.tile(np.asarray(gp.residual.position, float), (t.size, 1))))
    return tracks
