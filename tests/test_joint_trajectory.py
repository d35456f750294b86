"""Issue 13 item 5: `/joint_trajectory`, one trajectory_msgs/msg/JointTrajectory holding every sample, decoded
with mcap_ros2's ROS 2 decoder (the reference CDR reader) and compared with the CSV written by the same run.
"""
import shutil
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from typer.testing import CliRunner

from hoc_cli.cli import app
from hoc_cli.io.csv import read_csv

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module", params=["plan", "simulate"])
def outputs(request, tmp_path_factory):
    d = tmp_path_factory.mktemp(request.param)
    shutil.copy(ROOT / "robots" / "two_link.urdf", d / "two_link.urdf")
    (d / "t.yaml").write_text((ROOT / "configs" / "two_link.yaml").read_text().replace("../robots/", ""))
    run = CliRunner().invoke
    assert run(app, ["plan", str(d / "t.yaml"), "-o", str(d / "p.mcap"), "-o", str(d / "p.csv"), "-q"]).exit_code == 0
    if request.param == "simulate":
        r = run(app, ["simulate", str(d / "p.mcap"), "-o", str(d / "s.mcap"), "-o", str(d / "s.csv"), "-q"])
        assert r.exit_code == 0
        return d / "s.mcap", d / "s.csv"
    return d / "p.mcap", d / "p.csv"


def decoded(path, topic):
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        return [(schema.name, message, msg) for schema, _, message, msg in reader.iter_decoded_messages(topics=[topic])]


def test_one_joint_trajectory_message_at_t_0_holds_every_sample_and_equals_the_csv(outputs):
    mcap, csv = outputs
    msgs = decoded(mcap, "/joint_trajectory")
    assert len(msgs) == 1
    schema, message, msg = msgs[0]
    assert schema == "trajectory_msgs/msg/JointTrajectory"
    assert message.log_time == 0 and (msg.header.stamp.sec, msg.header.stamp.nanosec) == (0, 0)
    traj = read_csv(csv)
    assert tuple(msg.joint_names) == traj.joints
    assert len(msg.points) == traj.K
    for name, column in (("positions", traj.q), ("velocities", traj.dq), ("accelerations", traj.ddq),
                         ("effort", traj.u)):
        np.testing.assert_array_equal(np.array([getattr(p, name) for p in msg.points]), column, err_msg=name)
    t = np.array([p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in msg.points])
    assert np.max(np.abs(t - traj.t)) <= 0.5e-9 + 1e-15 * traj.t[-1]
    assert all(0 <= p.time_from_start.nanosec < 1_000_000_000 for p in msg.points)


def test_the_trajectory_agrees_with_joint_states(outputs):
    mcap, _ = outputs
    (_, _, traj), = decoded(mcap, "/joint_trajectory")
    states = decoded(mcap, "/joint_states")
    assert len(states) == len(traj.points)
    for (_, message, js), point in zip(states, traj.points):
        assert list(js.position) == list(point.positions) and list(js.effort) == list(point.effort)
        assert message.log_time == point.time_from_start.sec * 1_000_000_000 + point.time_from_start.nanosec


def test_the_shipped_foxglove_layout_reads_topics_and_fields_that_hoc_writes(outputs):
    import json

    layout = json.loads((ROOT / "docs" / "foxglove_layout.json").read_text())
    mcap, _ = outputs
    with open(mcap, "rb") as fh:
        topics = {c.topic for c in make_reader(fh).get_summary().channels.values()}
    panels = layout["configById"]
    urdf_layers = [layer for layer in panels["3D!hoc"]["layers"].values() if layer["layerId"] == "foxglove.Urdf"]
    assert [layer["topic"] for layer in urdf_layers] == ["/robot_description"] and "/tf" in topics
    (_, _, js), *_ = decoded(mcap, "/joint_states")
    for name in ("Plot!q", "Plot!dq", "Plot!u"):
        for path in panels[name]["paths"]:
            topic, field = path["value"].split(".")
            assert topic in topics and hasattr(js, field.split("[")[0])
    assert {"3D!hoc", "Plot!q", "Plot!dq", "Plot!u"} <= set(panels)
    from hoc_cli.io.mcap import TOPIC_CLEARANCE
    from hoc_cli.io.ros2_msgdefs import MSGDEFS

    assert [p["value"] for p in panels["Plot!clearance"]["paths"]] == [f"{TOPIC_CLEARANCE}.data"]
    assert MSGDEFS["std_msgs/msg/Float64"] == "float64 data\n"  # the field the panel plots
