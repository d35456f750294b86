"""Signed distances of a scene's pairs at joint configurations, and their gradients with respect to q.

Symbols: K configurations (samples), n joints, P robot primitives, Q pairs (see
:class:`~hoc_cli.collision.scene.CollisionScene`); lengths in m. Everything is batched over samples
and pairs: Python loops run over the robot's links only.
"""
from __future__ import annotations

import numpy as np

from hoc_cli.collision.distance import Contact, capsule_box, capsule_capsule, capsule_capsule_distance, capsule_halfspace, cross, sphere_box, within_rounding
from hoc_cli.collision.scene import KIND_BOX, KIND_CAPSULE, KIND_HALFSPACE, KIND_SELF, CollisionScene
from hoc_cli.collision.shapes import Box, Capsule, HalfSpace
from hoc_cli.dynamics.kinematics import body_poses
from hoc_cli.model.tree import RobotModel

_CACHE: dict = {}  # id(object) → (object, arrays derived from it): per-scene and per-model constants


def _cached(key: str, owner, build):
    """``build()`` once per ``owner`` object (kept alive with its entry, so the id is not reused)."""
    entry = _CACHE.get((key, id(owner)))
    if entry is None or entry[0] is not owner:
        if len(_CACHE) > 64:
            _CACHE.clear()
        entry = _CACHE[(key, id(owner))] = (owner, build())
    return entry[1]


def _primitive_frames(model: RobotModel, scene: CollisionScene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(body (P,) carrying each primitive, −1 on the fixed base; the segment ends (P, 3) and (P, 3) in that body's
    frame (the link offset applied)).
    """
    robot = scene.robot
    index = robot.link_index
    body = np.asarray(model.link_body, dtype=int)[index]
    off = np.asarray(model.link_offset, dtype=float)[index]            # (P, 4, 4) link pose in its body
    a = np.einsum("pij,pj->pi", off[:, :3, :3], robot.a) + off[:, :3, 3]
    b = np.einsum("pij,pj->pi", off[:, :3, :3], robot.b) + off[:, :3, 3]
    return body, a, b


def _poses(model: RobotModel, q: np.ndarray) -> np.ndarray:
    """Body poses T (K, n+1, 4, 4) at q (K, n), root frame; the last, the identity, stands for the fixed base."""
    K, n = len(q), model.n
    if not n:
        return np.broadcast_to(np.eye(4), (K, 1, 4, 4))
    poses = body_poses(model, q.T, model.order)
    return np.stack([poses[j] for j in range(n)] + [np.broadcast_to(np.eye(4), (K, 4, 4))], axis=1)


def _kinematics(model: RobotModel, scene: CollisionScene, q: np.ndarray, axes: bool = False):
    """(a, b) segment ends (K, P, 3) of every primitive at q (K, n), root frame; with ``axes`` also the joint axes
    Z and points on them O, each (K, 3, n): one pass of the body poses.
    """
    n = model.n
    body, la, lb = _cached("frames", scene, lambda: _primitive_frames(model, scene))
    T = _poses(model, q)
    Tp = T[:, np.where(body < 0, n, body)]                               # (K, P, 4, 4); body −1: the root frame
    R, t = Tp[..., :3, :3], Tp[..., :3, 3]
    a = _placed_points(R, la, t)
    ball = _cached("balls", scene, lambda: np.all(la == lb, axis=-1))    # spheres: b = a
    if ball.all():
        b = a.copy()
    elif not ball.any():
        b = _placed_points(R, lb, t)
    else:
        b = a.copy()
        seg = np.flatnonzero(~ball)
        b[:, seg] = _placed_points(R[:, seg], lb[seg], t[:, seg])
    if not axes:
        return a, b
    return a, b, _axes(T, n)


def _placed_points(R: np.ndarray, x: np.ndarray, t: np.ndarray) -> np.ndarray:
    """R x + t (K, P, 3) for rotations R (K, P, 3, 3), points x (P, 3) and translations t (K, P, 3): the products of
    ``np.einsum("kpij,pj->kpi", R, x)`` summed in the order it sums them, (R_0 x_0 + R_2 x_2) + R_1 x_1 (the same
    numbers), without its cost on an operand broadcast over K (four times as long on the Panda's points).
    """
    return (R[..., 0] * x[:, 0, None] + R[..., 2] * x[:, 2, None]) + R[..., 1] * x[:, 1, None] + t


def _axes(T: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The joint axes Z and points on them O, each (K, 3, n), from body poses T (K, n+1, 4, 4)."""
    return np.swapaxes(T[:, :n, :3, 2], 1, 2), np.swapaxes(T[:, :n, :3, 3], 1, 2)


def _row_ends(model: RobotModel, scene: CollisionScene, T: np.ndarray, rows: np.ndarray,
              prims: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Segment ends (a, b), each (M, 3), of primitive ``prims[m]`` at sample ``rows[m]`` from body poses T
    (K, n+1, 4, 4): only the (sample, primitive) combinations the rows use.
    """
    body, la, lb = _cached("frames", scene, lambda: _primitive_frames(model, scene))
    Tm = T[rows, np.where(body < 0, model.n, body)[prims]]               # (M, 4, 4)
    R, t = Tm[:, :3, :3], Tm[:, :3, 3]
    return np.einsum("mij,mj->mi", R, la[prims]) + t, np.einsum("mij,mj->mi", R, lb[prims]) + t


def row_contacts(model: RobotModel, scene: CollisionScene, q, rows, pairs, axes: bool = False):
    """The contact (M,) of pair ``pairs[m]`` at configuration ``q[rows[m]]`` (q (K, n)), as ``pair_contacts`` but
    with the primitives placed only where the rows need them; with ``axes`` also (Z, O) of ``_axes``.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    rows, pairs = np.asarray(rows, dtype=int), np.asarray(pairs, dtype=int)
    T = _poses(model, q)
    c = _placed_contacts(model, scene, T, rows, pairs)
    return (c, _axes(T, model.n)) if axes else c


def _placed_ends(model: RobotModel, scene: CollisionScene, T: np.ndarray, rows: np.ndarray,
                 pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(a1, b1, a2, b2), each (M, 3): the ends of each row's robot primitive and (self pairs; zeros otherwise) of
    its other primitive, from body poses T (K, n+1, 4, 4) at the rows' samples ``rows`` (M,).
    """
    a1, b1 = _row_ends(model, scene, T, rows, scene.prim[pairs])
    self_rows = scene.kind[pairs] == KIND_SELF
    a2, b2 = np.zeros_like(a1), np.zeros_like(b1)
    if self_rows.any():
        a2[self_rows], b2[self_rows] = _row_ends(model, scene, T, rows[self_rows], scene.other[pairs[self_rows]])
    return a1, b1, a2, b2


def _placed_contacts(model: RobotModel, scene: CollisionScene, T: np.ndarray, rows: np.ndarray,
                     pairs: np.ndarray) -> Contact:
    """The contacts (M,) of ``pairs`` at the samples ``rows`` of body poses T (K, n+1, 4, 4)."""
    return _contacts(scene, *_placed_ends(model, scene, T, rows, pairs), pairs)


def world_capsules(model: RobotModel, scene: CollisionScene, q) -> tuple[np.ndarray, np.ndarray]:
    """Segment ends (a, b), each (K, P, 3), of every robot primitive at configurations q (K, n), root frame."""
    return _kinematics(model, scene, np.atleast_2d(np.asarray(q, dtype=float)))


def _obstacle_arrays(scene: CollisionScene) -> dict:
    O = len(scene.obstacles)
    out = {"ca": np.zeros((O, 3)), "cb": np.zeros((O, 3)), "cr": np.zeros(O), "center": np.zeros((O, 3)),
           "rot": np.tile(np.eye(3), (O, 1, 1)), "half": np.zeros((O, 3)), "normal": np.zeros((O, 3)),
           "offset": np.zeros(O)}
    for o, obstacle in enumerate(scene.obstacles):
        p = obstacle.primitive
        if isinstance(p, Capsule):
            out["ca"][o], out["cb"][o], out["cr"][o] = p.a, p.b, p.radius
        elif isinstance(p, Box):
            out["center"][o], out["rot"][o], out["half"][o] = p.center, p.rotation, p.half
        elif isinstance(p, HalfSpace):
            out["normal"][o], out["offset"][o] = p.normal, p.offset
    return out


def pair_contacts(scene: CollisionScene, a: np.ndarray, b: np.ndarray, rows: np.ndarray, pairs: np.ndarray) -> Contact:
    """The contact (M,) of pair ``pairs[m]`` at sample ``rows[m]``, from world capsules a, b (K, P, 3)."""
    rows, pairs = np.asarray(rows, dtype=int), np.asarray(pairs, dtype=int)
    M = rows.size
    out = Contact(distance=np.empty(M), normal=np.empty((M, 3)), point_a=np.empty((M, 3)), point_b=np.empty((M, 3)))
    if M == 0:
        return out
    prim, other = scene.prim[pairs], scene.other[pairs]
    self_rows = scene.kind[pairs] == KIND_SELF
    a2, b2 = np.zeros((M, 3)), np.zeros((M, 3))
    a2[self_rows], b2[self_rows] = a[rows[self_rows], other[self_rows]], b[rows[self_rows], other[self_rows]]
    return _contacts(scene, a[rows, prim], b[rows, prim], a2, b2, pairs)


def _contacts(scene: CollisionScene, a1: np.ndarray, b1: np.ndarray, a2: np.ndarray, b2: np.ndarray,
              pairs: np.ndarray) -> Contact:
    """The contact (M,) of pair ``pairs[m]``, its robot primitive's ends a1, b1 (M, 3), the other primitive's
    a2, b2 (M, 3) (read on self pairs only), root frame.
    """
    M = pairs.size
    out = Contact(distance=np.empty(M), normal=np.empty((M, 3)), point_a=np.empty((M, 3)), point_b=np.empty((M, 3)))
    if M == 0:
        return out
    robot = scene.robot
    prim, other, kind = scene.prim[pairs], scene.other[pairs], scene.kind[pairs]
    r1 = robot.radius[prim]
    obs = _cached("obstacles", scene, lambda: _obstacle_arrays(scene))
    for k in (KIND_SELF, KIND_CAPSULE, KIND_BOX, KIND_HALFSPACE):
        m = kind == k
        if not m.any():
            continue
        o = other[m]
        if k == KIND_SELF:
            c = capsule_capsule(a1[m], b1[m], r1[m], a2[m], b2[m], robot.radius[o])
        elif k == KIND_CAPSULE:
            c = capsule_capsule(a1[m], b1[m], r1[m], obs["ca"][o], obs["cb"][o], obs["cr"][o])
        elif k == KIND_BOX:
            c = _box_contacts(scene, a1[m], b1[m], r1[m], o, pairs[m], obs)
        else:
            c = capsule_halfspace(a1[m], b1[m], r1[m], obs["normal"][o], obs["offset"][o])
        out.distance[m], out.normal[m], out.point_a[m], out.point_b[m] = c.distance, c.normal, c.point_a, c.point_b
    return out


def _box_contacts(scene: CollisionScene, a: np.ndarray, b: np.ndarray, r: np.ndarray, o: np.ndarray, pairs: np.ndarray,
                  obs: dict) -> Contact:
    """``capsule_box`` of rows (M,) against boxes ``o`` (M,): rows whose pair is a sphere's (``_spheres``; the
    penalty's rows) by ``distance.sphere_box`` directly, the same numbers without capsule_box's broadcasting.
    """
    center, rot, half = obs["center"][o], obs["rot"][o], obs["half"][o]
    if not _cached("spheres", scene, lambda: _spheres(scene))[pairs].all():
        return capsule_box(a, b, r, center, rot, half)
    got, done = sphere_box(a, r, center, rot, half)
    if done.all():
        return Contact(*got)
    return capsule_box(a, b, r, center, rot, half, spheres=(got, done))  # a centre in a box: its depth by the capsule path


def _spheres(scene: CollisionScene) -> np.ndarray:
    """(Q,) bool: the pairs of a sphere (a robot primitive with a = b) and a box, whose distance ``pair_distances``
    takes on its own path.
    """
    robot = scene.robot
    ball = np.all(robot.a == robot.b, axis=-1)
    return (scene.kind == KIND_BOX) & ball[scene.prim]


def _sphere_box_gap(c: np.ndarray, r: np.ndarray, center: np.ndarray, rot: np.ndarray, half: np.ndarray,
                    p: np.ndarray | None = None):
    """(distance, outside) of spheres (centres c (..., 3), radii r) and boxes, the arrays broadcast over the leading
    shape: the clamp of the centre in the box frame, as ``distance.capsule_box`` takes a sphere outside the box (the
    same operations, so the same numbers); ``outside`` False where the centre is in the box (its depth is not this).
    ``p``: the centres in the box frames (c − center) rot when the caller has them (``_box_frames``).
    """
    if p is None:
        p = np.matmul((c - center)[..., None, :], rot)[..., 0, :]
    gap = np.linalg.norm(p - np.clip(p, -half, half), axis=-1)
    return gap - r, ~within_rounding(gap, p, half)


def _sphere_box_columns(scene: CollisionScene) -> tuple[np.ndarray, list[tuple[int, int, int]]]:
    """The pairs of a sphere and a box (``_spheres``) ordered by box, and each box's run in that order: (columns (F,),
    [(start, stop, box)]).
    """
    cols = np.flatnonzero(_spheres(scene))
    cols = cols[np.argsort(scene.other[cols], kind="stable")]
    o = scene.other[cols]
    cuts = np.concatenate([[0], np.flatnonzero(np.diff(o)) + 1, [cols.size]])
    return cols, [(int(a), int(b), int(o[a])) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]


def _box_frames(c: np.ndarray, runs: list[tuple[int, int, int]], obs: dict) -> np.ndarray:
    """(c − center) rot (K, F, 3) for centres c (K, F, 3) whose columns ``runs`` (``_sphere_box_columns``) face one
    box each: one product per box instead of one 1 × 3 by 3 × 3 product per entry (the same numbers: each entry's
    three products summed alike).
    """
    K = c.shape[0]
    p = np.empty(c.shape)
    for a, b, box in runs:
        rel = c[:, a:b] - obs["center"][box]
        p[:, a:b] = (rel.reshape(-1, 3) @ obs["rot"][box]).reshape(K, b - a, 3)
    return p


def _fill_sphere_box(scene: CollisionScene, centres: np.ndarray, pairs: np.ndarray, fast: np.ndarray,
                     out: np.ndarray) -> None:
    """The rows where ``fast`` (M,) holds (a sphere of ``pairs`` (M,) against a box), their sphere centres ``centres``
    (F, 3) in the root frame: each distance written into ``out`` (M,) where the centre lies outside the box
    (``_sphere_box_gap``), and ``fast`` cleared where it lies inside (its depth by the capsule path).
    """
    obs = _cached("obstacles", scene, lambda: _obstacle_arrays(scene))
    k = pairs[fast]
    o = scene.other[k]
    d, outside = _sphere_box_gap(centres, scene.robot.radius[scene.prim[k]], obs["center"][o], obs["rot"][o],
                                 obs["half"][o])
    got = np.flatnonzero(fast)
    out[got[outside]] = d[outside]
    fast[got[~outside]] = False


def pair_distances(scene: CollisionScene, a: np.ndarray, b: np.ndarray, rows: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """The signed distance (M,) of pair ``pairs[m]`` at sample ``rows[m]``, from world capsules a, b (K, P, 3):
    ``pair_contacts``' distance, the same numbers, without the normals and witnesses where a sphere lies outside a
    box (``_sphere_box_gap``).
    """
    rows, pairs = np.asarray(rows, dtype=int), np.asarray(pairs, dtype=int)
    out = np.empty(rows.size)
    fast = _cached("spheres", scene, lambda: _spheres(scene))[pairs]
    if fast.any():
        _fill_sphere_box(scene, a[rows[fast], scene.prim[pairs[fast]]], pairs, fast, out)
    rest = np.flatnonzero(~fast)
    if rest.size:
        r, k = rows[rest], pairs[rest]
        prim, other = scene.prim[k], scene.other[k]
        self_rows = scene.kind[k] == KIND_SELF
        a2, b2 = np.zeros((r.size, 3)), np.zeros((r.size, 3))
        a2[self_rows], b2[self_rows] = a[r[self_rows], other[self_rows]], b[r[self_rows], other[self_rows]]
        out[rest] = _distances_only(scene, a[r, prim], b[r, prim], a2, b2, k)
    return out


def _distances_only(scene: CollisionScene, a1: np.ndarray, b1: np.ndarray, a2: np.ndarray, b2: np.ndarray,
                    pairs: np.ndarray) -> np.ndarray:
    """``_contacts``' distances (M,), the same numbers: two capsules' by ``capsule_capsule_distance`` (no normals or
    witnesses), the other kinds' by ``_contacts``.
    """
    out = np.empty(pairs.size)
    kind, other = scene.kind[pairs], scene.other[pairs]
    caps = (kind == KIND_SELF) | (kind == KIND_CAPSULE)
    if caps.any():
        robot = scene.robot
        obs = _cached("obstacles", scene, lambda: _obstacle_arrays(scene))
        o, sf = other[caps], kind[caps] == KIND_SELF
        a, b, r2 = a2[caps], b2[caps], np.empty(o.size)
        r2[sf] = robot.radius[o[sf]]
        ob = ~sf  # capsule obstacles
        a[ob], b[ob], r2[ob] = obs["ca"][o[ob]], obs["cb"][o[ob]], obs["cr"][o[ob]]
        out[caps] = capsule_capsule_distance(a1[caps], b1[caps], robot.radius[scene.prim[pairs[caps]]], a, b, r2)
    rest = np.flatnonzero(~caps)
    if rest.size:
        out[rest] = _contacts(scene, a1[rest], b1[rest], a2[rest], b2[rest], pairs[rest]).distance
    return out


def row_distances(model: RobotModel, scene: CollisionScene, q, rows, pairs) -> np.ndarray:
    """The signed distance (M,) of pair ``pairs[m]`` at configuration ``q[rows[m]]`` (q (K, n)): ``pair_distances``
    with the primitives placed only where the rows need them (``row_contacts``), the same numbers; cheaper than
    placing every primitive at every configuration when each configuration holds a few rows.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    rows, pairs = np.asarray(rows, dtype=int), np.asarray(pairs, dtype=int)
    a1, b1, a2, b2 = _placed_ends(model, scene, _poses(model, q), rows, pairs)
    out = np.empty(rows.size)
    fast = _cached("spheres", scene, lambda: _spheres(scene))[pairs]
    if fast.any():
        _fill_sphere_box(scene, a1[fast], pairs, fast, out)
    rest = np.flatnonzero(~fast)
    if rest.size:
        out[rest] = _distances_only(scene, a1[rest], b1[rest], a2[rest], b2[rest], pairs[rest])
    return out


def contacts(model: RobotModel, scene: CollisionScene, q) -> Contact:
    """Every pair at every configuration q (K, n): a Contact with arrays (K, Q) and (K, Q, 3)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    K, Q = len(q), scene.size
    a, b = world_capsules(model, scene, q)
    c = pair_contacts(scene, a, b, np.repeat(np.arange(K), Q), np.tile(np.arange(Q), K))
    return Contact(distance=c.distance.reshape(K, Q), normal=c.normal.reshape(K, Q, 3),
                   point_a=c.point_a.reshape(K, Q, 3), point_b=c.point_b.reshape(K, Q, 3))


def distances(model: RobotModel, scene: CollisionScene, q) -> np.ndarray:
    """Signed distances (K, Q), m, of every pair at configurations q (K, n) (``pair_distances``)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    K, Q = len(q), scene.size
    a, b = world_capsules(model, scene, q)
    D = np.empty((K, Q))
    fast = _cached("spheres", scene, lambda: _spheres(scene))
    inside = np.zeros((K, Q), dtype=bool)
    if fast.any():  # spheres against boxes on the grid of samples × pairs (``_sphere_box_gap``)
        obs = _cached("obstacles", scene, lambda: _obstacle_arrays(scene))
        cols, runs = _cached("sphere box columns", scene, lambda: _sphere_box_columns(scene))
        o, prim = scene.other[cols], scene.prim[cols]
        c = a[:, prim]
        d, outside = _sphere_box_gap(c, scene.robot.radius[prim], obs["center"][o], obs["rot"][o], obs["half"][o],
                                     p=_box_frames(c, runs, obs))
        D[:, cols] = d
        inside[:, cols] = ~outside
    rows, pairs = np.nonzero(inside | ~fast[None, :])  # the rest, and centres in a box, by ``pair_contacts``
    if rows.size:
        D[rows, pairs] = pair_contacts(scene, a, b, rows, pairs).distance
    return D


def _ancestors(model: RobotModel) -> np.ndarray:
    """(n + 1, n) bool: row b, whether joint j moves body b (j on the chain root → b); row n (body −1, the
    fixed base) all False.
    """
    n = model.n
    anc = np.zeros((n + 1, n), dtype=bool)
    for b in range(n):
        j = b
        while j >= 0:
            anc[b, j] = True
            j = int(model.parent[j])
    return anc


def pair_gradient(model: RobotModel, scene: CollisionScene, q, rows, pairs) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance d (M,) of pair ``pairs[m]`` at configuration ``q[rows[m]]`` (q: (K, n)), and ∂d/∂q (M, n).

    With n̂ the contact normal and x_A, x_B the witness points on the two shapes, moving q by δq
    moves x_A by (J_v − [x_A − o]× J_ω) δq for the frame Jacobian J = (J_v, J_ω) of A's link (origin
    o), so ∂d/∂q = n̂·J_v + ((x_A − o) × n̂)·J_ω, minus the same for B when B is a robot link. Column j
    of that Jacobian at x_A, for a joint j on A's chain with axis z_j through o_j, is z_j × (x_A − o_j)
    (revolute) or z_j (prismatic): ∂d/∂q_j = n̂·(z_j × (x_A − o_j)) or n̂·z_j, every link at once from
    one pass of the body poses. Exact wherever the witness points are unique (the distance is
    differentiable there).
    """
    d, grad, _ = pair_gradient_geometry(model, scene, q, rows, pairs)
    return d, grad


def pair_gradient_geometry(model: RobotModel, scene: CollisionScene, q, rows,
                           pairs) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, Contact] | None]:
    """``pair_gradient``'s (d (M,), ∂d/∂q (M, n)) and what it placed: (the body poses T (K, n+1, 4, 4) at q, the
    rows' contacts (M,)), which ``pair_hessian`` takes for the same rows (None without joints).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    rows, pairs = np.asarray(rows, dtype=int), np.asarray(pairs, dtype=int)
    n = model.n
    if n == 0:
        a, b = world_capsules(model, scene, q)
        c = pair_contacts(scene, a, b, rows, pairs)
        return c.distance, np.zeros((rows.size, n)), None
    T = _poses(model, q)
    c = _placed_contacts(model, scene, T, rows, pairs)
    Z, O = _axes(T, n)  # (K, 3, n): joint axes, points on them
    robot = scene.robot
    grad = np.zeros((rows.size, n))
    if rows.size == 0:
        return c.distance, grad, (T, c)
    revolute = ~np.asarray(model.is_prismatic, dtype=bool)
    anc = _cached("ancestors", model, lambda: _ancestors(model))
    body_a = robot.body[scene.prim[pairs]]
    body_b = np.where(scene.kind[pairs] == KIND_SELF, robot.body[scene.other[pairs]], -1)
    Zr, Or = Z[rows], O[rows]
    for body, point, sign in ((body_a, c.point_a, 1.0), (body_b, c.point_b, -1.0)):
        moved = anc[np.where(body < 0, n, body)]                      # (M, n)
        some = np.flatnonzero(moved.any(axis=1))  # the rows a joint moves (B: self pairs); the others add zeros
        if some.size == 0:
            continue
        if some.size == rows.size:
            normal, Zs, Os, part = c.normal, Zr, Or, slice(None)
        else:
            normal, Zs, Os, point, moved, part = c.normal[some], Zr[some], Or[some], point[some], moved[some], some
        turn = np.einsum("mi,mij->mj", normal, cross(Zs, point[:, :, None] - Os, axis=1))
        if not revolute.all():  # prismatic joints: the axis itself
            turn = np.where(revolute, turn, np.einsum("mi,mij->mj", normal, Zs))
        grad[part] += sign * np.where(moved, turn, 0.0)
    return c.distance, grad, (T, c)


def distance_gradient(model: RobotModel, scene: CollisionScene, q) -> tuple[np.ndarray, np.ndarray]:
    """Signed distances d (K, Q) of every pair and their gradients ∂d/∂q (K, Q, n) at configurations q (K, n)
    (:func:`pair_gradient` on every sample × pair).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    K, Q = len(q), scene.size
    d, g = pair_gradient(model, scene, q, np.repeat(np.arange(K), Q), np.tile(np.arange(Q), K))
    return d.reshape(K, Q), g.reshape(K, Q, model.n)


def _point_curvature(scene: CollisionScene, x: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """∇²φ (M, 3, 3), 1/m: the Hessian of the distance φ from a point x (M, 3) to obstacle ``scene.other[pairs]``
    (box or capsule obstacle; zeros for a half-space, a self pair, or a point inside the obstacle).

    Outside a box, in its frame, φ = |p − clip(p)| and ∇²φ = (D − n nᵀ)/φ, D the diagonal of the coordinates
    clipped (zero in a face's region: φ is linear there; an edge's or a corner's region curves). Off a
    segment, ∇²φ = (I − n nᵀ − u uᵀ)/φ beside it (u its direction) and (I − n nᵀ)/φ beyond an end.
    """
    M = pairs.size
    out = np.zeros((M, 3, 3))
    kind, other = scene.kind[pairs], scene.other[pairs]
    obs = _cached("obstacles", scene, lambda: _obstacle_arrays(scene))
    box = np.flatnonzero(kind == KIND_BOX)
    if box.size:
        o = other[box]
        R = obs["rot"][o]
        p = np.einsum("mji,mj->mi", R, x[box] - obs["center"][o])          # Rᵀ(x − centre)
        h = obs["half"][o]
        y = np.clip(p, -h, h)
        v = p - y
        gap = np.linalg.norm(v, axis=1)
        ok = gap > 0
        nb = v / np.where(ok, gap, 1.0)[:, None]
        Hb = (np.eye(3)[None] * (p != y)[:, None, :] - nb[:, :, None] * nb[:, None, :]) / np.where(ok, gap, 1.0)[:, None, None]
        Hb[~ok] = 0.0
        out[box] = np.einsum("mij,mjk,mlk->mil", R, Hb, R)
    cap = np.flatnonzero(kind == KIND_CAPSULE)
    if cap.size:
        o = other[cap]
        a, b = obs["ca"][o], obs["cb"][o]
        d = b - a
        L2 = np.einsum("mi,mi->m", d, d)
        s = np.clip(np.einsum("mi,mi->m", x[cap] - a, d) / np.where(L2 > 0, L2, 1.0), 0.0, 1.0)
        v = x[cap] - (a + s[:, None] * d)
        gap = np.linalg.norm(v, axis=1)
        ok = gap > 0
        nv = v / np.where(ok, gap, 1.0)[:, None]
        u = d / np.sqrt(np.where(L2 > 0, L2, 1.0))[:, None]
        beside = ((s > 0) & (s < 1) & (L2 > 0)).astype(float)
        H = (np.eye(3)[None] - nv[:, :, None] * nv[:, None, :]
             - beside[:, None, None] * u[:, :, None] * u[:, None, :]) / np.where(ok, gap, 1.0)[:, None, None]
        H[~ok] = 0.0
        out[cap] = H
    return out


def _kinematic_curvature(normal: np.ndarray, Z: np.ndarray, J: np.ndarray, moved: np.ndarray,
                         before: np.ndarray) -> np.ndarray:
    """n·∂²x/∂q² (M, n, n) of a point x of a body, from the unit vectors n (M, 3), the joint axes Z (M, 3, n), x's
    Jacobian columns J_j = z_j × (x − o_j) (M, 3, n), the revolute joints moving the body ``moved`` (M, n) and
    ``before`` (n, n) bool (joint i on the chain from the root to joint j, j included): ∂²x/∂q_i∂q_j = z_i × J_j
    for such i, so the entry is (n × z_i)·J_j, mirrored.
    """
    n = Z.shape[-1]
    K = np.where(before, np.einsum("mki,mkj->mij", cross(normal[:, :, None], Z, axis=1), J), 0.0)
    K = K + np.swapaxes(np.where(before & ~np.eye(n, dtype=bool), K, 0.0), 1, 2)
    return np.where(moved[:, :, None] & moved[:, None, :], K, 0.0)


def pair_hessian(model: RobotModel, scene: CollisionScene, q, rows, pairs,
                 placed: tuple[np.ndarray, Contact] | None = None) -> np.ndarray:
    """∇²d (M, n, n), m/rad², of pair ``pairs[m]`` at configuration ``q[rows[m]]`` (rows with d > 0): the curvature
    the Newton matrix of the penalty takes (−μ ∇²d). Revolute joints only (a prismatic joint adds nothing).

    Two segments (capsules; a sphere's is a point): d = min over s, t of f = |P(s) − Q(t)| − r_1 − r_2, P and Q
    points of the bodies (Q fixed for an obstacle). With v = P − Q, δ = |v|, n = v/δ, Π = I − n nᵀ,
    J_v = J_P − J_Q (columns z_j × (x − o_j)), e_1 = b_1 − a_1, e_2 = b_2 − a_2:
    f_qq = J_vᵀ Π J_v/δ + n·∂²P/∂q² − n·∂²Q/∂q² (``_kinematic_curvature``), f_qs = J_vᵀ Π e_1/δ + n·(z_j × e_1),
    f_qt = −J_vᵀ Π e_2/δ − n·(z_j × e_2), f_ss = e_1ᵀΠe_1/δ, f_tt = e_2ᵀΠe_2/δ, f_st = −e_1ᵀΠe_2/δ, and for the
    parameters y strictly inside (0, 1) the minimum's Hessian is f_qq − f_qy f_yy⁻¹ f_yq (implicit function);
    a parameter at an end stays there. A sphere against a box: d = φ(c) − r, φ the centre's distance to the
    box, ∇²d = J_cᵀ ∇²φ J_c + n·∂²c/∂q² (``_point_curvature``). A half-space: the kinematic part alone (φ is
    linear). Exact wherever d is twice differentiable (tested against central differences of ``pair_gradient``),
    except for a capsule (a ≠ b) against a box, whose witness's slide along the segment is left out (the
    penalty's rows against boxes are spheres: ``constraint.sphere_rows_scene``).

    ``placed``: (the body poses T (K, n+1, 4, 4) at q, the rows' contacts (M,)) when already computed
    (``pair_gradient_geometry`` on these rows: the same numbers); q is then not read.
    """
    rows, pairs = np.asarray(rows, dtype=int), np.asarray(pairs, dtype=int)
    n = model.n
    M = rows.size
    H = np.zeros((M, n, n))
    if n == 0 or M == 0:
        return H
    robot = scene.robot
    T = _poses(model, np.atleast_2d(np.asarray(q, dtype=float))) if placed is None else placed[0]
    prim, other, kind = scene.prim[pairs], scene.other[pairs], scene.kind[pairs]
    self_rows = kind == KIND_SELF
    a1, b1, a2, b2 = _placed_ends(model, scene, T, rows, pairs)
    c = _contacts(scene, a1, b1, a2, b2, pairs) if placed is None else placed[1]
    obs = _cached("obstacles", scene, lambda: _obstacle_arrays(scene))
    capsule_obstacle = kind == KIND_CAPSULE
    a2[capsule_obstacle], b2[capsule_obstacle] = obs["ca"][other[capsule_obstacle]], obs["cb"][other[capsule_obstacle]]
    r1 = robot.radius[prim]
    r2 = np.zeros(M)
    r2[self_rows] = robot.radius[other[self_rows]]
    r2[capsule_obstacle] = obs["cr"][other[capsule_obstacle]]
    normal = c.normal
    P = c.point_a + r1[:, None] * normal          # the witness on A's segment
    Qp = c.point_b - r2[:, None] * normal         # ... on B's segment (or the obstacle's witness)
    Z, O = _axes(T, n)
    Zr, Or = Z[rows], O[rows]
    revolute = ~np.asarray(model.is_prismatic, dtype=bool)
    anc = _cached("ancestors", model, lambda: _ancestors(model))
    moved_a = anc[np.where(robot.body[prim] < 0, n, robot.body[prim])] & revolute
    body_b = np.full(M, n)
    body_b[self_rows] = np.where(robot.body[other[self_rows]] < 0, n, robot.body[other[self_rows]])
    moved_b = anc[body_b] & revolute
    JP = np.where(moved_a[:, None, :], cross(Zr, P[:, :, None] - Or, axis=1), 0.0)      # (M, 3, n)
    JQ = np.zeros_like(JP)  # B's: zero where no joint moves it (obstacles)
    before = anc[:n].T                                                       # before[i, j]: i on j's chain
    H = _kinematic_curvature(normal, Zr, JP, moved_a, before)
    sr = np.flatnonzero(self_rows)
    if sr.size:  # x − 0 = x: the other rows' B part adds nothing
        JQ[sr] = np.where(moved_b[sr, None, :], cross(Zr[sr], Qp[sr, :, None] - Or[sr], axis=1), 0.0)
        H[sr] -= _kinematic_curvature(normal[sr], Zr[sr], JQ[sr], moved_b[sr], before)
    box = kind == KIND_BOX
    if box.any():  # the segment of A is a point here (a sphere row): its distance to the box curves at edges
        s = np.flatnonzero(box & np.all(a1 == b1, axis=1))
        Hp = _point_curvature(scene, P[s], pairs[s])
        H[s] += np.einsum("mki,mkl,mlj->mij", JP[s], Hp, JP[s])
    seg = np.flatnonzero(self_rows | capsule_obstacle)
    if seg.size:
        Jv = JP[seg] - JQ[seg]
        nn = normal[seg]
        delta = np.einsum("mi,mi->m", P[seg] - Qp[seg], nn)
        delta = np.where(delta > 0, delta, np.inf)
        Pi = (np.eye(3)[None] - nn[:, :, None] * nn[:, None, :]) / delta[:, None, None]
        e1, e2 = b1[seg] - a1[seg], b2[seg] - a2[seg]
        H[seg] += np.einsum("mki,mkl,mlj->mij", Jv, Pi, Jv)
        E = np.stack([e1, -e2], axis=2)                                          # (m, 3, 2): ∂v/∂(s, t)
        Fqy = np.einsum("mki,mkl,mly->miy", Jv, Pi, E)
        Fqy[:, :, 0] += np.where(moved_a[seg], np.einsum("mk,mkj->mj", nn, cross(Zr[seg], e1[:, :, None], axis=1)), 0.0)
        Fqy[:, :, 1] -= np.where(moved_b[seg], np.einsum("mk,mkj->mj", nn, cross(Zr[seg], e2[:, :, None], axis=1)), 0.0)
        Fyy = np.einsum("mkx,mkl,mly->mxy", E, Pi, E)

        def parameter(x, a, e):
            L2 = np.einsum("mi,mi->m", e, e)
            return np.einsum("mi,mi->m", x - a, e) / np.where(L2 > 0, L2, 1.0), L2 > 0

        s_, has_s = parameter(P[seg], a1[seg], e1)
        t_, has_t = parameter(Qp[seg], a2[seg], e2)
        tol = 1e-9
        free = np.stack([has_s & (s_ > tol) & (s_ < 1 - tol), has_t & (t_ > tol) & (t_ < 1 - tol)], axis=1)  # (m, 2)
        det = Fyy[:, 0, 0] * Fyy[:, 1, 1] - Fyy[:, 0, 1] ** 2
        scale = np.abs(Fyy[:, 0, 0] * Fyy[:, 1, 1]) + 1e-300
        free[:, 1] &= ~(free[:, 0] & (np.abs(det) <= 1e-9 * scale))  # parallel segments: one parameter is enough
        Fqy = np.where(free[:, None, :], Fqy, 0.0)
        Fyy = np.where(free[:, :, None] & free[:, None, :], Fyy, 0.0) + np.where(free, 0.0, 1.0)[:, :, None] * np.eye(2)
        ok = np.abs(Fyy[:, 0, 0] * Fyy[:, 1, 1] - Fyy[:, 0, 1] ** 2) > 0
        Fyy[~ok] = np.eye(2)
        Fqy[~ok] = 0.0
        H[seg] -= np.einsum("miy,myx,mjx->mij", Fqy, np.linalg.inv(Fyy), Fqy)
    return H
