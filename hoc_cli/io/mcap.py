"""MCAP plan files that Foxglove, ``ros2 bag play`` and hoc itself can read (README, Outputs).

Layout of a file written by :func:`write_mcap` (profile ``ros2``, CDR messages, zstd chunks):

=========================== ======================================= ==================================
topic                       schema (ROS 2 ``ros2msg``)              content, one message per sample k
=========================== ======================================= ==================================
``/robot_description``      ``std_msgs/msg/String``                 the URDF text, once, at t = 0
``/joint_states``           ``sensor_msgs/msg/JointState``          name = joints, position = q [rad|m],
                                                                    velocity = q̇, effort = u [N·m|N]
``/joint_accelerations``    ``trajectory_msgs/msg/JointTrajectory`` joint_names = joints, one point with
                                                                    accelerations = q̈ [rad/s²|m/s²] and
                                                                    time_from_start = t
``/joint_trajectory``       ``trajectory_msgs/msg/JointTrajectory`` ONE message at t = 0 (stamp 0: "start
                                                                    on receipt"): every sample k is a
                                                                    point with positions = q, velocities
                                                                    = q̇, accelerations = q̈, effort = u,
                                                                    time_from_start = t_k; what a ROS 2
                                                                    joint_trajectory_controller accepts
``/tf``                     ``tf2_msgs/msg/TFMessage``              one TransformStamped per URDF joint:
                                                                    child link in its parent link
=========================== ======================================= ==================================

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
from hoc_cli.io.ros2_msgdefs import MSGDEFS
from hoc_cli.trajectory import Trajectory

TOPIC_JOINT_STATES = "/joint_states"
TOPIC_ACCELERATIONS = "/joint_accelerations"
TOPIC_TRAJECTORY = "/joint_trajectory"
TOPIC_ROBOT_DESCRIPTION = "/robot_description"
TOPIC_TF = "/tf"
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
    root = ET.fromstring(urdf_text)
    parents = {}
    for joint in root.findall("joint"):
        p, c = joint.find("parent"), joint.find("child")
        if p is not None and c is not None:
            parents[c.get("link")] = p.get("link")
    return parents


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
) -> None:
    """Write ``traj`` (t (K,) s; q, dq, ddq, u (K, n)) as an MCAP plan file to the binary stream ``fh``.

    Parameters
    ----------
    urdf_text : the robot's URDF document (published on /robot_description and attached)
    task_text : the task YAML text (in the ``hoc`` metadata and attached)
    metadata : extra string entries of the ``hoc`` metadata record (e.g. ``solver``: a JSON
        summary); may not use the reserved keys ``hoc_version``, ``task``, ``joints``
    link_poses : pose (K, 4, 4) of each URDF link in the root frame at the K samples, or a
        callable mapping q (K, n) to such a dict; None writes no /tf
    tf_parents : child link → parent link of each published transform; default: the URDF's
        joints (parent link → child link, as robot_state_publisher does)
    markers : points (K, 3) [m] in the root frame to show on /goal_marker at each sample (a goal's
        target, ``hoc_cli.io.mcap_markers``)

    The stream is always finished (``finally``), so an exception leaves a truncated file that the
    caller discards (``atomic_output``).
    """
    from mcap.writer import CompressionType
    from mcap_ros2.writer import Writer

    from hoc_cli import __version__

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
    hermite = hermite_json(traj) if traj.mesh is not None and traj.coeffs is not None else None

    transforms: list[tuple[str, str, list, list]] = []
    if link_poses is not None:
        poses = link_poses(np.asarray(traj.q, dtype=float)) if callable(link_poses) else link_poses
        parents = urdf_tf_parents(urdf_text) if tf_parents is None else dict(tf_parents)
        for parent, child, rel in relative_transforms(poses, parents, K):
            transforms.append((parent, child, rel[:, :3, 3].tolist(), quaternions(rel[:, :3, :3]).tolist()))

    writer = Writer(fh, compression=CompressionType.ZSTD)
    try:
        schemas = {name: writer.register_msgdef(name, text) for name, text in MSGDEFS.items()
                   if name != MARKER_TYPE or markers}
        writer.write_message(TOPIC_ROBOT_DESCRIPTION, schemas["std_msgs/msg/String"], {"data": urdf_text},
                             log_time=0, publish_time=0)
        writer.write_message(TOPIC_TRAJECTORY, schemas["trajectory_msgs/msg/JointTrajectory"],
                             trajectory_message(joints, ns, arrays), log_time=0, publish_time=0)
        for k in range(K):
            stamp = {"sec": int(ns[k] // 1_000_000_000), "nanosec": int(ns[k] % 1_000_000_000)}
            header = {"stamp": stamp, "frame_id": ""}
            when = dict(log_time=int(ns[k]), publish_time=int(ns[k]), sequence=k)
            writer.write_message(TOPIC_JOINT_STATES, schemas["sensor_msgs/msg/JointState"], {
                "header": header, "name": joints, "position": arrays["q"][k],
                "velocity": arrays["dq"][k], "effort": arrays["u"][k]}, **when)
            writer.write_message(TOPIC_ACCELERATIONS, schemas["trajectory_msgs/msg/JointTrajectory"], {
                "header": header, "joint_names": joints, "points": [{
                    "positions": [], "velocities": [], "accelerations": arrays["ddq"][k], "effort": [],
                    "time_from_start": stamp}]}, **when)
            if transforms:
                writer.write_message(TOPIC_TF, schemas["tf2_msgs/msg/TFMessage"], {"transforms": [{
                    "header": {"stamp": stamp, "frame_id": parent},
                    "child_frame_id": child,
                    "transform": {
                        "translation": dict(zip("xyz", p[k])),
                        "rotation": dict(zip("xyzw", r[k])),
                    }} for parent, child, p, r in transforms]}, **when)
            for i, track in enumerate(markers):
                writer.write_message(TOPIC_GOAL_MARKER, schemas[MARKER_TYPE], marker_message(track, i, k, stamp), **when)
        writer.add_metadata(METADATA_NAME, {"hoc_version": __version__, "task": task_text,
                                            "joints": json.dumps(joints), **meta})
        writer.add_attachment(0, 0, ATTACHMENT_URDF, "application/xml", urdf_text.encode())
        writer.add_attachment(0, 0, ATTACHMENT_TASK, "application/yaml", task_text.encode())
        if hermite is not None:
            writer.add_attachment(0, 0, ATTACHMENT_HERMITE, "application/json", hermite)
    finally:
        writer.finish()


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
            states, accels = [], []
            for _, channel, message, msg in reader.iter_decoded_messages(topics=[TOPIC_JOINT_STATES, TOPIC_ACCELERATIONS]):
                (states if channel.topic == TOPIC_JOINT_STATES else accels).append((message.log_time, msg))
    except InputFileError:
        raise
    except (InvalidMagic, EndOfFile):
        raise InputFileError("not an MCAP file (expected an MCAP plan written by hoc)", file=path) from None
    except (McapError, *_READ_ERRORS) as exc:
        raise InputFileError(f"damaged or truncated MCAP file ({type(exc).__name__}: {_first_line(exc)})", file=path) from None
    except Exception as exc:  # third-party reader and CDR decoder on damaged bytes: wrap whatever they raise
        raise InputFileError(f"damaged MCAP file ({type(exc).__name__}: {_first_line(exc)})", file=path) from None
    try:
        traj = _trajectory(path, states, accels)
    except (AttributeError, TypeError, ValueError, OverflowError) as exc:  # a message decoded into the wrong shape
        raise InputFileError(f"damaged {TOPIC_JOINT_STATES}/{TOPIC_ACCELERATIONS} messages ({_first_line(exc)})",
                             file=path) from None
    if ATTACHMENT_HERMITE in attachments:
        traj.mesh, traj.coeffs = _hermite(path, attachments[ATTACHMENT_HERMITE], traj.joints)
    return PlanFile(path=path, task_text=attachments[ATTACHMENT_TASK].decode("utf-8", "replace"),
                    urdf_text=attachments[ATTACHMENT_URDF].decode("utf-8", "replace"),
                    metadata=metadata, trajectory=traj, attachments=attachments)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0][:200] if text else ""


def _trajectory(path: Path, states: list, accels: list) -> Trajectory:
    if not states:
        raise InputFileError(f"not a hoc plan (no messages on {TOPIC_JOINT_STATES})", file=path)
    joints = tuple(states[0][1].name)
    n = len(joints)
    if len(accels) != len(states):
        raise InputFileError(f"{TOPIC_ACCELERATIONS} has {len(accels)} messages, expected one per "
                             f"{TOPIC_JOINT_STATES} message ({len(states)})", file=path)
    ns, q, dq, u, ddq = [], [], [], [], []
    for k, ((log_time, js), (log_time_a, acc)) in enumerate(zip(states, accels)):
        stamp = js.header.stamp.sec * 1_000_000_000 + js.header.stamp.nanosec
        if tuple(js.name) != joints or tuple(acc.joint_names) != joints:
            raise InputFileError(f"message {k} names joints {list(js.name)}, expected {list(joints)} as in the first", file=path)
        if log_time_a != log_time or stamp != log_time:
            raise InputFileError(f"message {k}: stamps of {TOPIC_JOINT_STATES} and {TOPIC_ACCELERATIONS} differ", file=path)
        if len(acc.points) != 1:
            raise InputFileError(f"{TOPIC_ACCELERATIONS} message {k} has {len(acc.points)} points, expected 1", file=path)
        rows = (js.position, js.velocity, js.effort, acc.points[0].accelerations)
        if any(len(r) != n for r in rows):
            raise InputFileError(f"message {k} has arrays of lengths {[len(r) for r in rows]}, expected {n} each", file=path)
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
