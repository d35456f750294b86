"""Reading and checking a URDF before it becomes a model: file and XML, topology, values.

:func:`read` parses the file (:mod:`hoc_cli.model.urdf_xml`); :func:`check` validates joint types,
the tree (one root, no cycle: a cycle is blamed on the joint that closes it), every number (finite;
masses, inertias, origins and mimic factors within ±``MAX_MAGNITUDE``; limits finite) and the
inertias. Every failure is a :class:`hoc_cli.errors.ModelError` naming the file, the joint or link
and the attribute.
"""
from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ..errors import ModelError
from .tree import JOINT_TYPES
from .urdf_xml import UrdfSyntaxError, parse_robot

MOVABLE = JOINT_TYPES
SUPPORTED = MOVABLE + ("fixed",)
#: largest magnitude accepted for a mass (kg), an inertia (kg·m²), an origin coordinate (m) or a mimic
#: multiplier/offset: far above anything physical, low enough that the dynamics cannot overflow
MAX_MAGNITUDE = 1e50


def read(path, label: str | None = None) -> tuple[object, str, str]:
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


def link_inertial(link) -> tuple[float, np.ndarray, np.ndarray]:
    """(mass kg, pose (4,4) of the inertial frame in the link frame, inertia (3,3) about the com)."""
    inertial = link.inertial
    if inertial is None:
        return 0.0, np.eye(4), np.zeros((3, 3))
    mass = float(inertial.mass) if inertial.mass is not None else 0.0
    origin = np.eye(4) if inertial.origin is None else np.asarray(inertial.origin, dtype=float)
    inertia = np.zeros((3, 3)) if inertial.inertia is None else np.asarray(inertial.inertia, dtype=float)
    return mass, origin, inertia


def joint_axis(joint) -> np.ndarray:
    return np.array([1.0, 0.0, 0.0]) if joint.axis is None else np.asarray(joint.axis, dtype=float)


def joint_origin(joint) -> np.ndarray:
    return np.eye(4) if joint.origin is None else np.asarray(joint.origin, dtype=float)


def check(robot, path: str) -> tuple[str, dict, dict]:
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
            axis = joint_axis(joint)
            if not np.all(np.isfinite(axis)) or np.linalg.norm(axis) < 1e-12:
                raise ModelError(f"axis {axis.tolist()} is not a non-zero vector", file=path, key=key)
            _check_joint_values(joint, path, key)
        origin = joint_origin(joint)
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
        mass, origin, inertia = link_inertial(link)
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
