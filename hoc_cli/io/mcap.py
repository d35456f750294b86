"""MCAP plan files that Foxglove, ``ros2 bag play`` (ROS 2 Humble and later) and hoc itself can read
(README, Outputs).

Layout of a file written by :func:`write_mcap` (profile ``ros2``, CDR messages, zstd chunks; every
schema is the ROS 2 Humble definition, ``hoc_cli.io.ros2_msgdefs``):

=========================== ======================================= ==================================
topic                       schema (ROS 2 ``ros2msg``)              content
=========================== ======================================= ==================================
``/robot_description``      ``std_msgs/msg/String``                 the URDF text, once, at t = 0
                                                                    (QoS transient-local)
``/tf_static``              ``tf2_msgs/msg/TFMessage``              once, at t = 0 (QoS transient-local):
                                                                    one TransformStamped per URDF joint
                                                                    that does not move (fixed, locked,
                                                                    mimic): child link in parent link
``/joint_trajectory``       ``trajectory_msgs/msg/JointTrajectory`` ONE message at t = 0 (stamp 0: "start
                                                                    on receipt"): every sample k is a
                                                                    point with positions = q, velocities
                                                                    = q̇, accelerations = q̈, effort = u,
                                                                    time_from_start = t_k; what a ROS 2
                                                                    joint_trajectory_controller accepts
``/joint_states``           ``sensor_msgs/msg/JointState``          per sample k: name = the plan's joints,
                                                                    then every other non-fixed URDF joint
                                                                    (locked, mimic) in document order;
                                                                    position = q [rad|m] (the others at
                                                                    their locked value), velocity = q̇ (0),
                                                                    effort = u [N·m|N] (NaN: not computed)
``/joint_accelerations``    ``trajectory_msgs/msg/JointTrajectory`` per sample: joint_names = the plan's
                                                                    joints, one point with accelerations =
                                                                    q̈ [rad/s²|m/s²], time_from_start = t
``/tf``                     ``tf2_msgs/msg/TFMessage``              per sample: one TransformStamped per
                                                                    URDF joint of the plan: child link in
                                                                    its parent link
``/goal_marker``            ``visualization_msgs/msg/Marker``       per sample and link goal (when any,
                                                                    ``hoc_cli.io.mcap_markers``)
``/collision_scene``        ``visualization_msgs/msg/MarkerArray``  once, at t = 0, when collisions are
                                                                    checked (QoS transient-local): the
                                                                    obstacles and the robot's collision
                                                                    primitives (``hoc_cli.io.mcap_obstacles``)
``/collision_clearance``    ``std_msgs/msg/Float64``                per sample, when collisions are checked:
                                                                    the smallest signed distance of any
                                                                    checked pair [m] at that sample
=========================== ======================================= ==================================

Every channel carries ``offered_qos_profiles`` metadata as rosbag2 writes it (reliable; the
once-only topics transient-local, the others volatile), so ``ros2 bag play`` offers what a
recorded publisher would and a transient-local subscriber (robot_state_publisher's consumers, tf2's
static listener) connects.

Every header stamp, log time and publish time is the trajectory time t (ns since 0, i.e. the
Unix epoch): nothing is taken from the clock, so the same inputs give byte-identical files.

Metadata record ``hoc``: ``hoc_version``, ``task`` (the task YAML text), ``joints`` (JSON list),
plus the caller's keys (``plan`` writes ``solver``: the JSON summary).

Attachments (create and log time 0): ``robot.urdf`` (``application/xml``), ``task.yaml``
(``application/yaml``) and, when the trajectory has a Hermite representation, ``hermite.json``
(``application/json``): ``{"format": "hoc-hermite/1", "order", "T", "N", "joints", "coeffs"}``
with ``coeffs`` nested lists of shape (N+1, m, n) written with ``repr`` floats, so every double
round-trips exactly; a non-uniform mesh (``N: auto``) adds ``nodes``, its N+1 node times [s]. :func:`read_plan` rebuilds the trajectory and the mesh from these.
"""
from __future__ import annotations

import json
import os
import struct
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Callable, Mapping, Sequence, Union

import numpy as np

from hoc_cli.elements import HermiteMesh
from hoc_cli.errors import InputFileError
from hoc_cli.io.mcap_markers import MARKER_TYPE, TOPIC_GOAL_MARKER, MarkerTrack, marker_message
from hoc_cli.io.ros2_msgdefs import MSGDEFS, offered_qos_profiles
from hoc_cli.trajectory import Trajectory

TOPIC_JOINT_STATES = "/joint_states"
TOPIC_ACCELERATIONS = "/joint_accelerations"
TOPIC_TRAJECTORY = "/joint_trajectory"
TOPIC_ROBOT_DESCRIPTION = "/robot_description"
TOPIC_TF = "/tf"
TOPIC_TF_STATIC = "/tf_static"
TOPIC_COLLISION_SCENE = "/collision_scene"
TOPIC_CLEARANCE = "/collision_clearance"
LATCHED_TOPICS = (TOPIC_ROBOT_DESCRIPTION, TOPIC_TF_STATIC, TOPIC_COLLISION_SCENE)
MOVABLE_TYPES = ("revolute", "continuous", "prismatic")
METADATA_NAME = "hoc"
ATTACHMENT_URDF = "robot.urdf"
ATTACHMENT_TASK = "task.yaml"
ATTACHMENT_HERMITE = "hermite.json"
HERMITE_FORMAT = "hoc-hermite/1"
RESERVED_METADATA = ("hoc_version", "task", "joints")

LinkPoses = Mapping[str, np.ndarray]
LinkPosesSource = Union[LinkPoses, Callable[[np.ndarray], LinkPoses]]


# --------------------------------------------------------------------------- writing

def time_ns(t: np.ndarray) -> np.ndarray:
    """Trajectory times t [s] (K,) → integer nanoseconds (K,), rounded to the nearest ns."""
    return np.rint(np.asarray(t, dtype=float) * 1e9).astype(np.int64)


def urdf_tf_parents(urdf_text: str) -> dict[str, str]:
    """Child link → parent link for every ``<joint>`` of a URDF document (the /tf tree)."""
    return {j.child: j.parent for j in urdf_joints(urdf_text) if j.child is not None and j.parent is not None}


@dataclass(frozen=True)
class UrdfJoint:
    """A URDF ``<joint>`` as the writer needs it: name, type, parent and child links, and the mimic
    (master joint, multiplier, offset) or None.
    """

    name: str
    type: str
    parent: str | None
    child: str | None
    mimic: tuple[str, float, float] | None = None


def urdf_joints(urdf_text: str) -> list[UrdfJoint]:
    """Every ``<joint>`` of a URDF document, in document order."""
    out = []
    for joint in ET.fromstring(urdf_text).findall("joint"):
        p, c, m = joint.find("parent"), joint.find("child"), joint.find("mimic")
        mimic = None
        if m is not None:
            mimic = (m.get("joint"), float(m.get("multiplier") or 1.0), float(m.get("offset") or 0.0))
        out.append(UrdfJoint(joint.get("name"), joint.get("type"), None if p is None else p.get("link"),
                             None if c is None else c.get("link"), mimic))
    return out


def held_joint_values(joints: Sequence[UrdfJoint], moving: Sequence[str], locked: Mapping[str, float]) -> dict[str, float]:
    """Value (rad or m) of every movable URDF joint not in ``moving``, in document order: its
    ``locked`` value, else (mimic joints) multiplier · locked value of the master (0 when the master
    moves or is not listed) + offset, else 0, the rule of ``hoc_cli.model.load_robot``.
    """
    out = {}
    for j in joints:
        if j.type not in MOVABLE_TYPES or j.name in moving:
            continue
        if j.name in locked:
            out[j.name] = float(locked[j.name])
        elif j.mimic is not None:
            master, multiplier, offset = j.mimic
            out[j.name] = multiplier * float(locked.get(master, 0.0)) + offset
        else:
            out[j.name] = 0.0
    return out


def quaternions(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (K, 4) as (x, y, z, w), w >= 0, of rotation matrices R (K, 3, 3).

    Shepperd's method: each sample uses the largest of 1 + trace, 1 + 2 R_ii − trace as the
    pivot, so no division by a small number happens.
    """
    R = np.asarray(R, dtype=float)
    K = R.shape[0]
    d = np.stack([R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]], axis=1)
    tr = d.sum(axis=1)
    pivots = np.concatenate([tr[:, None], 2 * d - tr[:, None]], axis=1)  # (K, 4): w, x, y, z
    case = np.argmax(pivots, axis=1)
    s = 2.0 * np.sqrt(np.maximum(1.0 + pivots[np.arange(K), case], 0.0))  # 4 |pivot component|
    skew = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], axis=1)
    sym = np.stack([R[:, 0, 1] + R[:, 1, 0], R[:, 0, 2] + R[:, 2, 0], R[:, 1, 2] + R[:, 2, 1]], axis=1)
    q = np.empty((K, 4))  # x, y, z, w
    for c, (x, y, z, w) in enumerate((
        (skew[:, 0], skew[:, 1], skew[:, 2], s * s / 4),
        (s * s / 4, sym[:, 0], sym[:, 1], skew[:, 0]),
        (sym[:, 0], s * s / 4, sym[:, 2], skew[:, 1]),
        (sym[:, 1], sym[:, 2], s * s / 4, skew[:, 2]),
    )):
        m = case == c
        q[m] = np.stack([x[m], y[m], z[m], w[m]], axis=1) / s[m, None]
    q *= np.where(q[:, 3:] < 0, -1.0, 1.0)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def relative_transforms(link_poses: LinkPoses, parents: Mapping[str, str], K: int) -> list[tuple[str, str, np.ndarray]]:
    """(parent, child, parent_T_child (K, 4, 4)) for each child in ``parents`` whose pose is known.

    ``link_poses`` maps link name → pose (K, 4, 4) in the root frame. A child whose parent has no
    pose is an error (the tree would not be connected). Order: sorted by child name.
    """
    out = []
    for child in sorted(parents):
        if child not in link_poses:
            continue
        parent = parents[child]
        if parent not in link_poses:
            raise ValueError(f"/tf: link {child!r} has a pose but its parent {parent!r} has none")
        P, C = (np.asarray(link_poses[k], dtype=float) for k in (parent, child))
        for name, A in ((parent, P), (child, C)):
            if A.shape != (K, 4, 4):
                raise ValueError(f"/tf: pose of link {name!r} has shape {A.shape}, expected ({K}, 4, 4)")
        Rt = np.swapaxes(P[:, :3, :3], 1, 2)
        rel = np.zeros((K, 4, 4))
        rel[:, :3, :3] = Rt @ C[:, :3, :3]
        rel[:, :3, 3] = np.einsum("kij,kj->ki", Rt, C[:, :3, 3] - P[:, :3, 3])
        rel[:, 3, 3] = 1.0
        out.append((parent, child, rel))
    return out


def trajectory_message(joints: list[str], ns: np.ndarray, arrays: Mapping[str, list]) -> dict:
    """The ``/joint_trajectory`` message: every sample as a JointTrajectoryPoint.

    ``ns`` (K,) sample times [ns]; ``arrays`` maps q, dq, ddq, u to (K, n) nested lists. The header
    stamp is 0, which a ROS 2 joint_trajectory_controller reads as "start when received".
    """
    points = [{"positions": arrays["q"][k], "velocities": arrays["dq"][k], "accelerations": arrays["ddq"][k],
               "effort": arrays["u"][k],
               "time_from_start": {"sec": int(t // 1_000_000_000), "nanosec": int(t % 1_000_000_000)}}
              for k, t in enumerate(ns.tolist())]
    return {"header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""}, "joint_names": joints, "points": points}


def hermite_json(traj: Trajectory) -> bytes:
    """The exact Hermite representation of ``traj`` as JSON bytes (see the module docstring)."""
    mesh, C = traj.mesh, np.asarray(traj.coeffs, dtype=float)
    mesh.check_coefficients(C)
    if C.shape[2] != traj.n:
        raise ValueError(f"coefficients have {C.shape[2]} joints, the trajectory {traj.n}")
    if not np.all(np.isfinite(C)):
        raise ValueError("Hermite coefficients contain NaN or infinity")
    doc = {"format": HERMITE_FORMAT, "order": mesh.order, "T": float(mesh.T), "N": int(mesh.N),
           "joints": list(traj.joints), "coeffs": C.tolist()}
    if not mesh.uniform:
        doc["nodes"] = mesh.nodes.tolist()
    return (json.dumps(doc, allow_nan=False) + "\n").encode()


class _Ros2Writer:
    """mcap's Writer with ROS 2 channels (CDR messages, Humble schemas from ``MSGDEFS``), each
    registered once with its ``offered_qos_profiles`` metadata.
    """

    def __init__(self, fh: IO[bytes]):
        from mcap.writer import CompressionType
        from mcap.writer import Writer as McapWriter

        from hoc_cli import __version__

        self.mcap = McapWriter(fh, compression=CompressionType.ZSTD)
        self.mcap.start(profile="ros2", library=f"hoc {__version__}")
        self.schemas: dict[str, tuple[int, Callable]] = {}
        self.channels: dict[str, tuple[int, Callable]] = {}

    def channel(self, topic: str, type_name: str) -> None:
        """Register ``topic`` with the message type ``type_name`` (a key of ``MSGDEFS``)."""
        from mcap_ros2._dynamic import serialize_dynamic  # the CDR encoder of mcap-ros2-support

        if type_name not in self.schemas:
            text = MSGDEFS[type_name]
            schema_id = self.mcap.register_schema(type_name, "ros2msg", text.encode())
            self.schemas[type_name] = (schema_id, serialize_dynamic(type_name, text)[type_name])
        schema_id, encode = self.schemas[type_name]
        qos = offered_qos_profiles(latched=topic in LATCHED_TOPICS)
        self.channels[topic] = (self.mcap.register_channel(topic, "cdr", schema_id, {"offered_qos_profiles": qos}), encode)

    def write(self, topic: str, message: dict, ns: int, sequence: int = 0) -> None:
        """Write ``message`` on ``topic`` with log and publish time ``ns`` [ns]."""
        channel_id, encode = self.channels[topic]
        self.mcap.add_message(channel_id=channel_id, log_time=ns, publish_time=ns, sequence=sequence, data=encode(message))


def _stamp(ns: int) -> dict:
    return {"sec": int(ns // 1_000_000_000), "nanosec": int(ns % 1_000_000_000)}


def _tf_message(transforms: list, k: int, stamp: dict) -> dict:
    """TFMessage of sample k of ``transforms``: (parent, child, translations (K, 3), quaternions (K, 4)) lists."""
    return {"transforms": [{
        "header": {"stamp": stamp, "frame_id": parent}, "child_frame_id": child,
        "transform": {"translation": dict(zip("xyz", p[k])), "rotation": dict(zip("xyzw", r[k]))},
    } for parent, child, p, r in transforms]}


def write_mcap(
    fh: IO[bytes],
    traj: Trajectory,
    *,
    urdf_text: str,
    task_text: str,
    metadata: Mapping[str, str] | None = None,
    link_poses: LinkPosesSource | None = None,
    tf_parents: Mapping[str, str] | None = None,
    markers: Sequence[MarkerTrack] = (),
    locked: Mapping[str, float] | None = None,
    scene: Mapping | None = None,
    clearance: np.ndarray | None = None,
) -> None:
    """Write ``traj`` (t (K,) s; q, dq, ddq, u (K, n)) as an MCAP plan file to the binary stream ``fh``.

    Parameters
    ----------
    urdf_text : the robot's URDF document (published on /robot_description and attached)
    task_text : the task YAML text (in the ``hoc`` metadata and attached)
    metadata : extra string entries of the ``hoc`` metadata record (e.g. ``solver``: a JSON
        summary); may not use the reserved keys ``hoc_version``, ``task``, ``joints``
    link_poses : pose (K, 4, 4) of each URDF link in the root frame at the K samples, or a
        callable mapping q (K, n) to such a dict; None writes no /tf and no /tf_static
    tf_parents : child link → parent link of each published transform; default: the URDF's
        joints (parent link → child link, as robot_state_publisher does). A child whose URDF
        joint is not a trajectory joint (fixed, locked, mimic) goes once on /tf_static.
    markers : points (K, 3) [m] in the root frame to show on /goal_marker at each sample (a goal's
        target, ``hoc_cli.io.mcap_markers``)
    locked : value (rad or m) of the URDF's movable joints that are not trajectory joints
        (``RobotModel.locked``), published on /joint_states after the trajectory's joints;
        missing ones follow :func:`held_joint_values`
    scene : a ``visualization_msgs/msg/MarkerArray`` message (``hoc_cli.io.mcap_obstacles``), written
        once at t = 0 on /collision_scene; None writes no such topic
    clearance : (K,) m, the smallest signed distance of the checked pairs at each sample, on
        /collision_clearance; None writes no such topic

    The stream is always finished (``finally``), so an exception leaves a truncated file that the
    caller discards (``atomic_output``).
    """
    meta = dict(metadata or {})
    clash = [k for k in RESERVED_METADATA if k in meta]
    if clash:
        raise ValueError(f"metadata key {clash[0]!r} is reserved (set by write_mcap)")
    if not all(isinstance(k, str) and isinstance(v, str) for k, v in meta.items()):
        raise ValueError("metadata keys and values must be strings")
    joints = [str(j) for j in traj.joints]
    K, n = traj.K, len(joints)
    t = np.asarray(traj.t, dtype=float)
    if t.shape != (K,) or (K > 1 and not np.all(np.diff(t) > 0)) or t[0] < 0:
        raise ValueError("trajectory times must be a strictly increasing (K,) array starting at t >= 0")
    arrays = {}
    for g in ("q", "dq", "ddq", "u"):
        a = np.asarray(getattr(traj, g), dtype=float)
        if a.shape != (K, n):
            raise ValueError(f"trajectory {g} has shape {a.shape}, expected ({K}, {n})")
        arrays[g] = a.tolist()
    ns = time_ns(t)
    if K > 1 and not np.all(np.diff(ns) > 0):
        raise ValueError("two samples fall in the same nanosecond (output rate above 1 GHz)")
    if clearance is not None:
        clearance = np.asarray(clearance, dtype=float)
        if clearance.shape != (K,):
            raise ValueError(f"clearance has shape {clearance.shape}, expected ({K},)")
    hermite = hermite_json(traj) if traj.mesh is not None and traj.coeffs is not None else None

    try:
        table = urdf_joints(urdf_text)
    except ET.ParseError:  # a document that is not XML has no joints to hold (a /tf from it raises below)
        table = []
    held = held_joint_values(table, joints, locked or {})
    state_names = joints + list(held)
    held_q, held_zero, held_nan = list(held.values()), [0.0] * len(held), [float("nan")] * len(held)

    moving, still = [], []  # (parent, child, translations (K, 3), quaternions (K, 4))
    if link_poses is not None:
        poses = link_poses(np.asarray(traj.q, dtype=float)) if callable(link_poses) else link_poses
        parents = urdf_tf_parents(urdf_text) if tf_parents is None else dict(tf_parents)
        static_children = {j.child for j in table if j.name not in joints}
        for parent, child, rel in relative_transforms(poses, parents, K):
            entry = (parent, child, rel[:, :3, 3].tolist(), quaternions(rel[:, :3, :3]).tolist())
            (still if child in static_children else moving).append(entry)

    writer = _Ros2Writer(fh)
    try:
        topics = [(TOPIC_ROBOT_DESCRIPTION, "std_msgs/msg/String"), (TOPIC_TRAJECTORY, "trajectory_msgs/msg/JointTrajectory"),
                  (TOPIC_JOINT_STATES, "sensor_msgs/msg/JointState"), (TOPIC_ACCELERATIONS, "trajectory_msgs/msg/JointTrajectory")]
        topics += [(TOPIC_TF_STATIC, "tf2_msgs/msg/TFMessage")] if still else []
        topics += [(TOPIC_TF, "tf2_msgs/msg/TFMessage")] if moving else []
        topics += [(TOPIC_GOAL_MARKER, MARKER_TYPE)] if markers else []
        topics += [(TOPIC_COLLISION_SCENE, "visualization_msgs/msg/MarkerArray")] if scene is not None else []
        topics += [(TOPIC_CLEARANCE, "std_msgs/msg/Float64")] if clearance is not None else []
        for topic, type_name in topics:
            writer.channel(topic, type_name)
        writer.write(TOPIC_ROBOT_DESCRIPTION, {"data": urdf_text}, 0)
        if scene is not None:
            writer.write(TOPIC_COLLISION_SCENE, dict(scene), 0)
        if still:
            writer.write(TOPIC_TF_STATIC, _tf_message(still, 0, _stamp(0)), 0)
        writer.write(TOPIC_TRAJECTORY, trajectory_message(joints, ns, arrays), 0)
        for k in range(K):
            stamp = _stamp(ns[k])
            header = {"stamp": stamp, "frame_id": ""}
            when = dict(ns=int(ns[k]), sequence=k)
            writer.write(TOPIC_JOINT_STATES, {
                "header": header, "name": state_names, "position": arrays["q"][k] + held_q,
                "velocity": arrays["dq"][k] + held_zero, "effort": arrays["u"][k] + held_nan}, **when)
            writer.write(TOPIC_ACCELERATIONS, {
                "header": header, "joint_names": joints, "points": [{
                    "positions": [], "velocities": [], "accelerations": arrays["ddq"][k], "effort": [],
                    "time_from_start": stamp}]}, **when)
            if moving:
                writer.write(TOPIC_TF, _tf_message(moving, k, stamp), **when)
            for i, track in enumerate(markers):
                writer.write(TOPIC_GOAL_MARKER, marker_message(track, i, k, stamp), **when)
            if clearance is not None:
                writer.write(TOPIC_CLEARANCE, {"data": float(clearance[k])}, **when)
        from hoc_cli import __version__

        writer.mcap.add_metadata(METADATA_NAME, {"hoc_version": __version__, "task": task_text,
                                                 "joints": json.dumps(joints), **meta})
        for name, media_type, data in ((ATTACHMENT_URDF, "application/xml", urdf_text.encode()),
                                       (ATTACHMENT_TASK, "application/yaml", task_text.encode()),
                                       *(((ATTACHMENT_HERMITE, "application/json", hermite),) if hermite is not None else ())):
            writer.mcap.add_attachment(create_time=0, log_time=0, name=name, media_type=media_type, data=data)
    finally:
        writer.mcap.finish()


# --------------------------------------------------------------------------- reading

@dataclass(eq=False)
class PlanFile:
    """A plan read back from MCAP: everything needed to resample or re-simulate it.

    ``trajectory`` holds the samples of /joint_states and /joint_accelerations (t recovered from
    the stamps, to the nanosecond) and, when the file has ``hermite.json``, the exact mesh and
    coefficients (``trajectory.mesh``, ``trajectory.coeffs`` (N+1, m, n)).
    """

    path: Path
    task_text: str
    urdf_text: str
    metadata: dict[str, str]
    trajectory: Trajectory
    attachments: dict[str, bytes] = field(default_factory=dict, repr=False)
    clearance: np.ndarray | None = None  # (K,) m from /collision_clearance, at the trajectory's samples

    @property
    def joints(self) -> tuple[str, ...]:
        return self.trajectory.joints


_READ_ERRORS: tuple[type[BaseException], ...] = (struct.error, EOFError, UnicodeDecodeError, ValueError)


def read_plan(path: str | os.PathLike) -> PlanFile:
    """Read an MCAP written by :func:`write_mcap`. Raises InputFileError naming the file."""
    from mcap.exceptions import EndOfFile, InvalidMagic, McapError
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    path = Path(path)
    try:
        fh = open(path, "rb")
    except FileNotFoundError:
        raise InputFileError("file not found (expected an MCAP plan written by hoc)", file=path) from None
    except OSError as exc:
        raise InputFileError(f"cannot be read ({exc.strerror})", file=path) from None
    try:
        with fh:
            reader = make_reader(fh, decoder_factories=[DecoderFactory()])
            metadata = next((dict(m.metadata) for m in reader.iter_metadata() if m.name == METADATA_NAME), None)
            if metadata is None:
                raise InputFileError(f"not a hoc plan (no {METADATA_NAME!r} metadata record)", file=path)
            attachments = {a.name: bytes(a.data) for a in reader.iter_attachments()}
            for name in (ATTACHMENT_URDF, ATTACHMENT_TASK):
                if name not in attachments:
                    raise InputFileError(f"not a hoc plan (no {name!r} attachment)", file=path)
            states, accels, clear = [], [], []
            by_topic = {TOPIC_JOINT_STATES: states, TOPIC_ACCELERATIONS: accels, TOPIC_CLEARANCE: clear}
            for _, channel, message, msg in reader.iter_decoded_messages(topics=list(by_topic)):
                by_topic[channel.topic].append((message.log_time, msg))
    except InputFileError:
        raise
    except (InvalidMagic, EndOfFile):
        raise InputFileError("not an MCAP file (expected an MCAP plan written by hoc)", file=path) from None
    except (McapError, *_READ_ERRORS) as exc:
        raise InputFileError(f"damaged or truncated MCAP file ({type(exc).__name__}: {_first_line(exc)})", file=path) from None
    except Exception as exc:  # third-party reader and CDR decoder on damaged bytes: wrap whatever they raise
        raise InputFileError(f"damaged MCAP file ({type(exc).__name__}: {_first_line(exc)})", file=path) from None
    try:
        traj = _trajectory(path, states, accels, _plan_joints(metadata))
    except (AttributeError, TypeError, ValueError, OverflowError) as exc:  # a message decoded into the wrong shape
        raise InputFileError(f"damaged {TOPIC_JOINT_STATES}/{TOPIC_ACCELERATIONS} messages ({_first_line(exc)})",
                             file=path) from None
    if ATTACHMENT_HERMITE in attachments:
        traj.mesh, traj.coeffs = _hermite(path, attachments[ATTACHMENT_HERMITE], traj.joints)
    return PlanFile(path=path, task_text=attachments[ATTACHMENT_TASK].decode("utf-8", "replace"),
                    urdf_text=attachments[ATTACHMENT_URDF].decode("utf-8", "replace"),
                    metadata=metadata, trajectory=traj, attachments=attachments,
                    clearance=_clearance(path, clear, states))


def _clearance(path: Path, clear: list, states: list) -> np.ndarray | None:
    """The /collision_clearance samples (K,) m, None without that topic; each must share a /joint_states time."""
    if not clear:
        return None
    if [ns for ns, _ in clear] != [ns for ns, _ in states]:
        raise InputFileError(f"damaged {TOPIC_CLEARANCE} messages (expected one per /joint_states sample)", file=path)
    return np.array([float(m.data) for _, m in clear])


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0][:200] if text else ""


def _plan_joints(metadata: Mapping[str, str]) -> tuple[str, ...] | None:
    """The plan's joints from the ``hoc`` metadata record, or None when it does not list them."""
    try:
        joints = json.loads(metadata.get("joints", ""))
    except ValueError:
        return None
    if isinstance(joints, list) and joints and all(isinstance(j, str) for j in joints):
        return tuple(joints)
    return None


def _trajectory(path: Path, states: list, accels: list, joints: tuple[str, ...] | None) -> Trajectory:
    """The plan's samples: /joint_states' first n entries (the plan's joints; the held joints after
    them are not part of the trajectory) and /joint_accelerations.
    """
    if not states:
        raise InputFileError(f"not a hoc plan (no messages on {TOPIC_JOINT_STATES})", file=path)
    names = tuple(states[0][1].name)
    if joints is None:
        joints = names
    n = len(joints)
    if names[:n] != joints:
        raise InputFileError(f"{TOPIC_JOINT_STATES} names joints {list(names)}, expected the plan's joints "
                             f"{list(joints)} first", file=path)
    if len(accels) != len(states):
        raise InputFileError(f"{TOPIC_ACCELERATIONS} has {len(accels)} messages, expected one per "
                             f"{TOPIC_JOINT_STATES} message ({len(states)})", file=path)
    ns, q, dq, u, ddq = [], [], [], [], []
    for k, ((log_time, js), (log_time_a, acc)) in enumerate(zip(states, accels)):
        stamp = js.header.stamp.sec * 1_000_000_000 + js.header.stamp.nanosec
        if tuple(js.name) != names or tuple(acc.joint_names) != joints:
            raise InputFileError(f"message {k} names joints {list(js.name)}, expected {list(names)} as in the first", file=path)
        if log_time_a != log_time or stamp != log_time:
            raise InputFileError(f"message {k}: stamps of {TOPIC_JOINT_STATES} and {TOPIC_ACCELERATIONS} differ", file=path)
        if len(acc.points) != 1:
            raise InputFileError(f"{TOPIC_ACCELERATIONS} message {k} has {len(acc.points)} points, expected 1", file=path)
        rows = (js.position, js.velocity, js.effort)
        if any(len(r) != len(names) for r in rows) or len(acc.points[0].accelerations) != n:
            raise InputFileError(f"message {k} has arrays of lengths {[len(r) for r in rows]} and "
                                 f"{len(acc.points[0].accelerations)}, expected {len(names)} and {n}", file=path)
        rows = tuple(r[:n] for r in rows) + (acc.points[0].accelerations,)
        ns.append(stamp)
        for out, r in zip((q, dq, u, ddq), rows):
            out.append(r)
    t = np.array(ns, dtype=np.int64) / 1e9
    arr = {k: np.array(v, dtype=float).reshape(len(states), n) for k, v in (("q", q), ("dq", dq), ("ddq", ddq), ("u", u))}
    return Trajectory(joints=joints, t=t, **arr)


def _hermite(path: Path, data: bytes, joints: tuple[str, ...]) -> tuple[HermiteMesh, np.ndarray]:
    where = f"attachment {ATTACHMENT_HERMITE!r}"
    try:
        doc = json.loads(data)
        if doc.get("format") != HERMITE_FORMAT:
            raise ValueError(f"format is {doc.get('format')!r}, expected {HERMITE_FORMAT!r}")
        mesh = HermiteMesh(doc["order"], float(doc["T"]), int(doc["N"]),
                           None if doc.get("nodes") is None else tuple(float(v) for v in doc["nodes"]))
        C = np.array(doc["coeffs"], dtype=float)
        mesh.check_coefficients(C)
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        raise InputFileError(f"{where} is invalid ({exc})", file=path) from None
    if tuple(doc.get("joints", ())) != joints or C.shape[2] != len(joints):
        raise InputFileError(f"{where} names joints {doc.get('joints')}, expected {list(joints)}", file=path)
    if not np.all(np.isfinite(C)):
        raise InputFileError(f"{where} has non-finite coefficients", file=path)
    return mesh, C
