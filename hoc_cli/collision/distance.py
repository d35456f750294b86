"""Signed distances between a capsule and a capsule, a box or a half-space, batched with numpy.

Every function takes arrays with any common leading shape ``S`` (samples × pairs, ...), points as
(S, 3) in one frame, in metres, and returns a :class:`Contact` of arrays over ``S``. The first
shape, A, is always the capsule (a sphere when a = b). Signed distance: the distance between the
two solids when they are apart, minus the penetration depth (the length of the shortest
translation that separates them) when they overlap.

Formulas (docs/collision.md): capsule–capsule is the segment–segment distance minus both radii;
capsule–half-space the lower end's height minus the radius; capsule–box minimises the convex,
piecewise-quadratic squared distance from the segment's points to the box over the segment's
parameter (the minimum lies at a knot where the segment crosses a face plane, at an end, or at the
stationary point of a piece) and, when the segment meets the box, takes the penetration depth by
separating axes: the box's face normals and the cross products of its axes with the segment, the
facet normals of box ⊕ (−segment).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

EPS = 1e-300


@dataclass(frozen=True, eq=False)
class Contact:
    """Signed distance and witnesses, arrays over the leading shape S.

    distance : (S,) m, negative when the solids overlap.
    normal : (S, 3) unit; moving A by δ along it changes the distance by δ (to first order).
    point_a, point_b : (S, 3) m, the witness points on A and on B; point_a − point_b = distance · normal
        (for a box it is the deepest point of A and its projection on the separating face when they overlap).
    """

    distance: np.ndarray
    normal: np.ndarray
    point_a: np.ndarray
    point_b: np.ndarray


def _dot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", x, y)


def _unit(v: np.ndarray, fallback: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(v / |v| where |v| > 0 else the unit fallback, |v|)."""
    n = np.linalg.norm(v, axis=-1)
    ok = n > 0
    u = np.where(ok[..., None], v / np.where(ok, n, 1.0)[..., None], fallback)
    return u, n


def _perpendicular(d: np.ndarray) -> np.ndarray:
    """A unit vector perpendicular to each d (S, 3) (any unit vector where d = 0)."""
    e = np.where((np.abs(d[..., 0]) < 0.9 * np.linalg.norm(d, axis=-1))[..., None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    u, _ = _unit(np.cross(d, e), np.array([0.0, 0.0, 1.0]))
    return u


def segment_segment(p1, q1, p2, q2) -> tuple[np.ndarray, np.ndarray]:
    """Parameters (s, t), each (S,) in [0, 1], of the closest points p1 + s(q1 − p1), p2 + t(q2 − p2).

    Minimises |x1(s) − x2(t)|² over the unit square: the unconstrained minimiser in s with t
    eliminated, clamped; then t for that s, clamped, and s recomputed for a clamped t (the
    minimiser of a convex quadratic over a square lies on this path). Degenerate segments
    (points) and parallel segments are handled.
    """
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f = _dot(d1, d1), _dot(d2, d2), _dot(d2, r)
    c, b = _dot(d1, r), _dot(d1, d2)
    denom = a * e - b * b
    tiny = 1e-14 * np.maximum(a * e, EPS)
    point1, point2 = a <= EPS, e <= EPS
    s = np.where(denom > tiny, np.clip((b * f - c * e) / np.where(denom > tiny, denom, 1.0), 0.0, 1.0), 0.0)
    t = (b * s + f) / np.where(point2, 1.0, e)
    s_low = np.clip(-c / np.where(point1, 1.0, a), 0.0, 1.0)
    s_high = np.clip((b - c) / np.where(point1, 1.0, a), 0.0, 1.0)
    s = np.where(t < 0.0, s_low, np.where(t > 1.0, s_high, s))
    t = np.clip(t, 0.0, 1.0)
    # points: one parameter is free of the other
    s = np.where(point2 & ~point1, s_low, s)
    t = np.where(point2, 0.0, t)
    t = np.where(point1 & ~point2, np.clip(f / np.where(point2, 1.0, e), 0.0, 1.0), t)
    s = np.where(point1, 0.0, s)
    return s, t


def capsule_capsule(a1, b1, r1, a2, b2, r2) -> Contact:
    """Capsule [a1, b1] radius r1 (A) against capsule [a2, b2] radius r2 (B): |x1 − x2| − r1 − r2.

    Where the segments meet, the normal is along d1 × d2 (or perpendicular to d1 if parallel).
    """
    s, t = segment_segment(a1, b1, a2, b2)
    x1 = a1 + s[..., None] * (b1 - a1)
    x2 = a2 + t[..., None] * (b2 - a2)
    fallback, _ = _unit(np.cross(b1 - a1, b2 - a2), _perpendicular(b1 - a1 + (b2 - a2)))
    n, gap = _unit(x1 - x2, fallback)
    r1, r2 = np.asarray(r1, dtype=float), np.asarray(r2, dtype=float)
    return Contact(distance=gap - r1 - r2, normal=n, point_a=x1 - r1[..., None] * n, point_b=x2 + r2[..., None] * n)


def capsule_halfspace(a, b, r, normal, offset) -> Contact:
    """Capsule [a, b] radius r (A) against the half-space {x : normal · x <= offset} (B, unit normal)."""
    ha, hb = _dot(a, normal) - offset, _dot(b, normal) - offset
    low = np.where((ha <= hb)[..., None], a, b)
    h = np.minimum(ha, hb)
    r = np.asarray(r, dtype=float)
    n = np.broadcast_to(normal, low.shape)
    point_a = low - r[..., None] * n
    return Contact(distance=h - r, normal=n.copy(), point_a=point_a, point_b=low - h[..., None] * n)


def capsule_box(a, b, r, center, rotation, half) -> Contact:
    """Capsule [a, b] radius r (A) against the box (B) with ``center`` (S, 3), ``rotation`` (S, 3, 3)
    (its axes as columns) and half side lengths ``half`` (S, 3).
    """
    R = np.asarray(rotation, dtype=float)
    h = np.asarray(half, dtype=float)
    p = np.einsum("...ji,...j->...i", R, a - center)          # segment in the box frame
    d = np.einsum("...ji,...j->...i", R, b - a)
    shape = p.shape[:-1]
    # knots: where a coordinate crosses ±h (inside (0, 1)), plus the ends
    with np.errstate(divide="ignore", invalid="ignore"):
        cross = np.concatenate([(h - p) / d, (-h - p) / d], axis=-1)  # (S, 6)
    cross = np.where(np.isfinite(cross) & (cross > 0.0) & (cross < 1.0), cross, 0.0)
    knots = np.sort(np.concatenate([np.zeros(shape + (1,)), cross, np.ones(shape + (1,))], axis=-1), axis=-1)
    # the stationary point of each piece: the active faces are those the piece's midpoint is outside of
    mid = (knots[..., 1:] + knots[..., :-1]) / 2                        # (S, 7)
    x = p[..., None, :] + mid[..., None] * d[..., None, :]              # (S, 7, 3)
    side = np.where(x > h[..., None, :], 1.0, np.where(x < -h[..., None, :], -1.0, 0.0))
    dd = d[..., None, :]
    num = -np.sum(side * side * dd * (p[..., None, :] - side * h[..., None, :]), axis=-1)
    den = np.sum(side * side * dd * dd, axis=-1)
    stationary = np.where(den > 0, num / np.where(den > 0, den, 1.0), mid)
    stationary = np.clip(stationary, knots[..., :-1], knots[..., 1:])
    cand = np.concatenate([knots, stationary], axis=-1)                 # (S, 15)
    xc = p[..., None, :] + cand[..., None] * d[..., None, :]
    out = xc - np.clip(xc, -h[..., None, :], h[..., None, :])
    f = np.sum(out * out, axis=-1)
    k = np.argmin(f, axis=-1)
    t = np.take_along_axis(cand, k[..., None], axis=-1)[..., 0]
    x = p + t[..., None] * d                                            # closest point of the segment (box frame)
    y = np.clip(x, -h, h)                                               # closest point of the box
    gap = np.linalg.norm(x - y, axis=-1)
    separated = gap > 0.0

    # overlap: penetration depth by separating axes (box frame), for both ends of the segment
    e = np.broadcast_to(np.eye(3), shape + (3, 3))
    axes_c = np.cross(e, d[..., None, :])                               # (S, 3, 3): e_i × d
    axes_c, length = _unit(axes_c, np.zeros(3))
    axes = np.concatenate([e, axes_c], axis=-2)                         # (S, 6, 3)
    valid = np.concatenate([np.ones(shape + (3,), bool), length > 1e-12 * np.maximum(np.linalg.norm(d, axis=-1), EPS)[..., None]], axis=-1)
    rho = np.sum(np.abs(axes) * h[..., None, :], axis=-1)               # box support along each axis
    u0, u1 = _dot(axes, p[..., None, :]), _dot(axes, (p + d)[..., None, :])
    up = rho - np.minimum(u0, u1)    # push the segment along +axis
    down = rho + np.maximum(u0, u1)  # along −axis
    depth = np.where(valid, np.minimum(up, down), np.inf)
    j = np.argmin(depth, axis=-1)
    pen = np.take_along_axis(depth, j[..., None], axis=-1)[..., 0]
    axis = np.take_along_axis(axes, j[..., None, None], axis=-2)[..., 0, :]
    sign = np.where(np.take_along_axis(up, j[..., None], axis=-1)[..., 0] <= np.take_along_axis(down, j[..., None], axis=-1)[..., 0], 1.0, -1.0)
    n_in = sign[..., None] * axis
    deep = np.where((_dot(n_in, p) <= _dot(n_in, p + d))[..., None], p, p + d)  # the end deepest against n_in

    n_out, _ = _unit(x - y, np.zeros(3))
    n_box = np.where(separated[..., None], n_out, n_in)
    xa = np.where(separated[..., None], x, deep)
    dist_core = np.where(separated, gap, -pen)
    r = np.asarray(r, dtype=float)
    normal = np.einsum("...ij,...j->...i", R, n_box)
    point_a = np.einsum("...ij,...j->...i", R, xa) + center - r[..., None] * normal
    distance = dist_core - r
    return Contact(distance=distance, normal=normal, point_a=point_a, point_b=point_a - distance[..., None] * normal)
