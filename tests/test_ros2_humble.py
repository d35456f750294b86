"""ROS 2 Humble and Jazzy read hoc's MCAP: every message of written plans decoded by rosbags with its
own Humble and Jazzy type stores (``deserialize_cdr``, not the file's embedded schema), the schemas
equal to those stores field by field, QoS metadata that rosbags parses, fixed and locked joints once
on /tf_static, and /joint_states naming every non-fixed URDF joint (locked and mimic ones included)."""
from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from hoc_cli.cli import app
from hoc_cli.io.ros2_msgdefs import MSGDEFS

rosbags_typesys = pytest.importorskip("rosbags.typesys")
Stores, get_typestore, get_types_from_msg = (rosbags_typesys.Stores, rosbags_typesys.get_typestore,
                                            rosbags_typesys.get_types_from_msg)
STORES = {"humble": get_typestore(Stores.ROS2_HUMBLE), "jazzy": get_typestore(Stores.ROS2_JAZZY)}
ROOT = Path(__file__).resolve().parent.parent

# two_link.urdf with a locked wrist, a prismatic finger and a finger that mimics it (mirrored)
HAND = """
  <link name="hand"><inertial><mass value="0.2"/><inertia ixx="1e-3" ixy="0" ixz="0" iyy="1e-3" iyz="0" izz="1e-3"/></inertial></link>
  <link name="finger_l"><inertial><mass value="0.05"/><inertia ixx="1e-5" ixy="0" ixz="0" iyy="1e-5" iyz="0" izz="1e-5"/></inertial></link>
  <link name="finger_r"><inertial><mass value="0.05"/><inertia ixx="1e-5" ixy="0" ixz="0" iyy="1e-5" iyz="0" izz="1e-5"/></inertial></link>
  <joint name="wrist" type="revolute"><parent link="tool"/><child link="hand"/><axis xyz="1 0 0"/>
    <limit lower="-3" upper="3" effort="10" velocity="5"/></joint>
  <joint name="finger" type="prismatic"><parent link="hand"/><child link="finger_l"/><axis xyz="0 1 0"/>
    <limit lower="0" upper="0.04" effort="10" velocity="1"/></joint>
  <joint name="finger_mirror" type="prismatic"><parent link="hand"/><child link="finger_r"/><axis xyz="0 1 0"/>
    <limit lower="-0.04" upper="0" effort="10" velocity="1"/><mimic joint="finger" multiplier="-1" offset="0.001"/></joint>
</robot>
"""
TASKS = {
    "plain": "",
    "goal": "x1: {link: tool, position: [1.0, 0.0, 1.2], dq: zero}\n",
    "locked": "joints: [shoulder, elbow]\nlocked: {wrist: 0.4, finger: 0.01}\n",
    "collision": ("collision: {mode: check, robot: {tool: [{sphere: {radius: 0.05}}]},\n"
                  "            obstacles: [{name: ball, sphere: {radius: 0.1}, position: [0.0, 1.0, 0.0]}]}\n"),
}
NON_FIXED = {"plain": ["shoulder", "elbow"], "goal": ["shoulder", "elbow"], "collision": ["shoulder", "elbow"],
             "locked": ["shoulder", "elbow", "wrist", "finger", "finger_mirror"]}
HELD = {"locked": {"wrist": 0.4, "finger": 0.01, "finger_mirror": -0.01 + 0.001}}
STATIC_CHILDREN = {"plain": {"tool"}, "goal": {"tool"}, "collision": {"tool"}, "locked": {"tool", "hand", "finger_l", "finger_r"}}


def test_every_schema_hoc_writes_is_the_humble_and_jazzy_definition_field_by_field():
    for name, text in MSGDEFS.items():
        types = get_types_from_msg(text, name)
        assert name in types
        for store in STORES.values():
            for t, (_, fields) in types.items():
                assert store.fielddefs[t][1] == fields, (name, t)
    marker = dict(get_types_from_msg(MSGDEFS["visualization_msgs/msg/Marker"], "visualization_msgs/msg/Marker"))
    names = [f for f, _ in marker["visualization_msgs/msg/Marker"][1]]
    assert {"texture_resource", "texture", "uv_coordinates", "mesh_file", "mesh_use_embedded_materials"} <= set(names)


@pytest.fixture(scope="module")
def plans(tmp_path_factory):
    """(kind → MCAP bytes) of three plans: a joint-space task, a link goal, locked and mimic joints."""
    d = tmp_path_factory.mktemp("ros2")
    urdf = (ROOT / "robots" / "two_link.urdf").read_text()
    (d / "arm.urdf").write_text(urdf)
    (d / "hand.urdf").write_text(urdf.replace("</robot>", HAND))
    base = (ROOT / "configs" / "two_link.yaml").read_text().replace("../robots/two_link.urdf", "arm.urdf")
    base = base.replace("N: 16", "N: 6").replace("output: {rate: 100}", "output: {rate: 20}")
    out = {}
    for kind, extra in TASKS.items():
        text = base.replace("arm.urdf", "hand.urdf") if kind == "locked" else base
        if kind == "goal":
            text = text.replace("x1: {q: [1.2, -0.6], dq: [0.0, 0.0]}\n", extra)
        else:
            text += extra
        (d / f"{kind}.yaml").write_text(text)
        r = CliRunner().invoke(app, ["plan", str(d / f"{kind}.yaml"), "-o", str(d / f"{kind}.mcap"), "-q"])
        assert r.exit_code == 0, r.output
        out[kind] = (d / f"{kind}.mcap").read_bytes()
    return out


def raw_messages(data: bytes):
    from mcap.reader import make_reader

    reader = make_reader(io.BytesIO(data))
    return list(reader.iter_messages()), reader.get_summary()


@pytest.mark.parametrize("kind", list(TASKS))
def test_every_message_decodes_with_the_humble_and_jazzy_type_stores(plans, kind):
    messages, _ = raw_messages(plans[kind])
    topics = {c.topic for _, c, _ in messages}
    expected = {"/robot_description", "/joint_states", "/joint_accelerations", "/joint_trajectory", "/tf", "/tf_static"}
    assert topics == expected | ({"/goal_marker"} if kind == "goal" else set()) | (
        {"/collision_scene", "/collision_clearance"} if kind == "collision" else set())
    for store_name, store in STORES.items():
        for schema, channel, message in messages:
            msg = store.deserialize_cdr(message.data, schema.name)
            # re-serialising with the store's own definition gives the same bytes: no field missing or extra
            assert store.serialize_cdr(msg, schema.name) == message.data, (store_name, channel.topic)
            if channel.topic == "/goal_marker":
                assert msg.ns == "x1" and msg.type == 2 and msg.texture_resource == "" and msg.mesh_file.filename == ""


@pytest.mark.parametrize("kind", list(TASKS))
def test_every_channel_offers_a_qos_profile_rosbags_parses(plans, kind):
    from rosbags.rosbag2.metadata import parse_qos

    _, summary = raw_messages(plans[kind])
    for channel in summary.channels.values():
        text = channel.metadata["offered_qos_profiles"]
        (qos,) = parse_qos(text)
        latched = channel.topic in ("/robot_description", "/tf_static", "/collision_scene")
        assert qos.reliability.name == "RELIABLE"
        assert qos.durability.name == ("TRANSIENT_LOCAL" if latched else "VOLATILE")
        assert qos.history.name == "KEEP_LAST" and qos.depth == (1 if latched else 10)
        assert isinstance(json.loads(json.dumps(text)), str)


def test_rosbags_reads_the_file_as_a_rosbag2_mcap(plans, tmp_path):
    from rosbags.rosbag2 import Reader

    path = tmp_path / "goal.mcap"
    path.write_bytes(plans["goal"])
    with Reader(path) as reader:
        by_topic = {c.topic: c for c in reader.connections}
        assert by_topic["/tf_static"].ext.offered_qos_profiles[0].durability.name == "TRANSIENT_LOCAL"
        assert by_topic["/goal_marker"].msgtype == "visualization_msgs/msg/Marker"
        counts = {}
        for connection, _, raw in reader.messages():
            STORES["humble"].deserialize_cdr(raw, connection.msgtype)
            counts[connection.topic] = counts.get(connection.topic, 0) + 1
    assert counts["/tf_static"] == counts["/robot_description"] == counts["/joint_trajectory"] == 1
    assert counts["/joint_states"] == counts["/tf"] == counts["/goal_marker"]


@pytest.mark.parametrize("kind", list(TASKS))
def test_tf_static_holds_the_joints_that_do_not_move_once_and_tf_only_the_plans_joints(plans, kind):
    messages, _ = raw_messages(plans[kind])
    store = STORES["humble"]
    static = [store.deserialize_cdr(m.data, s.name) for s, c, m in messages if c.topic == "/tf_static"]
    assert len(static) == 1
    assert {ts.child_frame_id for ts in static[0].transforms} == STATIC_CHILDREN[kind]
    moving = {"upper_arm", "forearm"}
    for s, c, m in messages:
        if c.topic == "/tf":
            assert {ts.child_frame_id for ts in store.deserialize_cdr(m.data, s.name).transforms} == moving
    if kind == "locked":  # the wrist's transform is its rotation by the locked 0.4 rad about x
        hand = next(ts for ts in static[0].transforms if ts.child_frame_id == "hand")
        r = hand.transform.rotation
        assert np.allclose([r.x, r.y, r.z, r.w], [np.sin(0.2), 0, 0, np.cos(0.2)], atol=1e-15)
        finger_r = next(ts for ts in static[0].transforms if ts.child_frame_id == "finger_r")
        assert finger_r.transform.translation.y == pytest.approx(-0.01 + 0.001, abs=1e-15)


@pytest.mark.parametrize("kind", list(TASKS))
def test_joint_states_name_every_non_fixed_joint_the_held_ones_at_their_values(plans, kind, tmp_path):
    from hoc_cli.io.mcap import read_plan

    messages, _ = raw_messages(plans[kind])
    store = STORES["jazzy"]
    states = [store.deserialize_cdr(m.data, s.name) for s, c, m in messages if c.topic == "/joint_states"]
    held = HELD.get(kind, {})
    for js in states:
        assert list(js.name) == NON_FIXED[kind]
        assert len(js.position) == len(js.velocity) == len(js.effort) == len(js.name)
        for i, name in enumerate(js.name[2:], start=2):
            assert js.position[i] == pytest.approx(held[name], abs=1e-15) and js.velocity[i] == 0.0
            assert np.isnan(js.effort[i])  # a held joint's torque is not computed
    path = tmp_path / "plan.mcap"  # hoc reads its own plan back with the plan's joints only
    path.write_bytes(plans[kind])
    back = read_plan(path).trajectory
    assert back.joints == ("shoulder", "elbow")
    assert np.array_equal(back.q, np.array([js.position[:2] for js in states]))


def test_a_plan_replays_with_hoc_simulate_when_joint_states_carry_held_joints(plans, tmp_path):
    path = tmp_path / "locked.mcap"
    path.write_bytes(plans["locked"])
    r = CliRunner().invoke(app, ["simulate", str(path), "--check", "1e-6", "-q"])
    assert r.exit_code == 0, r.output
