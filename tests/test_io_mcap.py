"""MCAP plan files, read back with mcap's own reader and the ROS 2 decoder, agree with the CSV."""
import io
import json
import sysconfig
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import NonSeekingReader, make_reader
from mcap_ros2.decoder import DecoderFactory
from scipy.spatial.transform import Rotation

from hoc_cli.elements import HermiteMesh
from hoc_cli.errors import InputFileError
from hoc_cli.io.csv import write_csv
from hoc_cli.io.mcap import quaternions, read_plan, time_ns, urdf_tf_parents, write_mcap
from hoc_cli.trajectory import Trajectory, sample_times

JOINTS = ("shoulder", "elbow")
# A small branching tree: base → l1 → l2, base → l3 (fixed), l2 → tool (fixed).
URDF = """<?xml version="1.0"?>
<robot name="synthetic">
  <link name="base"/><link name="l1"/><link name="l2"/><link name="l3"/><link name="tool"/>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/></joint>
  <joint name="elbow" type="revolute"><parent link="l1"/><child link="l2"/><axis xyz="0 1 0"/></joint>
  <joint name="mount" type="fixed"><parent link="base"/><child link="l3"/></joint>
  <joint name="flange" type="fixed"><parent link="l2"/><child link="tool"/></joint>
</robot>
"""
TASK = "robot: synthetic.urdf\nT: 1.3\nN: 5\n"


def synthetic(rng: np.random.Generator, T=1.3, N=5, order="quintic", rate=100.0) -> Trajectory:
    """A trajectory from random Hermite coefficients, with random torques (no planner involved)."""
    mesh = HermiteMesh(order, T, N)
    C = rng.standard_normal((N + 1, mesh.m, len(JOINTS)))
    t = sample_times(T, rate)
    q, dq, ddq = mesh.evaluate_all(C, t)
    u = rng.standard_normal(q.shape) * 1e3
    return Trajectory(JOINTS, t, q, dq, ddq, u, mesh=mesh, coeffs=C)


def random_poses(rng: np.random.Generator, K: int, links=("base", "l1", "l2", "l3", "tool")) -> dict:
    """Random rigid poses (K, 4, 4) in the root frame for each link; the root ("base") is the identity."""
    out = {}
    for name in links:
        T = np.tile(np.eye(4), (K, 1, 1))
        if name != "base":
            T[:, :3, :3] = Rotation.random(K, random_state=int(rng.integers(1 << 30))).as_matrix()
            T[:, :3, 3] = rng.standard_normal((K, 3))
        out[name] = T
    return out


def write(traj, **kw) -> bytes:
    buf = io.BytesIO()
    kw.setdefault("urdf_text", URDF)
    kw.setdefault("task_text", TASK)
    kw.setdefault("metadata", {"solver": json.dumps({"cost": 1.5, "converged": True})})
    write_mcap(buf, traj, **kw)
    return buf.getvalue()


def decoded(data: bytes, topic: str) -> list:
    reader = make_reader(io.BytesIO(data), decoder_factories=[DecoderFactory()])
    return [(m.log_time, m.publish_time, msg) for _, _, m, msg in reader.iter_decoded_messages(topics=[topic])]


def rigidly_attached(poses: dict, rng: np.random.Generator) -> dict:
    """``poses`` with the links of URDF's fixed joints (l3 on base, tool on l2) at a constant random
    offset from their parents, as forward kinematics gives them."""
    out = dict(poses)
    for child, parent in (("l3", "base"), ("tool", "l2")):
        A = np.eye(4)
        A[:3, :3] = Rotation.random(random_state=int(rng.integers(1 << 30))).as_matrix()
        A[:3, 3] = rng.standard_normal(3)
        out[child] = poses[parent] @ A
    return out


@pytest.fixture(scope="module")
def plan():
    rng = np.random.default_rng(7)
    traj = synthetic(rng)
    poses = rigidly_attached(random_poses(rng, traj.K), rng)
    return traj, poses, write(traj, link_poses=poses)


def tf_edges(message) -> dict:
    """child → (parent, parent_T_child (4, 4)) of a decoded TFMessage."""
    edges = {}
    for ts in message.transforms:
        r, p = ts.transform.rotation, ts.transform.translation
        assert r.w >= 0 and abs(r.x**2 + r.y**2 + r.z**2 + r.w**2 - 1) < 1e-15
        A = np.eye(4)
        A[:3, :3] = Rotation.from_quat([r.x, r.y, r.z, r.w]).as_matrix()
        A[:3, 3] = [p.x, p.y, p.z]
        edges[ts.child_frame_id] = (ts.header.frame_id, A)
    return edges


def test_there_is_one_joint_state_per_csv_row_with_bit_equal_values_and_stamps_equal_to_t(plan):
    traj, _, data = plan
    buf = io.StringIO()
    write_csv(buf, traj)
    rows = [list(map(float, line.split(","))) for line in buf.getvalue().splitlines()[1:]]
    msgs = decoded(data, "/joint_states")
    assert len(msgs) == len(rows) == traj.K
    n = len(JOINTS)
    for row, (log_time, publish_time, js) in zip(rows, msgs):
        ns = round(row[0] * 1e9)
        assert log_time == publish_time == js.header.stamp.sec * 10**9 + js.header.stamp.nanosec == ns
        assert list(js.name) == list(JOINTS)
        assert list(js.position) == row[1:1 + n]
        assert list(js.velocity) == row[1 + n:1 + 2 * n]
        assert list(js.effort) == row[1 + 3 * n:]
    assert msgs[-1][0] == 1_300_000_000  # the last sample is exactly T


def test_the_acceleration_topic_carries_ddq_bit_exactly_at_the_same_stamps(plan):
    traj, _, data = plan
    msgs = decoded(data, "/joint_accelerations")
    assert len(msgs) == traj.K
    for k, (log_time, _, jt) in enumerate(msgs):
        assert log_time == time_ns(traj.t)[k]
        assert list(jt.joint_names) == list(JOINTS)
        (point,) = jt.points
        assert np.array(point.accelerations).tobytes() == traj.ddq[k].tobytes()
        assert point.time_from_start.sec * 10**9 + point.time_from_start.nanosec == log_time


def test_the_urdf_is_published_once_on_robot_description_at_t_zero(plan):
    _, _, data = plan
    (log_time, _, msg), = decoded(data, "/robot_description")
    assert log_time == 0
    assert msg.data == URDF


def test_tf_and_tf_static_compose_back_to_every_links_pose_along_the_urdf_tree(plan):
    traj, poses, data = plan
    msgs = decoded(data, "/tf")
    (static_time, _, static), = decoded(data, "/tf_static")  # the fixed joints, once, at t = 0
    assert static_time == 0
    static_edges = tf_edges(static)
    assert {c: p for c, (p, _) in static_edges.items()} == {"l3": "base", "tool": "l2"}
    assert len(msgs) == traj.K
    assert urdf_tf_parents(URDF) == {"l1": "base", "l2": "l1", "l3": "base", "tool": "l2"}
    for k in (0, 17, traj.K - 1):
        log_time, _, tf = msgs[k]
        assert log_time == time_ns(traj.t)[k]
        assert all(ts.header.stamp.sec * 10**9 + ts.header.stamp.nanosec == log_time for ts in tf.transforms)
        edges = tf_edges(tf)
        assert {c: p for c, (p, _) in edges.items()} == {"l1": "base", "l2": "l1"}  # the moving joints only
        edges.update(static_edges)
        for link, expected in poses.items():
            pose, frame = np.eye(4), link
            while frame in edges:  # walk up to the root, composing parent_T_child
                parent, A = edges[frame]
                pose, frame = A @ pose, parent
            assert frame == "base"
            np.testing.assert_allclose(pose, expected[k], atol=1e-12)


def test_tf_accepts_a_callable_of_q_and_explicit_parents():
    rng = np.random.default_rng(3)
    traj = synthetic(rng)
    seen = []

    def fk(q):
        seen.append(q)
        T = np.tile(np.eye(4), (q.shape[0], 1, 1))
        T[:, 0, 3] = q[:, 0]
        return {"world": np.tile(np.eye(4), (q.shape[0], 1, 1)), "hand": T}

    data = write(traj, link_poses=fk, tf_parents={"hand": "world"})
    assert np.array_equal(seen[0], traj.q)
    msgs = decoded(data, "/tf")
    xs = [m.transforms[0].transform.translation.x for _, _, m in msgs]
    assert xs == traj.q[:, 0].tolist()
    assert {m.transforms[0].header.frame_id for _, _, m in msgs} == {"world"}


def test_a_link_whose_parent_has_no_pose_is_refused():
    traj = synthetic(np.random.default_rng(4))
    poses = random_poses(np.random.default_rng(4), traj.K, links=("base", "l2"))
    with pytest.raises(ValueError, match="'l2'.*parent 'l1'"):
        write(traj, link_poses=poses)


def test_quaternions_agree_with_scipy_for_every_pivot_case():
    R = Rotation.random(2000, random_state=11).as_matrix()
    special = np.array([np.eye(3), np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1])])
    R = np.concatenate([R, special])
    q = quaternions(R)
    ref = Rotation.from_matrix(R).as_quat()
    ref *= np.where(ref[:, 3:] < 0, -1.0, 1.0)
    flip = (np.abs(ref[:, 3]) < 1e-12) & (np.sign(q[:, :3] * ref[:, :3]).sum(1) < 0)  # w = 0: ±q are equal
    ref[flip] *= -1
    np.testing.assert_allclose(q, ref, atol=1e-14)
    assert np.all(q[:, 3] >= 0)


def test_the_hoc_metadata_record_holds_the_task_the_solver_summary_and_the_version(plan):
    from hoc_cli import __version__

    _, _, data = plan
    reader = make_reader(io.BytesIO(data))
    (meta,) = [m for m in reader.iter_metadata() if m.name == "hoc"]
    assert meta.metadata["task"] == TASK
    assert meta.metadata["hoc_version"] == __version__
    assert json.loads(meta.metadata["solver"]) == {"cost": 1.5, "converged": True}
    assert json.loads(meta.metadata["joints"]) == list(JOINTS)


def test_the_urdf_task_and_exact_hermite_coefficients_are_attached(plan):
    traj, _, data = plan
    att = {a.name: a for a in make_reader(io.BytesIO(data)).iter_attachments()}
    assert set(att) == {"robot.urdf", "task.yaml", "hermite.json"}
    assert att["robot.urdf"].media_type == "application/xml" and att["robot.urdf"].data.decode() == URDF
    assert att["task.yaml"].data.decode() == TASK
    doc = json.loads(att["hermite.json"].data)
    assert (doc["order"], doc["T"], doc["N"], doc["joints"]) == ("quintic", 1.3, 5, list(JOINTS))
    assert np.array(doc["coeffs"]).tobytes() == traj.coeffs.tobytes()


def test_the_file_is_valid_for_a_streaming_reader_that_checks_every_crc(plan):
    _, _, data = plan
    reader = NonSeekingReader(io.BytesIO(data), validate_crcs=True)
    topics = {c.topic for _, c, _ in reader.iter_messages()}
    assert topics == {"/joint_states", "/joint_accelerations", "/joint_trajectory", "/robot_description", "/tf", "/tf_static"}
    assert make_reader(io.BytesIO(data)).get_header().profile == "ros2"


def test_identical_inputs_give_byte_identical_files_whatever_the_clock_says(plan, monkeypatch):
    traj, poses, data = plan
    import time

    monkeypatch.setattr(time, "time", lambda: 4.0e9)
    monkeypatch.setattr(time, "time_ns", lambda: 4 * 10**18)
    assert write(traj, link_poses=poses) == data
    assert write(traj, link_poses=poses) == data


def test_read_plan_rebuilds_the_trajectory_and_the_exact_mesh(tmp_path, plan):
    traj, _, data = plan
    path = tmp_path / "plan.mcap"
    path.write_bytes(data)
    p = read_plan(path)
    assert p.task_text == TASK and p.urdf_text == URDF
    assert p.metadata["hoc_version"] and p.joints == JOINTS
    back = p.trajectory
    for name in ("t", "q", "dq", "ddq", "u", "coeffs"):  # t: k/100 is recovered exactly from its ns
        assert getattr(back, name).tobytes() == getattr(traj, name).tobytes(), name
    assert back.mesh == traj.mesh
    q, dq, ddq = back.mesh.evaluate_all(back.coeffs, back.t)  # resampled from the file alone
    assert np.array_equal(q, traj.q) and np.array_equal(ddq, traj.ddq)


def test_a_trajectory_without_hermite_coefficients_is_written_and_read_without_them(tmp_path):
    traj = synthetic(np.random.default_rng(5), order="cubic")
    traj.mesh = traj.coeffs = None
    path = tmp_path / "sim.mcap"
    path.write_bytes(write(traj))
    p = read_plan(path)
    assert p.trajectory.mesh is None and p.trajectory.coeffs is None
    assert decoded(path.read_bytes(), "/tf") == []
    assert np.array_equal(p.trajectory.u, traj.u)


def test_reserved_metadata_keys_are_refused():
    with pytest.raises(ValueError, match="reserved"):
        write(synthetic(np.random.default_rng(6)), metadata={"task": "x"})


def test_reading_something_that_is_not_a_hoc_plan_is_an_input_error_naming_the_file(tmp_path):
    from mcap.writer import Writer

    bare = io.BytesIO()
    w = Writer(bare)
    w.start()
    w.finish()
    cases = {
        "missing.mcap": None,
        "empty.mcap": b"",
        "text.mcap": b"t,q.a\n0,1\n",
        "truncated.mcap": write(synthetic(np.random.default_rng(8)))[:400],
        "bare.mcap": bare.getvalue(),
    }
    messages = {}
    for name, content in cases.items():
        path = tmp_path / name
        if content is not None:
            path.write_bytes(content)
        with pytest.raises(InputFileError) as err:
            read_plan(path)
        assert str(path) in str(err.value)
        messages[name] = str(err.value)
    assert "file not found" in messages["missing.mcap"]
    assert "not an MCAP file" in messages["empty.mcap"] and "not an MCAP file" in messages["text.mcap"]
    assert "truncated" in messages["truncated.mcap"]
    assert "not a hoc plan" in messages["bare.mcap"]


ERD = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix/share/example-robot-data/robots"
ROBOTS_DIR = Path(__file__).resolve().parents[1] / "robots"
FK_CASES = [
    ROBOTS_DIR / "lbr7.urdf",
    ROBOTS_DIR / "dual_arm.urdf",
    ERD / "ur_description/urdf/ur5_robot.urdf",
    ERD / "panda_description/urdf/panda.urdf",   # mimic fingers
    ERD / "baxter_description/urdf/baxter.urdf",  # a branching tree with ~70 links, mimic fingers
]


def joints_without_mimic_masters(model_mod, path):
    """Default joints minus the masters of mimic joints: hoc locks a mimic joint at its master's
    *locked* value, yourdfpy moves it with the master, so the masters are locked (at 0) here."""
    from hoc_cli.errors import HocWarning

    masters = {m.get("joint") for m in ET.parse(path).getroot().findall("joint/mimic")}
    if masters:  # the default joints move the masters: hoc says it holds each mimic joint fixed
        with pytest.warns(HocWarning, match="mimic coupling is not modelled"):
            default = model_mod.load_robot(path).joint_names
    else:
        default = model_mod.load_robot(path).joint_names
    return [j for j in default if j not in masters]


@pytest.mark.parametrize("path", [
    pytest.param(p, id=p.stem)
    for p in FK_CASES])
def test_tf_matches_forward_kinematics_computed_independently_by_yourdfpy(path):
    """Oracle: yourdfpy's own scene graph (trimesh transform tree), yourdfpy 0.0.5x/0.0.6x."""
    import yourdfpy

    import hoc_cli.model as model_mod
    from hoc_cli import dynamics

    model = model_mod.load_robot(path, joints=joints_without_mimic_masters(model_mod, path))
    rng = np.random.default_rng(12)
    t = sample_times(0.2, 50.0)
    q = rng.uniform(-1.5, 1.5, (t.size, model.n))
    zeros = np.zeros_like(q)
    traj = Trajectory(tuple(model.joint_names), t, q, zeros, zeros, zeros)
    urdf_text = path.read_text()
    data = write(traj, urdf_text=urdf_text, link_poses=lambda q: dynamics.link_poses(model, q))
    msgs = decoded(data, "/tf")
    (_, _, static), = decoded(data, "/tf_static")
    assert len(msgs) == traj.K

    oracle = yourdfpy.URDF.load(str(path), build_scene_graph=True, load_meshes=False,
                                build_collision_scene_graph=False, load_collision_meshes=False)
    moving = {j.child for j in oracle.robot.joints if j.name in model.joint_names}
    assert {ts.child_frame_id for ts in msgs[0][2].transforms} == moving
    assert {ts.child_frame_id for ts in static.transforms} == {j.child for j in oracle.robot.joints} - moving
    for k in (0, 4, traj.K - 1):
        cfg = {**model.locked, **dict(zip(model.joint_names, q[k].tolist()))}
        oracle.update_cfg({name: cfg.get(name, 0.0) for name in oracle.actuated_joint_names})
        for ts in list(msgs[k][2].transforms) + list(static.transforms):
            r, p = ts.transform.rotation, ts.transform.translation
            A = np.eye(4)
            A[:3, :3] = Rotation.from_quat([r.x, r.y, r.z, r.w]).as_matrix()
            A[:3, 3] = [p.x, p.y, p.z]
            expected = oracle.get_transform(frame_to=ts.child_frame_id, frame_from=ts.header.frame_id)
            np.testing.assert_allclose(A, expected, atol=1e-12, err_msg=f"{ts.header.frame_id} → {ts.child_frame_id}")
