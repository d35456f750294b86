"""Signed distances of a scene's pairs at joint configurations, and their gradients with respect to q.

Symbols: K configurations (samples), n joints, P robot primitives, Q pairs (see
:class:`~hoc_cli.collision.scene.CollisionScene`); lengths in m. Everything is batched over samples
and pairs: Python loops run over the robot's links only.
"""
from __future__ import annotations

import numpy as np

from hoc_cli.collision.distance import Contact, capsule_box, capsule_capsule, capsule_halfspace
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
    a = np.einsum("kpij,pj->kpi", R, la) + t
    b = np.einsum("kpij,pj->kpi", R, lb) + t
    if not axes:
        return a, b
    return a, b, _axes(T, n)


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
    a1, b1 = _row_ends(model, scene, T, rows, scene.prim[pairs])
    self_rows = scene.kind[pairs] == KIND_SELF
    a2, b2 = np.zeros_like(a1), np.zeros_like(b1)
    if self_rows.any():
        a2[self_rows], b2[self_rows] = _row_ends(model, scene, T, rows[self_rows], scene.other[pairs[self_rows]])
    c = _contacts(scene, a1, b1, a2, b2, pairs)
    return (c, _axes(T, model.n)) if axes else c


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
            c = capsule_box(a1[m], b1[m], r1[m], obs["center"][o], obs["rot"][o], obs["half"][o])
        else:
            c = capsule_halfspace(a1[m], b1[m], r1[m], obs["normal"][o], obs["offset"][o])
        out.distance[m], out.normal[m], out.point_a[m], out.point_b[m] = c.distance, c.normal, c.point_a, c.point_b
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
    """Signed distances (K, Q), m, of every pair at configurations q (K, n)."""
    return contacts(model, scene, q).distance


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
    q = np.atleast_2d(np.asarray(q, dtype=float))
    rows, pairs = np.asarray(rows, dtype=int), np.asarray(pairs, dtype=int)
    n = model.n
    if n == 0:
        a, b = world_capsules(model, scene, q)
        c = pair_contacts(scene, a, b, rows, pairs)
        return c.distance, np.zeros((rows.size, n))
    c, (Z, O) = row_contacts(model, scene, q, rows, pairs, axes=True)  # Z, O (K, 3, n): joint axes, points on them
    robot = scene.robot
    grad = np.zeros((rows.size, n))
    if rows.size == 0:
        return c.distance, grad
    revolute = ~np.asarray(model.is_prismatic, dtype=bool)
    anc = _cached("ancestors", model, lambda: _ancestors(model))
    body_a = robot.body[scene.prim[pairs]]
    body_b = np.where(scene.kind[pairs] == KIND_SELF, robot.body[scene.other[pairs]], -1)
    Zr, Or = Z[rows], O[rows]
    for body, point, sign in ((body_a, c.point_a, 1.0), (body_b, c.point_b, -1.0)):
        moved = anc[np.where(body < 0, n, body)]                      # (M, n)
        if not moved.any():
            continue
        turn = np.einsum("mi,mij->mj", c.normal, np.cross(Zr, point[:, :, None] - Or, axis=1))
        slide = np.einsum("mi,mij->mj", c.normal, Zr)
        grad += sign * np.where(moved, np.where(revolute, turn, slide), 0.0)
    return c.distance, grad


def distance_gradient(model: RobotModel, scene: CollisionScene, q) -> tuple[np.ndarray, np.ndarray]:
    """Signed distances d (K, Q) of every pair and their gradients ∂d/∂q (K, Q, n) at configurations q (K, n)
    (:func:`pair_gradient` on every sample × pair).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    K, Q = len(q), scene.size
    d, g = pair_gradient(model, scene, q, np.repeat(np.arange(K), Q), np.tile(np.arange(Q), K))
    return d.reshape(K, Q), g.reshape(K, Q, model.n)
