"""The convex primitives hoc takes exact distances to, and conservative fits of other geometry.

Every robot primitive is a capsule: the points within ``radius`` (m) of the segment [a, b]; a
sphere is a capsule with a = b. Obstacles are capsules (spheres, and cylinders as their enclosing
capsule), boxes and half-spaces. Points are (3,) arrays in metres, in the frame the caller states.

Fits are conservative: the capsule returned contains every given vertex, hence (being convex) the
vertices' convex hull; a box or cylinder becomes a capsule that contains it. The fit of a vertex
cloud tries the cloud's three principal axes, the frame's axes and its enclosing sphere, and keeps
the smallest volume.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class Capsule:
    """Points within ``radius`` (m) of the segment [a, b] (a = b: a sphere). a, b: (3,) m."""

    a: np.ndarray
    b: np.ndarray
    radius: float

    @property
    def length(self) -> float:
        """|b − a| in m."""
        return float(np.linalg.norm(self.b - self.a))

    @property
    def volume(self) -> float:
        """m³: π r² |b − a| + 4/3 π r³."""
        r = self.radius
        return math.pi * r * r * self.length + 4.0 / 3.0 * math.pi * r ** 3

    def moved(self, T: np.ndarray) -> "Capsule":
        """The capsule under the rigid transform T (4, 4)."""
        return Capsule(a=T[:3, :3] @ self.a + T[:3, 3], b=T[:3, :3] @ self.b + T[:3, 3], radius=self.radius)

    @property
    def is_sphere(self) -> bool:
        """True when a = b."""
        return bool(np.all(self.a == self.b))


@dataclass(frozen=True, eq=False)
class Box:
    """A box: centre (3,) m, rotation (3, 3) of its axes (columns) in the frame, half side lengths (3,) m."""

    center: np.ndarray
    rotation: np.ndarray
    half: np.ndarray

    @property
    def volume(self) -> float:
        """m³."""
        return float(8.0 * np.prod(self.half))

    def corners(self) -> np.ndarray:
        """(8, 3) corners in the frame."""
        signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
        return self.center + (signs * self.half) @ self.rotation.T


@dataclass(frozen=True, eq=False)
class HalfSpace:
    """The solid {x : normal · (x − point) <= 0}: the side of the plane through ``point`` opposite the unit ``normal``."""

    point: np.ndarray
    normal: np.ndarray

    @property
    def offset(self) -> float:
        """The offset normal · point (m): the solid is {x : normal · x <= offset}."""
        return float(self.normal @ self.point)


def sphere(center, radius: float) -> Capsule:
    """A sphere as a capsule with a = b."""
    c = np.asarray(center, dtype=float).reshape(3)
    return Capsule(a=c, b=c.copy(), radius=float(radius))


def cylinder_capsule(T: np.ndarray, radius: float, length: float) -> Capsule:
    """The capsule that contains a cylinder (axis z of pose T (4, 4), ``length`` m, ``radius`` m).

    Its segment is the cylinder's axis and its radius the cylinder's: every point of the cylinder is
    within ``radius`` of its axis segment. It adds a half-ball of volume 2/3 π r³ at each end.
    """
    half = np.array([0.0, 0.0, length / 2.0])
    return Capsule(a=T[:3, :3] @ -half + T[:3, 3], b=T[:3, :3] @ half + T[:3, 3], radius=float(radius))


def box_capsule(box: Box) -> Capsule:
    """The smallest capsule along one of the box's axes that contains its 8 corners (hence the box)."""
    best = None
    for k in range(3):
        c = _axis_capsule(box.corners(), box.rotation[:, k], box.center)
        if best is None or c.volume < best.volume:
            best = c
    return best  # type: ignore[return-value]


def _axis_capsule(V: np.ndarray, axis: np.ndarray, origin: np.ndarray) -> Capsule:
    """The capsule along ``axis`` (unit) containing every vertex V (k, 3), with the smallest radius.

    The axis line passes through the centre of the bounding rectangle of the vertices projected on
    the plane normal to it (through ``origin``); the radius is the largest distance of a vertex from
    that line, and each end of the segment is pulled in as far as every vertex stays inside.
    """
    axis = axis / np.linalg.norm(axis)
    u = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(axis, u)
    X = V - origin
    pu, pw = X @ u, X @ w
    centre = origin + u * (pu.max() + pu.min()) / 2 + w * (pw.max() + pw.min()) / 2
    X = V - centre
    s = X @ axis
    rho = np.linalg.norm(X - np.outer(s, axis), axis=1)
    r = float(rho.max())
    reach = np.sqrt(np.maximum(r * r - rho * rho, 0.0))
    lo, hi = float((s + reach).min()), float((s - reach).max())  # [lo, hi] must cover s ± reach
    if lo > hi:  # every vertex fits in the sphere of radius r about the middle: a sphere
        mid = (lo + hi) / 2
        c = centre + mid * axis
        return sphere(c, float(np.linalg.norm(V - c, axis=1).max()))
    a, b = centre + lo * axis, centre + hi * axis
    # round-off: grow the radius to cover every vertex as computed from the final segment
    r = max(r, float(point_segment_distance(V, a, b).max()))
    return Capsule(a=a, b=b, radius=r)


def point_segment_distance(P: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distances (k,) m of points P (k, 3) from the segment [a, b]."""
    d = b - a
    dd = float(d @ d)
    t = np.zeros(len(P)) if dd == 0.0 else np.clip((P - a) @ d / dd, 0.0, 1.0)
    return np.linalg.norm(P - (a + t[:, None] * d), axis=1)


def fit_vertices(V: np.ndarray) -> Capsule:
    """A capsule (or sphere) containing every vertex V (k, 3): the smallest by volume of the capsules
    along the vertices' three principal axes and the frame's x, y, z axes (CAD meshes are often
    aligned with them), and the sphere about their bounding-box centre.
    """
    V = np.asarray(V, dtype=float).reshape(-1, 3)
    mean = V.mean(axis=0)
    _, _, axes = np.linalg.svd(V - mean, full_matrices=False)
    centre = (V.max(axis=0) + V.min(axis=0)) / 2
    best = sphere(centre, float(np.linalg.norm(V - centre, axis=1).max()))
    for axis in np.concatenate([axes, np.eye(3)]):
        c = _axis_capsule(V, axis, mean)
        if c.volume < best.volume:
            best = c
    return best


def hull_volume(V: np.ndarray) -> float:
    """Volume (m³) of the convex hull of vertices V (k, 3); 0 for flat or too few vertices."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        return float(ConvexHull(np.asarray(V, dtype=float)).volume)
    except (QhullError, ValueError):
        return 0.0
