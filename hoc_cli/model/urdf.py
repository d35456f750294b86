"""URDF → :class:`RobotModel` (the XML itself is read by :mod:`hoc_cli.model.urdf_xml`).

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
import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ..errors import HocWarning, JointSelectionError, ModelError
from .spatial import align_z, joint_motion, motion_transform, spatial_inertia
from .tree import JOINT_TYPES, RobotModel
from .urdf_xml import UrdfSyntaxError, parse_robot

MOVABLE = JOINT_TYPES
SUPPORTED = MOVABLE + ("fixed",)
#: subtree inertia about a joint axis below this (kg·m² or kg) is treated as zero (singular M)
SINGULAR_INERTIA = 1e-12
#: largest magnitude accepted for a mass (kg), an inertia (kg·m²), an origin coordinate (m) or a mimic
#: multiplier/offset: far above anything physical, low enough that the dynamics cannot overflow
MAX_MAGNITUDE = 1e50


def _read(path, label: str | None = None) -> tuple[object, str, str]:
    """Read a URDF's links and joints; ModelError on a missing file, malformed XML or a bad value.

    Returns (robot, path, name): ``name`` is what messages call the file (``label``, else the path).
    """
    try:
        path = os.fspath(path)
    except TypeError:
        raise ModelError(f"expected a URDF file path, got {type(path).__name__}", file=label or str(path)) from None
    name = label or path
    try:
        exists, found = Path(path).exists(), Path(path).is_file()
    except (OSError, ValueError):  # a name the system cannot look up (too long, ...)
        exists = found = False
    if not found:
        what = "is not a regular file" if exists else "file not found"
        raise ModelError(f"{what} (expected a URDF file)", file=name)
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise ModelError(f"malformed XML ({exc}); expected a URDF document", file=name) from None
    except OSError as exc:
        raise ModelError(f"cannot be read ({exc.strerror})", file=name) from None
    if root.tag != "robot":
        raise ModelError(f"root element is <{root.tag}>, expected <robot>", file=name)
    try:
        robot = parse_robot(root)
    except UrdfSyntaxError as exc:
        raise ModelError(f"not a valid URDF: {exc.message}", file=name, key=exc.where) from None
    return robot, path, name


def _inertial(link) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """(mass kg, pose (4,4) of the inertial frame in the link frame, inertia (3,3) about the com)."""
    inertial = link.inertial
    if inertial is None:
        return 0.0, np.eye(4), np.zeros((3, 3))
    mass = float(inertial.mass) if inertial.mass is not None else 0.0
    origin = np.eye(4) if inertial.origin is None else np.asarray(inertial.origin, dtype=float)
    inertia = np.zeros((3, 3)) if inertial.inertia is None else np.asarray(inertial.inertia, dtype=float)
    return mass, origin, inertia


def _axis(joint) -> np.ndarray:
    return np.array([1.0, 0.0, 0.0]) if joint.axis is None else np.asarray(joint.axis, dtype=float)


def _origin(joint) -> np.ndarray:
    return np.eye(4) if joint.origin is None else np.asarray(joint.origin, dtype=float)


def _check(robot, path: str) -> tuple[str, dict, dict]:
    """Validate joint types, topology and inertias; return (root link, children map, links by name)."""
    links = {link.name: link for link in robot.links}
    if not links:
        raise ModelError("the URDF has no <link> (expected at least one)", file=path)
    for kind, items in (("link", robot.links), ("joint", robot.joints)):
        seen_names: set = set()
        for item in items:
            if item.name in seen_names:
                raise ModelError(f"two {kind}s are named {item.name!r} (names must be unique)",
                                 file=path, key=f"{kind} {item.name!r}")
            seen_names.add(item.name)
    parent_joint: dict[str, str] = {}
    children: dict[str, list] = {name: [] for name in links}
    for joint in robot.joints:
        key = f"joint {joint.name!r}"
        if joint.type in ("floating", "planar"):
            raise ModelError(
                f"{joint.type} joints are not supported (a fixed-base tree needs revolute, "
                "continuous, prismatic or fixed joints)", file=path, key=key)
        if joint.type not in SUPPORTED:
            raise ModelError(f"unknown joint type {joint.type!r} (expected one of {list(SUPPORTED)})",
                             file=path, key=key)
        for role, link in (("parent", joint.parent), ("child", joint.child)):
            if link not in links:
                raise ModelError(f"{role} link {link!r} is not defined by any <link>", file=path, key=key)
        if joint.child in parent_joint:
            raise ModelError(
                f"link {joint.child!r} is already the child of joint {parent_joint[joint.child]!r} "
                "(a closed loop; expected a tree)", file=path, key=key)
        parent_joint[joint.child] = joint.name
        children[joint.parent].append(joint)
        if joint.type in MOVABLE:
            axis = _axis(joint)
            if not np.all(np.isfinite(axis)) or np.linalg.norm(axis) < 1e-12:
                raise ModelError(f"axis {axis.tolist()} is not a non-zero vector", file=path, key=key)
            _check_joint_values(joint, path, key)
        origin = _origin(joint)
        if not np.all(np.isfinite(origin)):
            raise ModelError("origin is not finite (expected finite <origin xyz> and <origin rpy>)",
                             file=path, key=key)
        if np.abs(origin[:3, 3]).max() > MAX_MAGNITUDE:
            raise ModelError(f"<origin xyz> {origin[:3, 3].tolist()} m is beyond ±{MAX_MAGNITUDE:g} m "
                             "(expected a physical length)", file=path, key=key)
    roots = [name for name in links if name not in parent_joint]
    if len(roots) > 1:
        raise ModelError(
            f"several root links {roots} (expected exactly one link that is no joint's child)",
            file=path, key=f"link {roots[1]!r}")
    if not roots:
        cycle = _cycle(next(iter(links)), parent_joint, robot.joints)
        raise ModelError(f"every link is a joint's child: joints {cycle} form a cycle (expected a tree)",
                         file=path, key=f"joint {cycle[-1]!r}")
    root = roots[0]
    seen = set()
    stack = [root]
    while stack:
        name = stack.pop()
        seen.add(name)
        stack.extend(j.child for j in children[name])
    unreached = [name for name in links if name not in seen]
    if unreached:
        cycle = _cycle(unreached[0], parent_joint, robot.joints)
        raise ModelError(
            f"links {unreached} are not connected to the root {root!r}: joints {cycle} form a cycle "
            "(expected a tree)", file=path, key=f"joint {cycle[-1]!r}")
    # links welded to the root by fixed joints never move: their inertia never enters the dynamics,
    # so a CAD-rounding defect there (TIAGo's antennas: principal moments down to -3.5e-8 kg·m²) is
    # not a reason to refuse the robot
    static = {root}
    stack = [root]
    while stack:
        for j in children[stack.pop()]:
            if j.type == "fixed":
                static.add(j.child)
                stack.append(j.child)
    for link in robot.links:
        key = f"link {link.name!r}"
        mass, origin, inertia = _inertial(link)
        for what, values, unit in (("<mass value>", mass, "kg"), ("<inertial><origin>", origin, "m"),
                                   ("<inertia>", inertia, "kg·m²")):
            if not np.all(np.isfinite(values)):
                raise ModelError(f"{what} is not finite (expected a finite number in {unit})", file=path, key=key)
            if np.abs(values).max() > MAX_MAGNITUDE:
                raise ModelError(f"{what} is beyond ±{MAX_MAGNITUDE:g} {unit} (expected a physical value)",
                                 file=path, key=key)
        if mass < 0.0:
            raise ModelError(f"mass {mass} kg is negative (expected >= 0)", file=path, key=key)
        scale = max(1.0, float(np.abs(inertia).max()))
        if np.abs(inertia - inertia.T).max() > 1e-12 * scale:
            raise ModelError("inertia tensor is not symmetric", file=path, key=key)
        eig = np.linalg.eigvalsh(inertia)
        if eig.min() < -1e-12 * scale and link.name not in static:
            raise ModelError(
                f"inertia tensor is not positive (semi)definite: principal moments {eig.tolist()} "
                "kg·m² (expected all >= 0)", file=path, key=key)
    return root, children, links


def _check_joint_values(joint, path: str, key: str) -> None:
    """A movable joint's limits and mimic: finite numbers, and a mimic of another joint."""
    if joint.limit is not None:
        for attribute in ("lower", "upper", "velocity", "effort"):
            value = getattr(joint.limit, attribute)
            if value is not None and not math.isfinite(value):
                raise ModelError(f"<limit {attribute}> is {value} (expected a finite number; leave the attribute "
                                 "out for no limit)", file=path, key=key)
    if joint.mimic is not None:
        if joint.mimic.joint == joint.name:
            raise ModelError("<mimic joint> names the joint itself (expected another joint)", file=path, key=key)
        for attribute in ("multiplier", "offset"):
            value = getattr(joint.mimic, attribute)
            if value is not None and not (math.isfinite(value) and abs(value) <= MAX_MAGNITUDE):
                raise ModelError(f"<mimic {attribute}> is {value} (expected a finite number within "
                                 f"±{MAX_MAGNITUDE:g})", file=path, key=key)


def _cycle(start: str, parent_joint: dict[str, str], joints: list) -> list[str]:
    """The joints of the cycle reached by walking up from link ``start`` (every link on the way has a
    parent joint), in document order: the last one is the joint that closes it, the one to blame."""
    by_name = {j.name: j for j in joints}
    path: list[str] = []
    seen: dict[str, int] = {}
    link = start
    while link not in seen:
        seen[link] = len(path)
        path.append(parent_joint[link])
        link = by_name[parent_joint[link]].parent
    members = set(path[seen[link]:])
    return [j.name for j in joints if j.name in members]


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

    Args:
        path: URDF file.
        joints: movable joints that become degrees of freedom, in the order wanted for the
            ``(K, n)`` sample arrays; default: every revolute, continuous and prismatic non-mimic
            joint in URDF tree order (depth-first from the root, children in document order).
        locked: value (rad or m) of locked movable joints (every movable joint not in ``joints``;
            default 0.0). Mimic joints are always locked (see the module docstring).
        gravity: (3,) m/s² in the root-link frame.
        label: what messages call the file (default: ``path``), e.g. ``plan.mcap: attachment
            robot.urdf`` for a URDF extracted to a scratch file.

    Raises:
        ModelError: naming the file and the joint or link at fault, for a missing or malformed
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
    m, centre of mass in the link frame). Raises ModelError like :func:`load_robot`."""
    robot, _, name = _read(path, label)
    _check(robot, name)
    rows = []
    for link in robot.links:
        mass, origin, _ = _inertial(link)
        rows.append({"name": link.name, "mass": mass, "com": origin[:3, 3].tolist()})
    return rows
