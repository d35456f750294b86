"""The URDF elements hoc needs, read with the standard library's XML parser.

The kinematic and inertial description is read: ``<link>`` (name, ``<inertial>``: origin,
mass, inertia) and ``<joint>`` (name, type, parent, child, origin, axis, limit, mimic); a link's
``<collision>`` elements are kept as written (origin and the ``<geometry>`` element's tag and
attributes, checked by :mod:`hoc_cli.io.collision_geometry` when collision checking asks for them).
Visuals, materials, transmissions and ``<gazebo>`` tags are ignored. Units are the URDF's: m,
rad, kg, kg·m², N·m (N), rad/s (m/s).

Conventions (URDF specification, wiki.ros.org/urdf/XML): an origin is the transform
T = Trans(xyz) · Rz(yaw) Ry(pitch) Rx(roll) with rpy = (roll, pitch, yaw), both default 0; a missing
``<axis>`` is (1, 0, 0); a missing ``<origin>``, ``<inertial>`` or ``<limit>`` is None (the caller
decides the default); limit attributes that are absent are None; mimic multiplier and offset default
to 1 and 0. A number that does not parse raises :class:`UrdfSyntaxError` naming the element and
attribute; range checks (finite, non-zero axis, positive inertia) are the caller's.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

import numpy as np


class UrdfSyntaxError(ValueError):
    """An element or attribute is missing or not a number. ``where`` names it (e.g. "link 'a'")."""

    def __init__(self, where: str, message: str) -> None:
        super().__init__(f"{where}: {message}")
        self.where = where
        self.message = message


@dataclass
class Inertial:
    origin: np.ndarray | None  # (4, 4) pose of the centre-of-mass frame in the link frame
    mass: float | None         # kg
    inertia: np.ndarray | None  # (3, 3) about the centre of mass, in the inertial frame, kg·m²


@dataclass
class Collision:
    origin: np.ndarray | None   # (4, 4) pose of the geometry in the link frame (None: identity)
    shape: str | None           # the <geometry> child's tag (box, sphere, cylinder, mesh, ...), None if absent
    attributes: dict[str, str]  # that element's attributes as written (size, radius, length, filename, scale)
    error: str | None = None    # why the origin does not parse (kept, not raised: only collision checking reads it)


@dataclass
class Link:
    name: str
    inertial: Inertial | None = None
    collisions: list[Collision] = field(default_factory=list)


@dataclass
class Limit:
    lower: float | None = None
    upper: float | None = None
    velocity: float | None = None
    effort: float | None = None


@dataclass
class Mimic:
    joint: str | None
    multiplier: float = 1.0
    offset: float = 0.0


@dataclass
class Joint:
    name: str
    type: str | None
    parent: str | None
    child: str | None
    origin: np.ndarray | None = None  # (4, 4) child joint frame in the parent link frame
    axis: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0]))
    limit: Limit | None = None
    mimic: Mimic | None = None


@dataclass
class Robot:
    name: str | None
    links: list[Link]
    joints: list[Joint]


def rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """(3, 3) rotation Rz(yaw) · Ry(pitch) · Rx(roll) (fixed-axis x, then y, then z); NaN entries for
    a non-finite angle (reported by the caller's finiteness checks).
    """
    with np.errstate(invalid="ignore"):
        cr, sr, cp, sp, cy, sy = (np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch),
                                  np.cos(yaw), np.sin(yaw))
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def _numbers(text: str, count: int, where: str, what: str) -> list[float]:
    expected = "a number" if count == 1 else f"{count} numbers"
    try:
        values = [float(p) for p in text.split()]
    except ValueError:
        values = []
    if len(values) != count:
        raise UrdfSyntaxError(where, f"{what}={text!r} is not {expected}")
    return values


def _number(element: ET.Element, attribute: str, where: str, default: float | None) -> float | None:
    text = element.get(attribute)
    if text is None:
        return default
    return _numbers(text, 1, where, f"<{element.tag} {attribute}>")[0]


def _origin(element: ET.Element | None, where: str) -> np.ndarray | None:
    if element is None:
        return None
    xyz = _numbers(element.get("xyz", "0 0 0"), 3, where, "<origin xyz>")
    rpy = _numbers(element.get("rpy", "0 0 0"), 3, where, "<origin rpy>")
    T = np.eye(4)
    T[:3, :3] = rpy_matrix(*rpy)
    T[:3, 3] = xyz
    return T


def _inertial(element: ET.Element | None, where: str) -> Inertial | None:
    if element is None:
        return None
    mass_el = element.find("mass")
    mass = None if mass_el is None else _number(mass_el, "value", where, None)
    if mass_el is not None and mass is None:
        raise UrdfSyntaxError(where, "<mass> has no value attribute")
    inertia_el = element.find("inertia")
    inertia = None
    if inertia_el is not None:
        names = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
        missing = [a for a in names if inertia_el.get(a) is None]
        if missing:
            raise UrdfSyntaxError(where, f"<inertia> lacks {', '.join(missing)} (all six are required)")
        ixx, ixy, ixz, iyy, iyz, izz = (_number(inertia_el, a, where, None) for a in names)
        inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]], dtype=float)
    return Inertial(origin=_origin(element.find("origin"), where), mass=mass, inertia=inertia)


def _link_name(element: ET.Element, role: str, where: str) -> str | None:
    el = element.find(role)
    if el is None:
        raise UrdfSyntaxError(where, f"has no <{role}> element")
    name = el.get("link")
    if name is None:
        raise UrdfSyntaxError(where, f"<{role}> has no link attribute")
    return name


def _joint(element: ET.Element) -> Joint:
    name = element.get("name")
    if name is None:
        raise UrdfSyntaxError("a <joint>", "has no name attribute")
    where = f"joint {name!r}"
    joint = Joint(name=name, type=element.get("type"), parent=_link_name(element, "parent", where),
                  child=_link_name(element, "child", where), origin=_origin(element.find("origin"), where))
    axis = element.find("axis")
    if axis is not None:
        joint.axis = np.array(_numbers(axis.get("xyz", "1 0 0"), 3, where, "<axis xyz>"))
    limit = element.find("limit")
    if limit is not None:
        joint.limit = Limit(**{a: _number(limit, a, where, None) for a in ("lower", "upper", "velocity", "effort")})
    mimic = element.find("mimic")
    if mimic is not None:
        joint.mimic = Mimic(joint=mimic.get("joint"), multiplier=_number(mimic, "multiplier", where, 1.0),
                            offset=_number(mimic, "offset", where, 0.0))
    return joint


def _link(element: ET.Element) -> Link:
    name = element.get("name")
    if name is None:
        raise UrdfSyntaxError("a <link>", "has no name attribute")
    where = f"link {name!r}"
    return Link(name=name, inertial=_inertial(element.find("inertial"), where),
                collisions=[_collision(e, where) for e in element.findall("collision")])


def _collision(element: ET.Element, where: str) -> Collision:
    geometry = element.find("geometry")
    shape = None if geometry is None or len(geometry) == 0 else geometry[0]
    try:
        origin, error = _origin(element.find("origin"), where), None
    except UrdfSyntaxError as exc:
        origin, error = None, exc.message
    return Collision(origin=origin, shape=None if shape is None else shape.tag,
                     attributes={} if shape is None else dict(shape.attrib), error=error)


def parse_robot(root: ET.Element) -> Robot:
    """The links and joints of a parsed ``<robot>`` element, in document order.

    Raises
    ------
    UrdfSyntaxError
        a link or joint lacks a name, a joint its parent or child, or a number
        does not parse.
    """
    return Robot(name=root.get("name"), links=[_link(e) for e in root.findall("link")],
                 joints=[_joint(e) for e in root.findall("joint")])
