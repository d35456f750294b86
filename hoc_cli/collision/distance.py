"""Signed distances between a capsule and a capsule, a box or a half-space, batched with numpy.

Every function takes arrays with any common leading shape ``S`` (samples × pairs, ...), points as
(S, 3) in one frame, in metres, and returns a :class:`Contact` of arrays over ``S``. The first
shape, A, is always the capsule (a sphere when a = b). Signed distance: the distance between the
two solids when they are apart, minus the penetration depth (the length of the shortest
translation that separates them) when they overlap.

Formulas (docs/collision.md): capsule–capsule is the segment–segment distance minus both radii;
capsule–half-space the lower end's height minus the radius; capsule–box minimises the convex, C¹,
piecewise-quadratic squared distance from the segment's points to the box over the segment's
parameter (its derivative is piecewise linear between the knots where the segment crosses a face
plane: the minimiser is an end or the zero of that derivative between two knots) and, when the
segment meets the box, takes the penetration depth by
separating axes: the box's face normals and the cross products of its axes with the segment, the
facet normals of box ⊕ (−segment); on an edge axis the witness on the segment is where it passes
the supporting box edge (an end for a face axis).
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


def cross(a: np.ndarray, b: np.ndarray, axis: int = -1) -> np.ndarray:
    """The cross product a × b along ``axis`` (length 3; −1 or a leading axis) of broadcastable arrays: ``np.cross``'s
    products and differences, without its axis moves (a hot path's small arrays).
    """
    lead = (Ellipsis,) if axis == -1 else (slice(None),) * axis
    tail = () if axis == -1 else (Ellipsis,)
    a0, a1, a2 = (a[lead + (i,) + tail] for i in range(3))
    b0, b1, b2 = (b[lead + (i,) + tail] for i in range(3))
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=axis)


def _unit(v: np.ndarray, fallback: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(v / |v| where |v| > 0 else the unit fallback, |v|)."""
    n = np.linalg.norm(v, axis=-1)
    ok = n > 0
    u = np.where(ok[..., None], v / np.where(ok, n, 1.0)[..., None], fallback)
    return u, n


def _perpendicular(d: np.ndarray) -> np.ndarray:
    """A unit vector perpendicular to each d (S, 3) (any unit vector where d = 0)."""
    e = np.where((np.abs(d[..., 0]) < 0.9 * np.linalg.norm(d, axis=-1))[..., None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    u, _ = _unit(cross(d, e), np.array([0.0, 0.0, 1.0]))
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
    v = x1 - x2
    gap = np.linalg.norm(v, axis=-1)
    ok = gap > 0
    n = v / np.where(ok, gap, 1.0)[..., None]
    if not ok.all():  # the segments meet: the fallback normal where they do (``_unit``'s, the same numbers)
        e1, e2 = np.broadcast_arrays(b1 - a1, b2 - a2)
        meet = ~ok
        fallback, _ = _unit(cross(e1[meet], e2[meet]), _perpendicular(e1[meet] + e2[meet]))
        n[meet] = fallback
    r1, r2 = np.asarray(r1, dtype=float), np.asarray(r2, dtype=float)
    return Contact(distance=gap - r1 - r2, normal=n, point_a=x1 - r1[..., None] * n, point_b=x2 + r2[..., None] * n)


def capsule_capsule_distance(a1, b1, r1, a2, b2, r2) -> np.ndarray:
    """``capsule_capsule``'s distance alone (S,), the same numbers, without its normal and witness points."""
    s, t = segment_segment(a1, b1, a2, b2)
    x1 = a1 + s[..., None] * (b1 - a1)
    x2 = a2 + t[..., None] * (b2 - a2)
    gap = np.linalg.norm(x1 - x2, axis=-1)
    return gap - np.asarray(r1, dtype=float) - np.asarray(r2, dtype=float)


def capsule_halfspace(a, b, r, normal, offset) -> Contact:
    """Capsule [a, b] radius r (A) against the half-space {x : normal · x <= offset} (B, unit normal)."""
    ha, hb = _dot(a, normal) - offset, _dot(b, normal) - offset
    low = np.where((ha <= hb)[..., None], a, b)
    h = np.minimum(ha, hb)
    r = np.asarray(r, dtype=float)
    n = np.broadcast_to(normal, low.shape)
    point_a = low - r[..., None] * n
    return Contact(distance=h - r, normal=n.copy(), point_a=point_a, point_b=low - h[..., None] * n)


def capsule_box(a, b, r, center, rotation, half, spheres: tuple | None = None) -> Contact:
    """Capsule [a, b] radius r (A) against the box (B) with ``center`` (S, 3), ``rotation`` (S, 3, 3)
    (its axes as columns) and half side lengths ``half`` (S, 3).

    ``spheres``: ``sphere_box``'s result on these rows when every row is a sphere (a = b, rows (M,) of
    C-contiguous arrays) and the caller has it already; it is not computed again.
    """
    a, b, center = (np.asarray(x, dtype=float) for x in (a, b, center))
    R, h = np.asarray(rotation, dtype=float), np.asarray(half, dtype=float)
    r = np.asarray(r, dtype=float)
    lead = np.broadcast_shapes(a.shape[:-1], b.shape[:-1], center.shape[:-1], R.shape[:-2], h.shape[:-1], r.shape)
    if lead != (np.prod(lead, dtype=int),):  # work on rows (M,), reshape back at the end
        flat = capsule_box(*(np.broadcast_to(x, lead + x.shape[len(x.shape) - k:]).reshape((-1,) + x.shape[len(x.shape) - k:])
                             for x, k in ((a, 1), (b, 1), (r, 0), (center, 1), (R, 2), (h, 1))))
        return Contact(*(getattr(flat, f).reshape(lead + getattr(flat, f).shape[1:])
                         for f in ("distance", "normal", "point_a", "point_b")))
    M = lead[0]
    a, b, center, h = (np.broadcast_to(x, (M, 3)) for x in (a, b, center, h))
    R, r = np.broadcast_to(R, (M, 3, 3)), np.broadcast_to(r, (M,))
    ball = np.flatnonzero(np.all(a == b, axis=-1))  # spheres (the rows standing for capsules against obstacles)
    if ball.size == 0:
        return _capsule_box_rows(a, b, r, center, R, h)
    if ball.size == M:  # every row a sphere (the penalty's rows): no gathering unless a centre is in a box
        got, done = spheres if spheres is not None else sphere_box(*(np.ascontiguousarray(x) for x in (a, r, center, R, h)))
        if done.all():
            return Contact(*got)
    else:
        got, done = sphere_box(a[ball], r[ball], center[ball], R[ball], h[ball])
    out = Contact(distance=np.empty(M), normal=np.empty((M, 3)), point_a=np.empty((M, 3)), point_b=np.empty((M, 3)))
    fields = ("distance", "normal", "point_a", "point_b")
    for f, v in zip(fields, got):
        getattr(out, f)[ball[done]] = v[done]
    keep = np.ones(M, dtype=bool)
    keep[ball[done]] = False
    rest = np.flatnonzero(keep)  # capsules, and spheres whose centre is in the box
    if rest.size:
        c = _capsule_box_rows(a[rest], b[rest], r[rest], center[rest], R[rest], h[rest])
        for f in fields:
            getattr(out, f)[rest] = getattr(c, f)
    return out


def within_rounding(gap: np.ndarray, p: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Whether gap <= 1e-12·(max_i h_i + |p|) (gap (S,), a point p (S, 3) in the box frame, half sides h broadcast to (S, 3)):
    a sphere's centre within rounding of its box (``sphere_box``). |p| is taken only where gap is at most
    1e-11·(1 + max h) (elsewhere the test is false: |p| <= gap + |clip(p)| <= gap + √3·max h), the same booleans.
    """
    out = np.zeros(gap.shape, dtype=bool)
    near = gap <= 1e-11 * (1.0 + float(np.max(h, initial=0.0)))
    if near.any():
        hn, pn = np.broadcast_to(h, p.shape)[near], p[near]
        out[near] = gap[near] <= 1e-12 * (np.max(hn, axis=-1) + np.linalg.norm(pn, axis=-1))
    return out


def sphere_box(c, r, center, R, h):
    """``capsule_box`` for spheres (a = b = c, (S, 3), rows of C-contiguous arrays) outside the box: ((distance,
    normal, point_a, point_b), done (S,) bool); rows not done (the centre within rounding of the box) take the capsule
    path. The same operations as the capsule path with a zero direction (its segment parameter is 0), so the same
    numbers.
    """
    p = np.matmul((c - center)[..., None, :], R)[..., 0, :]
    h, _ = np.broadcast_arrays(h, p)
    y = np.clip(p, -h, h)
    n_box, gap = _unit(p - y, np.zeros(3))
    done = ~within_rounding(gap, p, h)  # the capsule path's test, its |d| = 0
    normal = np.matmul(R, n_box[..., None])[..., 0]
    point_a = np.matmul(R, p[..., None])[..., 0] + center - r[..., None] * normal
    distance = gap - r
    return (distance, normal, point_a, point_a - distance[..., None] * normal), done


def _capsule_box_rows(a, b, r, center, R, h) -> Contact:
    """``capsule_box`` on rows (M,) of arrays broadcast to (M, 3), (M,), (M, 3, 3)."""
    p = np.matmul((a - center)[..., None, :], R)[..., 0, :]  # segment start in the box frame (Rᵀ x)
    d = np.matmul((b - a)[..., None, :], R)[..., 0, :]       # segment direction in the box frame
    h, _ = np.broadcast_arrays(h, p)
    shape = p.shape[:-1]
    # f(t) = dist²(p + t d, box) is convex and C¹ with f'(t) = 2 d·(x − clip(x)), piecewise linear between the
    # knots where a coordinate crosses ±h: the minimiser is an end, or where f' changes sign between two knots
    with np.errstate(divide="ignore", invalid="ignore"):
        cross = np.concatenate([(h - p) / d, (-h - p) / d], axis=-1)          # (S, 6)
    knots = np.concatenate([np.zeros(shape + (1,)), np.where((cross > 0.0) & (cross < 1.0), cross, 0.0),
                            np.ones(shape + (1,))], axis=-1)                    # (S, 8)
    xk = p[..., None, :] + knots[..., None] * d[..., None, :]
    slope = np.sum(d[..., None, :] * (xk - np.clip(xk, -h[..., None, :], h[..., None, :])), axis=-1)  # f'/2
    neg = slope < 0.0
    t_lo = np.max(np.where(neg, knots, -1.0), axis=-1)
    t_hi = np.min(np.where(neg, 2.0, knots), axis=-1)
    k_lo = np.argmax(np.where(neg, knots, -1.0), axis=-1)[..., None]
    k_hi = np.argmin(np.where(neg, 2.0, knots), axis=-1)[..., None]
    s_lo = np.take_along_axis(slope, k_lo, axis=-1)[..., 0]
    s_hi = np.take_along_axis(slope, k_hi, axis=-1)[..., 0]
    jump = s_hi - s_lo
    inner = t_lo - s_lo * (t_hi - t_lo) / np.where(jump > 0, jump, 1.0)
    t = np.where(t_lo < 0.0, 0.0, np.where(t_hi > 1.0, 1.0, np.where(jump > 0, inner, t_hi)))
    t = np.clip(t, 0.0, 1.0)
    x = p + t[..., None] * d                                            # closest point of the segment (box frame)
    y = np.clip(x, -h, h)                                               # closest point of the box
    n_box, gap = _unit(x - y, np.zeros(3))
    xa = x.copy()
    dist_core = gap.copy()
    # rows whose segment meets the box (up to rounding in t): the penetration depth by separating axes
    # (box frame), for these rows only; a positive depth on every axis proves the overlap
    scale = np.max(h, axis=-1) + np.linalg.norm(p, axis=-1) + np.linalg.norm(d, axis=-1)
    inside = gap <= 1e-12 * scale
    if np.any(inside):
        pi, di, hi = p[inside], d[inside], h[inside]
        m = pi.shape[0]
        e = np.broadcast_to(np.eye(3), (m, 3, 3))
        axes_c, length = _unit(np.cross(e, di[:, None, :]), np.zeros(3))  # e_i × d
        axes = np.concatenate([e, axes_c], axis=1)                          # (m, 6, 3)
        valid = np.concatenate([np.ones((m, 3), bool), length > 1e-12 * np.maximum(np.linalg.norm(di, axis=-1), EPS)[:, None]],
                               axis=1)
        rho = np.sum(np.abs(axes) * hi[:, None, :], axis=-1)               # box support along each axis
        u0, u1 = _dot(axes, pi[:, None, :]), _dot(axes, (pi + di)[:, None, :])
        up = rho - np.minimum(u0, u1)    # push the segment along +axis
        down = rho + np.maximum(u0, u1)  # along −axis
        depth = np.where(valid, np.minimum(up, down), np.inf)
        j = np.argmin(depth, axis=-1)[:, None]
        pen = np.take_along_axis(depth, j, axis=-1)[:, 0]
        axis = np.take_along_axis(axes, j[..., None], axis=1)[:, 0, :]
        sign = np.where(np.take_along_axis(up, j, axis=-1)[:, 0] <= np.take_along_axis(down, j, axis=-1)[:, 0], 1.0, -1.0)
        n_in = sign[:, None] * axis
        deep = np.where((_dot(n_in, pi) <= _dot(n_in, pi + di))[:, None], pi, pi + di)  # the end deepest against n_in
        # an edge axis e_i × d: every point of the segment is equally deep; the witness is where the segment passes
        # the box edge that supports n_in (the closest points of the two lines), so that ∂d/∂q = n·∂x_A/∂q holds
        edge = j[:, 0] >= 3
        if edge.any():
            k = j[edge, 0] - 3
            r_ = np.arange(k.size)
            y0 = hi[edge] * np.sign(n_in[edge])                     # the supporting edge passes through y0 along e_k
            y0[r_, k] = 0.0
            de, w0 = di[edge], pi[edge] - y0
            aa, bb = _dot(de, de), de[r_, k]
            det = aa - bb * bb
            t_edge = (bb * w0[r_, k] - _dot(de, w0)) / np.where(det > 0, det, 1.0)
            deep[edge] = pi[edge] + np.clip(t_edge, 0.0, 1.0)[:, None] * de
        overlap = pen > 0.0
        rows = np.flatnonzero(inside)[overlap]
        n_box[rows], xa[rows], dist_core[rows] = n_in[overlap], deep[overlap], -pen[overlap]
    normal = np.matmul(R, n_box[..., None])[..., 0]
    point_a = np.matmul(R, xa[..., None])[..., 0] + center - r[..., None] * normal
    distance = dist_core - r
    return Contact(distance=distance, normal=normal, point_a=point_a, point_b=point_a - distance[..., None] * normal)
