"""Batched forward kinematics of a :class:`~hoc_cli.model.RobotModel`: link poses, a link's frame
Jacobian, its spatial velocity and the derivatives of that velocity.

Symbols (SI units; sample axis first; n joints in ``model.joint_names`` order):

====== ================================================================================
K      number of samples evaluated together
q, dq  (K, n) joint positions (rad or m) and velocities (rad/s or m/s)
link   name of a URDF link (any of ``model.link_names``, merged and fixed-base links included)
pose   (K, 4, 4) homogeneous pose of a link frame in the root-link frame, translation in m
J      (K, 6, n) frame Jacobian of a link: ``[v; ω] = J(q) q̇`` with rows 0:3 the linear velocity
       v (m/s) of the link frame's *origin* and rows 3:6 the angular velocity ω (rad/s) of the
       link, both expressed in the root-link frame (Pinocchio's ``LOCAL_WORLD_ALIGNED``)
V      (K, 6) = (v, ω), the link's spatial velocity in that convention
====== ================================================================================

Column j of J is, for a revolute (or continuous) joint j with unit axis z_j through the point o_j
(root frame), (z_j × (p − o_j), z_j), p the link origin; for a prismatic joint (z_j, 0); zero for
joints that are not ancestors of the link. Python loops run only over the bodies of one
root-to-link chain; every operation is batched over the K samples.
"""
from __future__ import annotations

import numpy as np

from ..model.tree import RobotModel
from ._layout import _cos_sin, _inputs, _shape_out


def body_poses(model: RobotModel, qT: np.ndarray, bodies) -> dict[int, np.ndarray]:
    """Pose (K, 4, 4) in the root frame of each body in ``bodies`` (parents listed before their
    children, every ancestor of a listed body listed too), from positions qT (n, K).
    """
    K = qT.shape[1]
    bodies = list(bodies)
    idx = np.asarray(bodies, dtype=int)
    c, s = _cos_sin(qT[idx])
    joint = np.zeros((idx.size, K, 4, 4))  # each body's joint transform, all at once
    joint[:, :, 0, 0] = c
    joint[:, :, 0, 1] = -s
    joint[:, :, 1, 0] = s
    joint[:, :, 1, 1] = c
    joint[:, :, 2, 2] = joint[:, :, 3, 3] = 1.0
    prismatic = np.array([model.joint_types[i] == "prismatic" for i in bodies], bool)
    if prismatic.any():
        joint[prismatic, :, :3, :3] = np.eye(3)
        joint[prismatic, :, 2, 3] = qT[idx[prismatic]]
    body: dict[int, np.ndarray] = {}
    for k, i in enumerate(bodies):
        p = model.parent[i]
        base = model.tree_transform[i] if p < 0 else body[p] @ model.tree_transform[i]
        body[i] = base @ joint[k]
    return body


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The cross product a × b along axis 1 of (K, 3, ...) arrays (np.cross's per-call overhead is tens of µs at these sizes)."""
    a1, a2, b1, b2 = a[:, _NEXT], a[:, _PREV], b[:, _NEXT], b[:, _PREV]
    return a1 * b2 - a2 * b1


_NEXT, _PREV = np.array([1, 2, 0]), np.array([2, 0, 1])  # (a × b)_i = a_{i+1} b_{i+2} − a_{i+2} b_{i+1}


def link_body(model: RobotModel, link: str) -> tuple[int, np.ndarray]:
    """(body carrying ``link`` or -1 for the fixed base, (4, 4) link pose in that body frame)."""
    try:
        k = model.link_names.index(link)
    except ValueError:
        raise KeyError(f"no link {link!r}; links are {list(model.link_names)}") from None
    return int(model.link_body[k]), model.link_offset[k]


def chain_to_root(model: RobotModel, b: int) -> list[int]:
    """Bodies from the root to body b (b included), parents first."""
    chain = []
    while b >= 0:
        chain.append(b)
        b = int(model.parent[b])
    return chain[::-1]


def _chain_jacobian(model: RobotModel, qT: np.ndarray, link: str):
    """(chain, Jc (K, 6, m), pose (K, 4, 4)): the root-to-link chain of bodies, the Jacobian's columns for
    them (the other columns are zero; m = 0 for a link on the fixed base) and the link's pose.
    """
    b, offset = link_body(model, link)
    K = qT.shape[1]
    if b < 0:
        return [], np.zeros((K, 6, 0)), np.broadcast_to(offset, (K, 4, 4)).copy()
    chain = chain_to_root(model, b)
    poses = body_poses(model, qT, chain)
    pose = poses[b] @ offset
    p = pose[:, :3, 3]                                              # (K, 3) link origin
    frames = np.stack([poses[j][:, :3, 2:] for j in chain], axis=3)  # (K, 3, 2, m)
    Z, O = frames[:, :, 0], frames[:, :, 1]                         # (K, 3, m) joint axes, points on them
    rev = np.array([model.joint_types[j] != "prismatic" for j in chain])
    Jc = np.empty((K, 6, len(chain)))
    Jc[:, 0:3] = _cross(Z, p[:, :, None] - O)
    Jc[:, 3:6] = Z
    if not rev.all():
        Jc[:, 0:3, ~rev] = Z[:, :, ~rev]
        Jc[:, 3:6, ~rev] = 0.0
    return chain, Jc, pose


def link_poses(model: RobotModel, q) -> dict[str, np.ndarray]:
    """Pose of every URDF link (merged and fixed-base links included) in the root-link frame.

    Parameters
    ----------
    model : RobotModel
    q : (K, n) or (n,) joint positions, rad or m.

    Returns
    -------
    dict
        link name → (K, 4, 4) pose (or (4, 4) for 1-D ``q``); translations in m.
    """
    (qT,), K, one_d = _inputs(model, q=q)
    body = body_poses(model, qT, model.order)
    out = {}
    for name, b, offset in zip(model.link_names, model.link_body, model.link_offset):
        T = np.broadcast_to(offset, (K, 4, 4)).copy() if b < 0 else body[b] @ offset
        out[name] = _shape_out(T, one_d)
    return out


def frame_jacobian(model: RobotModel, q, link: str) -> np.ndarray:
    """Frame Jacobian J (K, 6, n) of a link's origin, in the root-link frame.

    Rows 0:3 map q̇ to the linear velocity (m/s) of the link frame's origin, rows 3:6 to the
    link's angular velocity (rad/s), both expressed in the root-link frame (Pinocchio's
    ``LOCAL_WORLD_ALIGNED`` frame Jacobian). Columns follow ``model.joint_names``; a column is
    zero when its joint does not move the link. Rows 0:3 are also ∂p/∂q of the link origin p.

    Parameters
    ----------
    model : RobotModel
    q : (K, n) or (n,) joint positions, rad or m.
    link : str
        URDF link name.

    Returns
    -------
    numpy.ndarray
        (K, 6, n), or (6, n) for 1-D ``q``; m/rad or 1 (linear rows of revolute / prismatic
        columns), rad/rad or rad/m (angular rows).

    Raises
    ------
    KeyError
        If ``link`` is not a link of the model (the message lists the links).
    ValueError
        If ``q`` has the wrong shape.
    """
    (qT,), K, one_d = _inputs(model, q=q)
    chain, Jc, _ = _chain_jacobian(model, qT, link)
    J = np.zeros((K, 6, model.n))
    J[:, :, chain] = Jc
    return _shape_out(J, one_d)


def link_velocity(model: RobotModel, q, dq, link: str) -> np.ndarray:
    """Spatial velocity V = J(q) q̇ (K, 6) of a link: rows as :func:`frame_jacobian`.

    ``V[:, 0:3]`` is the linear velocity (m/s) of the link origin, ``V[:, 3:6]`` the angular
    velocity (rad/s), both in the root-link frame; (6,) for 1-D ``q`` and ``dq``.
    """
    return link_velocity_derivatives(model, q, dq, link)[0]


def link_velocity_derivatives(model: RobotModel, q, dq, link: str):
    """A link's spatial velocity V = J(q) q̇ and its partial derivatives (see ``link_motion`` for the link's pose too).

    Parameters
    ----------
    model : RobotModel
    q, dq : (K, n) or (n,) joint positions and velocities.
    link : str
        URDF link name.

    Returns
    -------
    V : (K, 6)
        (linear velocity of the link origin m/s, angular velocity rad/s), root-link frame.
    dV_dq : (K, 6, n)
        ∂V/∂q with ``dV_dq[k, r, j] = ∂V_r/∂q_j``.
    dV_ddq : (K, 6, n)
        ∂V/∂q̇ = J(q), the frame Jacobian.

    Notes
    -----
    Along the chain (index order root → link), with ω_k = J_k[3:6] (z_k or 0) and J_k the
    columns: moving q_k rotates every column j at or below k about axis k (∂J_j/∂q_k = ω_k × J_j),
    and moves the link origin by J_k[0:3], which changes the linear part of every column above k
    (∂J_j[0:3]/∂q_k = ω_j × J_k[0:3]). Summed with the rates,
    ∂V/∂q_k = (ω_k × S_k[0:3] + W_k × J_k[0:3], ω_k × S_k[3:6]), with S_k = Σ_{j ≥ k} J_j q̇_j and
    W_k = Σ_{j < k} ω_j q̇_j (the angular velocity of body k's parent). O(m) per sample.
    """
    return link_motion(model, q, dq, link)[1:]


def link_motion(model: RobotModel, q, dq, link: str):
    """(pose (K, 4, 4), V (K, 6), ∂V/∂q (K, 6, n), J (K, 6, n)) of a link from one pass along its chain: the
    pose as :func:`link_poses`' entry for the link (only the chain's bodies are computed), the rest as
    :func:`link_velocity_derivatives`; 1-D ``q`` and ``dq`` give unbatched arrays.
    """
    (qT, dqT), K, one_d = _inputs(model, q=q, dq=dq)
    chain, Jc, pose = _chain_jacobian(model, qT, link)
    n = model.n
    V = np.zeros((K, 6))
    dV_dq = np.zeros((K, 6, n))
    J = np.zeros((K, 6, n))
    if chain:
        cols = Jc * dqT[chain].T[:, None, :]                # (K, 6, m): J_j q̇_j
        V[:] = cols.sum(axis=2)
        S = np.cumsum(cols[:, :, ::-1], axis=2)[:, :, ::-1]  # Σ_{j ≥ k}
        W = np.zeros((K, 3, len(chain)))                     # Σ_{j < k} ω_j q̇_j
        np.cumsum(cols[:, 3:6, :-1], axis=2, out=W[:, :, 1:])
        w = Jc[:, 3:6]
        D = np.empty_like(Jc)
        D[:, 0:3] = _cross(w, S[:, 0:3]) + _cross(W, Jc[:, 0:3])
        D[:, 3:6] = _cross(w, S[:, 3:6])
        dV_dq[:, :, chain] = D
        J[:, :, chain] = Jc
    return tuple(_shape_out(x, one_d) for x in (pose, V, dV_dq, J))
