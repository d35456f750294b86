"""The collision scene as one ROS 2 ``visualization_msgs/msg/MarkerArray``, for a plan's MCAP.

Obstacles are drawn in the URDF root frame (box: CUBE; sphere: SPHERE; capsule: a CYLINDER between
two SPHEREs; half-space: a thin 4 m square CUBE on its plane). The robot's collision primitives are
drawn in their link frames with ``frame_locked`` set, so Foxglove's 3D panel moves them with /tf.
Every marker has an infinite lifetime: one message at t = 0 shows the scene for the whole plan.
Namespaces: ``obstacle/<name>`` and ``robot/<link>``. The message is a dict for ``mcap_ros2``'s
writer (``write_mcap``'s ``scene``), whose definition is :func:`marker_array_msgdef`.
"""
from __future__ import annotations

import numpy as np

from hoc_cli.collision.scene import CollisionScene
from hoc_cli.collision.shapes import Box, Capsule, HalfSpace
from hoc_cli.io.ros2_msgdefs import MSGDEFS

MARKER_ARRAY_TYPE = "visualization_msgs/msg/MarkerArray"
CUBE, SPHERE, CYLINDER = 1, 2, 3   # Marker.type
ADD = 0                            # Marker.action
OBSTACLE_COLOR = (0.55, 0.55, 0.6, 0.6)
ROBOT_COLOR = (0.2, 0.8, 0.3, 0.35)
PLANE_SIZE, PLANE_THICKNESS = 4.0, 0.001  # m


def marker_array_msgdef() -> str:
    """The MarkerArray definition as rosbag2 stores it (ROS 2 Humble's, from ``hoc_cli.io.ros2_msgdefs``)."""
    return MSGDEFS[MARKER_ARRAY_TYPE]


def _quaternion(R: np.ndarray) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation matrix (3, 3)."""
    from scipy.spatial.transform import Rotation

    return tuple(float(v) for v in Rotation.from_matrix(R).as_quat())  # type: ignore[return-value]


def _z_to(v: np.ndarray) -> np.ndarray:
    """A rotation (3, 3) taking z to the unit vector along v (identity for v = 0)."""
    n = np.linalg.norm(v)
    if n == 0:
        return np.eye(3)
    z = v / n
    x = np.cross([0.0, 1.0, 0.0] if abs(z[1]) < 0.9 else [1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


def _marker(frame: str, ns: str, index: int, kind: int, center, R, scale, color, locked: bool) -> dict:
    x, y, z, w = _quaternion(np.asarray(R, float))
    r, g, b, a = color
    return {
        "header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": frame},
        "ns": ns, "id": index, "type": kind, "action": ADD,
        "pose": {"position": dict(zip("xyz", (float(v) for v in center))), "orientation": {"x": x, "y": y, "z": z, "w": w}},
        "scale": dict(zip("xyz", (float(v) for v in scale))),
        "color": {"r": r, "g": g, "b": b, "a": a},
        "lifetime": {"sec": 0, "nanosec": 0}, "frame_locked": locked, "points": [], "colors": [],
        "texture_resource": "", "texture": {"header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""}, "format": "",
                                            "data": b""},
        "uv_coordinates": [], "text": "", "mesh_resource": "", "mesh_file": {"filename": "", "data": b""},
        "mesh_use_embedded_materials": False,
    }


def _capsule(frame: str, ns: str, start: int, c: Capsule, color, locked: bool) -> list[dict]:
    d = 2 * c.radius
    out = [_marker(frame, ns, start, SPHERE, c.a, np.eye(3), (d, d, d), color, locked)]
    if not c.is_sphere:
        out.append(_marker(frame, ns, start + 1, SPHERE, c.b, np.eye(3), (d, d, d), color, locked))
        out.append(_marker(frame, ns, start + 2, CYLINDER, (c.a + c.b) / 2, _z_to(c.b - c.a), (d, d, c.length), color,
                           locked))
    return out


def scene_markers(scene: CollisionScene, root_frame: str) -> dict:
    """The MarkerArray message (a dict) of ``scene``'s obstacles (in ``root_frame``) and robot primitives."""
    markers: list[dict] = []
    for o in scene.obstacles:
        ns, p = f"obstacle/{o.name}", o.primitive
        if isinstance(p, Box):
            markers.append(_marker(root_frame, ns, 0, CUBE, p.center, p.rotation, 2 * p.half, OBSTACLE_COLOR, False))
        elif isinstance(p, HalfSpace):
            size = (PLANE_SIZE, PLANE_SIZE, PLANE_THICKNESS)
            centre = p.point - p.normal * PLANE_THICKNESS / 2  # the slab's top face is the plane
            markers.append(_marker(root_frame, ns, 0, CUBE, centre, _z_to(p.normal), size, OBSTACLE_COLOR, False))
        else:
            markers += _capsule(root_frame, ns, 0, p, OBSTACLE_COLOR, False)
    robot = scene.robot
    count: dict[str, int] = {}
    for i, link in enumerate(robot.links):
        c = Capsule(robot.a[i], robot.b[i], float(robot.radius[i]))
        k = count.get(link, 0)
        markers += _capsule(link, f"robot/{link}", k, c, ROBOT_COLOR, True)
        count[link] = k + 3
    return {"markers": markers}
