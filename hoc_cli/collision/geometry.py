"""Geometry as written (a URDF ``<collision>``, a task's link override or obstacle) and its primitives.

A :class:`Shape` is a solid as the user wrote it, placed by ``pose`` (4, 4) in its frame (a link
frame for robot geometry, the URDF root frame for obstacles). :func:`robot_capsule` turns it into
the capsule hoc checks for a robot link (boxes, cylinders and meshes are enclosed, see
:mod:`hoc_cli.collision.shapes`); :func:`obstacle_primitive` into the exact capsule, box or
half-space of an obstacle (a cylinder becomes its enclosing capsule).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from hoc_cli.collision.shapes import Box, Capsule, HalfSpace, box_capsule, cylinder_capsule, fit_vertices, hull_volume

KINDS = ("sphere", "capsule", "box", "cylinder", "mesh", "half_space")


@dataclass(frozen=True, eq=False)
class Shape:
    """A solid as written. Lengths in m; the fields a kind does not use are None.

    kind : one of ``KINDS``.
    pose : (4, 4) the shape's frame in the frame it is given in (sphere: centre; box: centre and axes;
        cylinder: centre, axis z; capsule: a and b are given in this frame; half-space: the plane
        passes through the origin, the solid is on the side opposite ``normal``; mesh: the vertices' frame).
    radius, length : sphere, capsule, cylinder radius; cylinder length along z.
    size : (3,) box side lengths (full lengths, as URDF and MoveIt give them).
    a, b : (3,) capsule segment ends.
    normal : (3,) unit outward normal of a half-space, in the shape's frame.
    vertices : (k, 3) mesh vertices (already scaled), in the shape's frame.
    source : what produced it, for messages (e.g. a mesh file name).
    """

    kind: str
    pose: np.ndarray = field(default_factory=lambda: np.eye(4))
    radius: float | None = None
    length: float | None = None
    size: np.ndarray | None = None
    a: np.ndarray | None = None
    b: np.ndarray | None = None
    normal: np.ndarray | None = None
    vertices: np.ndarray | None = None
    source: str = ""

    @property
    def volume(self) -> float:
        """m³ of the solid as written (a mesh: its convex hull; a half-space: inf)."""
        if self.kind == "sphere":
            return 4.0 / 3.0 * math.pi * self.radius ** 3
        if self.kind == "capsule":
            return Capsule(np.asarray(self.a), np.asarray(self.b), self.radius).volume
        if self.kind == "box":
            return float(np.prod(self.size))
        if self.kind == "cylinder":
            return math.pi * self.radius ** 2 * self.length
        if self.kind == "mesh":
            return hull_volume(self.vertices)
        return math.inf


def _box(shape: Shape) -> Box:
    return Box(center=shape.pose[:3, 3].copy(), rotation=shape.pose[:3, :3].copy(), half=np.asarray(shape.size) / 2.0)


def robot_capsule(shape: Shape) -> Capsule:
    """The capsule (a sphere when a = b) that represents ``shape`` on a robot link, in the shape's frame
    of reference (the link frame): exact for a sphere or capsule, enclosing for a box, cylinder or mesh.
    """
    T = shape.pose
    if shape.kind == "sphere":
        c = T[:3, 3]
        return Capsule(a=c.copy(), b=c.copy(), radius=float(shape.radius))
    if shape.kind == "capsule":
        return Capsule(a=np.asarray(shape.a, float), b=np.asarray(shape.b, float), radius=float(shape.radius)).moved(T)
    if shape.kind == "box":
        return box_capsule(_box(shape))
    if shape.kind == "cylinder":
        return cylinder_capsule(T, float(shape.radius), float(shape.length))
    if shape.kind == "mesh":
        V = np.asarray(shape.vertices, float)
        return fit_vertices(V @ T[:3, :3].T + T[:3, 3])
    raise ValueError(f"a {shape.kind} cannot be robot geometry")


def obstacle_primitive(shape: Shape) -> Capsule | Box | HalfSpace:
    """The primitive hoc checks for an obstacle (root frame): exact, except a cylinder (its enclosing capsule)
    and a mesh (the capsule fitted to its vertices).
    """
    if shape.kind == "box":
        return _box(shape)
    if shape.kind == "half_space":
        n = shape.pose[:3, :3] @ np.asarray(shape.normal, float)
        return HalfSpace(point=shape.pose[:3, 3].copy(), normal=n / np.linalg.norm(n))
    return robot_capsule(shape)
