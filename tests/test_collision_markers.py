"""The collision scene as a MarkerArray: written with mcap_ros2 and decoded back, every obstacle and robot primitive
is where the scene says (boxes, spheres, capsules as cylinder + end spheres, half-spaces as a slab)."""
from __future__ import annotations

import io

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer
from scipy.spatial.transform import Rotation

from hoc_cli.collision.geometry import Shape
from hoc_cli.collision.robot import robot_geometry
from hoc_cli.collision.scene import Obstacle, collision_scene
from hoc_cli.collision.shapes import Box, Capsule, HalfSpace, sphere
from hoc_cli.io.mcap import TOPIC_COLLISION_SCENE
from hoc_cli.io.mcap_obstacles import MARKER_ARRAY_TYPE, marker_array_msgdef, scene_markers
from hoc_cli.model import load_robot
from tests._robots import ROBOTS


def roundtrip(message: dict):
    buf = io.BytesIO()
    w = Writer(buf)
    schema = w.register_msgdef(MARKER_ARRAY_TYPE, marker_array_msgdef())
    w.write_message(TOPIC_COLLISION_SCENE, schema, message, log_time=0, publish_time=0)
    w.finish()
    buf.seek(0)
    (_, _, raw, decoded), = list(make_reader(buf, decoder_factories=[DecoderFactory()]).iter_decoded_messages())
    typesys = pytest.importorskip("rosbags.typesys")
    for store in (typesys.Stores.ROS2_HUMBLE, typesys.Stores.ROS2_JAZZY):  # what a Humble or Jazzy subscriber decodes
        ts = typesys.get_typestore(store)
        msg = ts.deserialize_cdr(raw.data, MARKER_ARRAY_TYPE)
        assert len(msg.markers) == len(decoded.markers) and ts.serialize_cdr(msg, MARKER_ARRAY_TYPE) == raw.data
    return decoded.markers


def z_axis(m) -> np.ndarray:
    o = m.pose.orientation
    return Rotation.from_quat([o.x, o.y, o.z, o.w]).as_matrix()[:, 2]


def test_every_obstacle_and_robot_primitive_is_drawn_where_the_scene_has_it():
    model = load_robot(ROBOTS / "lbr7.urdf")
    robot = robot_geometry(model, {}, {
        "lbr_link_4": [Shape("capsule", np.eye(4), radius=0.05, a=np.array([0, 0, 0.03]), b=np.array([0.1, 0, 0.15]))],
        "lbr_link_6": [Shape("sphere", np.eye(4), radius=0.06)]})
    R = Rotation.from_euler("xyz", [0.3, -0.2, 1.0]).as_matrix()
    obstacles = [Obstacle("table", Box(np.array([0.6, 0, 0.2]), R, np.array([0.4, 0.5, 0.02]))),
                 Obstacle("ball", sphere([0.3, 0.3, 0.5], 0.1)),
                 Obstacle("bar", Capsule(np.array([0.0, 0, 0]), np.array([0.0, 0.3, 0.4]), 0.02)),
                 Obstacle("floor", HalfSpace(np.array([0, 0, -0.1]), np.array([0, 0, 1.0])))]
    markers = roundtrip(scene_markers(collision_scene(model, robot, obstacles), "lbr_link_0"))
    by = {}
    for m in markers:
        by.setdefault(m.ns, []).append(m)
    (table,) = by["obstacle/table"]
    assert table.type == 1 and table.header.frame_id == "lbr_link_0" and not table.frame_locked
    o = table.pose.orientation
    assert np.allclose(Rotation.from_quat([o.x, o.y, o.z, o.w]).as_matrix(), R)
    assert (table.scale.x, table.scale.y, table.scale.z) == (0.8, 1.0, 0.04)
    (ball,) = by["obstacle/ball"]
    assert ball.type == 2 and ball.scale.x == 0.2 and (ball.pose.position.x, ball.pose.position.z) == (0.3, 0.5)
    bar = {m.type: m for m in by["obstacle/bar"]}
    assert len(by["obstacle/bar"]) == 3 and np.allclose(z_axis(bar[3]), [0, 0.6, 0.8]) and bar[3].scale.z == 0.5
    (floor,) = by["obstacle/floor"]
    assert np.allclose(z_axis(floor), [0, 0, 1]) and floor.pose.position.z + floor.scale.z / 2 == -0.1
    arm = by["robot/lbr_link_4"]
    assert len(arm) == 3 and all(m.header.frame_id == "lbr_link_4" and m.frame_locked for m in arm)
    assert len({m.id for m in arm}) == 3
    (wrist,) = by["robot/lbr_link_6"]
    assert wrist.type == 2 and wrist.scale.x == 0.12
