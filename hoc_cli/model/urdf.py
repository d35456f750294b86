"""URDF → :class:`RobotModel` (the XML is read by :mod:`hoc_cli.model.urdf_xml` and checked by
:mod:`hoc_cli.model.urdf_checks`).

Every failure while reading a URDF is raised as :class:`hoc_cli.errors.ModelError` naming the file
and the joint or link at fault; no other exception type leaves :func:`load_robot`.

Locking: every movable joint not listed in ``joints`` is locked at ``locked.get(name, 0.0)`` and,
like a fixed joint, merges its child link into the parent body. Mimic joints are always locked
(they cannot be task joints); a mimic joint without its own ``locked`` entry is locked at
``multiplier * locked.get(master, 0.0) + offset``.
"""
from __future__ import annotations

import math
import warnings

import numpy as np

from ..errors import HocWarning, JointSelectionError, ModelError
from .spatial import align_z, joint_motion, motion_transform, spatial_inertia
from .tree import RobotModel
from .urdf_checks import MOVABLE
from .urdf_checks import check as _check
from .urdf_checks import joint_axis as _axis
from .urdf_checks import joint_origin as _origin
from .urdf_checks import link_inertial as _inertial
from .urdf_checks import read as _read

#: subtree inertia about a joint axis below this (kg·m² or kg) is treated as zero (singular M)
SINGULAR_INERTIA = 1e-12


def _dfs(root: str, children: dict) -> list:
    """Joints depth-first from the root, children in document order (iterative: deep chains are fine)."""
    out = []
    stack = [iter(children[root])]
    while stack:
        joint = next(stack[-1], None)
        if joint is None:
            stack.pop()
            continue
        out.append(joint)
        stack.append(iter(children[joint.child]))
    return out


def load_robot(path, joints: list[str] | None = None, locked: dict[str, float] | None = None,
               gravity=(0.0, 0.0, -9.81), *, label: str | None = None) -> RobotModel:
    """Read a URDF into a :class:`RobotModel`.

    Parameters
    ----------
    path
        URDF file.
    joints
        movable joints that become degrees of freedom, in the order wanted for the
        ``(K, n)`` sample arrays; default: every revolute, continuous and prismatic non-mimic
        joint in URDF tree order (depth-first from the root, children in document order).
    locked
        value (rad or m) of locked movable joints (every movable joint not in ``joints``;
        default 0.0). Mimic joints are always locked (see the module docstring).
    gravity
        (3,) m/s² in the root-link frame.
    label
        what messages call the file (default: ``path``), e.g. ``plan.mcap: attachment
        robot.urdf`` for a URDF extracted to a scratch file.

    Raises
    ------
    ModelError
        naming the file and the joint or link at fault, for a missing or malformed
        file, a floating/planar joint, a cycle, several roots, a negative mass, an inertia that
        is not positive semidefinite, a movable joint whose subtree has no mass or no inertia
        about its axis (a singular mass matrix). A ``joints``, ``locked`` or ``gravity`` value that
        does not fit the URDF raises the subclass :class:`JointSelectionError`, whose
        ``task_key`` names the task key at fault (``joints[1]``, ``locked.wrist``, ``gravity``).
    """
    robot, path, src = _read(path, label)
    root, children, links = _check(robot, src)
    tree = _dfs(root, children)
    by_name = {j.name: j for j in robot.joints}
    movable = [j.name for j in tree if j.type in MOVABLE and j.mimic is None]

    def selection_error(message: str, task_key: str, key: str | None = None) -> JointSelectionError:
        return JointSelectionError(message, file=src, key=key or task_key, task_key=task_key)

    try:
        g = np.array(gravity, dtype=float).reshape(3)
    except (TypeError, ValueError):
        raise selection_error(f"gravity {gravity!r} is not 3 numbers (m/s²)", "gravity") from None
    if not np.all(np.isfinite(g)):
        raise selection_error(f"gravity {g.tolist()} is not finite", "gravity")

    user_joints = joints is not None
    if joints is None:
        joints = list(movable)
    if isinstance(joints, str) or not hasattr(joints, "__iter__"):
        raise selection_error(f"joints must be a list of joint names, got {joints!r}", "joints")
    joints = list(joints)
    for i, name in enumerate(joints):
        key = f"joint {name!r}"
        if name not in by_name:
            raise selection_error(f"no such joint in {src} (movable joints: {movable})", f"joints[{i}]", key)
        joint = by_name[name]
        if joint.type not in MOVABLE:
            raise selection_error(f"is a {joint.type} joint in {src} (expected one of {movable})", f"joints[{i}]", key)
        if joint.mimic is not None:
            raise selection_error(f"is a mimic joint of {joint.mimic.joint!r} in {src}; mimic joints are always "
                                  f"locked (expected one of {movable})", f"joints[{i}]", key)
    if len(set(joints)) != len(joints):
        dup = next(n for n in joints if joints.count(n) > 1)
        raise selection_error("is listed twice in joints", f"joints[{len(joints) - 1 - joints[::-1].index(dup)}]",
                              f"joint {dup!r}")
    try:
        locked = dict(locked or {})
    except (TypeError, ValueError):
        raise selection_error(f"locked must map joint names to values, got {locked!r}", "locked") from None
    for name, value in locked.items():
        key = f"joint {name!r}"
        if name not in by_name or by_name[name].type not in MOVABLE:
            all_movable = [j.name for j in tree if j.type in MOVABLE]
            raise selection_error(f"cannot be locked: not a movable joint of {src} (movable joints: "
                                  f"{all_movable})", f"locked.{name}", key)
        if name in joints:
            raise selection_error("is both a task joint and locked (expected one or the other)", f"locked.{name}", key)
        try:
            value = float(value)
        except (TypeError, ValueError):
            raise selection_error(f"locked value {value!r} is not a number", f"locked.{name}", key) from None
        if not math.isfinite(value):
            raise selection_error(f"locked value {value} is not finite", f"locked.{name}", key)
        locked[name] = value

    if not joints:
        message = (f"has no movable joints to plan (expected at least one revolute, continuous or "
                   f"prismatic joint; movable joints: {movable})")
        if user_joints:
            raise selection_error(message, "joints")
        raise ModelError(message, file=src, key="joints")
    for joint in robot.joints:
        if joint.mimic is None:
            continue
        master = joint.mimic.joint
        if master not in by_name or by_name[master].type not in MOVABLE:
            raise ModelError(f"mimics {master!r}, which is not a movable joint of the URDF", file=src,
                             key=f"joint {joint.name!r}")
        if master in joints:
            warnings.warn(HocWarning(f"{src}: joint {joint.name!r} mimics task joint {master!r} but hoc holds it "
                                     f"fixed (mimic coupling is not modelled); lock {master!r} for exact dynamics"),
                          stacklevel=2)

    index = {name: i for i, name in enumerate(joints)}
    n = len(joints)
    parent = np.full(n, -1, dtype=int)
    axis_out = np.zeros((n, 3))
    tree_transform = np.zeros((n, 4, 4))
    inertia = np.zeros((n, 6, 6))
    body_mass = np.zeros(n)
    lower = np.full(n, -np.inf)
    upper = np.full(n, np.inf)
    vel = np.full(n, np.inf)
    eff = np.full(n, np.inf)
    order: list[int] = []
    locked_values: dict[str, float] = {}

    # link name -> (body index, pose of the link frame in the body frame)
    place: dict[str, tuple[int, np.ndarray]] = {root: (-1, np.eye(4))}
    for joint in tree:
        body, P = place[joint.parent]
        T = P @ _origin(joint)
        if joint.name in index:
            i = index[joint.name]
            axis = _axis(joint)
            axis = axis / np.linalg.norm(axis)
            A = np.eye(4)
            A[:3, :3] = align_z(axis)
            parent[i] = body
            axis_out[i] = axis
            tree_transform[i] = T @ A
            A_inv = np.eye(4)
            A_inv[:3, :3] = A[:3, :3].T
            place[joint.child] = (i, A_inv)
            order.append(i)
            if joint.type != "continuous" and joint.limit is not None:
                if joint.limit.lower is not None:
                    lower[i] = float(joint.limit.lower)
                if joint.limit.upper is not None:
                    upper[i] = float(joint.limit.upper)
            if joint.limit is not None:
                if joint.limit.velocity is not None:
                    vel[i] = float(joint.limit.velocity)
                if joint.limit.effort is not None:
                    eff[i] = float(joint.limit.effort)
        else:
            if joint.type in MOVABLE:
                if joint.name in locked:
                    value = locked[joint.name]
                elif joint.mimic is not None:
                    m = joint.mimic
                    value = (1.0 if m.multiplier is None else float(m.multiplier)) * locked.get(m.joint, 0.0) \
                        + (0.0 if m.offset is None else float(m.offset))
                else:
                    value = 0.0
                locked_values[joint.name] = value
                T = T @ joint_motion(joint.type, _axis(joint) / np.linalg.norm(_axis(joint)), value)
            place[joint.child] = (body, T)

    link_names = tuple(link.name for link in robot.links)
    link_body = np.array([place[name][0] for name in link_names], dtype=int)
    link_offset = np.array([place[name][1] for name in link_names]).reshape(-1, 4, 4)
    total_mass = 0.0
    for link in robot.links:
        mass, origin, I_com = _inertial(link)
        total_mass += mass
        body, P = place[link.name]
        if body < 0 or mass == 0.0:
            continue
        T = P @ origin
        R = T[:3, :3]
        inertia[body] += spatial_inertia(mass, T[:3, 3], R @ I_com @ R.T)
        body_mass[body] += mass

    tree_motion = np.array([motion_transform(T) for T in tree_transform]).reshape(n, 6, 6)
    # composite inertia of every subtree at q = 0; its component along the joint axis must be > 0
    composite = inertia.copy()
    for i in reversed(order):
        if parent[i] >= 0:
            X = tree_motion[i]
            composite[parent[i]] += X.T @ composite[i] @ X
    for i in order:
        if not np.all(np.isfinite(composite[i])):
            raise ModelError(
                "the inertia of the bodies it moves overflows (masses, inertias or lengths too large, "
                "or a locked prismatic joint placed too far)", file=src, key=f"joint {joints[i]!r}")
        row = 5 if by_name[joints[i]].type == "prismatic" else 2
        if composite[i][row, row] <= SINGULAR_INERTIA:
            what = "mass" if composite[i][5, 5] <= SINGULAR_INERTIA else "inertia about its axis"
            raise ModelError(
                f"the bodies it moves have no {what} (a singular mass matrix); give its child links "
                "an <inertial>, or lock the joint", file=src, key=f"joint {joints[i]!r}")

    return RobotModel(
        name=str(robot.name),
        joint_names=tuple(joints),
        joint_types=tuple(by_name[name].type for name in joints),
        parent=parent,
        order=np.array(order, dtype=int),
        axis=axis_out,
        tree_transform=tree_transform,
        tree_motion=tree_motion,
        inertia=inertia,
        body_mass=body_mass,
        lower=lower,
        upper=upper,
        velocity_limit=vel,
        effort_limit=eff,
        gravity=g,
        urdf_path=path,
        total_mass=float(total_mass),
        root_link=root,
        link_names=link_names,
        link_body=link_body,
        link_offset=link_offset,
        locked=locked_values,
    )


def urdf_joint_table(path, *, label: str | None = None) -> list[dict]:
    """Every URDF joint as written (before merging), in tree order, for ``hoc inspect``.

    Each dict: ``name``, ``type``, ``axis`` (3 floats, normalised; None for fixed joints),
    ``parent``, ``child`` (link names), ``lower``, ``upper`` (rad or m), ``velocity`` (rad/s or
    m/s), ``effort`` (N·m or N) — None where the URDF gives none — and ``mimic`` (master joint
    name or None). Raises ModelError like :func:`load_robot`.
    """
    robot, _, name = _read(path, label)
    root, children, _ = _check(robot, name)
    rows = []
    for joint in _dfs(root, children):
        movable = joint.type in MOVABLE
        axis = _axis(joint)
        limit = joint.limit if movable else None
        rows.append({
            "name": joint.name,
            "type": joint.type,
            "axis": (axis / np.linalg.norm(axis)).tolist() if movable else None,
            "parent": joint.parent,
            "child": joint.child,
            "lower": None if limit is None or limit.lower is None or joint.type == "continuous" else float(limit.lower),
            "upper": None if limit is None or limit.upper is None or joint.type == "continuous" else float(limit.upper),
            "velocity": None if limit is None or limit.velocity is None else float(limit.velocity),
            "effort": None if limit is None or limit.effort is None else float(limit.effort),
            "mimic": None if joint.mimic is None else joint.mimic.joint,
        })
    return rows


def urdf_link_table(path, *, label: str | None = None) -> list[dict]:
    """Every URDF link as written, in document order: ``name``, ``mass`` (kg) and ``com`` (3 floats,
    m, centre of mass in the link frame). Raises ModelError like :func:`load_robot`.
    """
    robot, _, name = _read(path, label)
    _check(robot, name)
    rows = []
    for link in robot.links:
        mass, origin, _ = _inertial(link)
        rows.append({"name": link.name, "mass": mass, "com": origin[:3, 3].tolist()})
    return rows
