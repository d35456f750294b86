"""Small rigid-body helpers on single (unbatched) transforms, used when a model is built.

Conventions (Featherstone's spatial algebra, written with 3-vectors):

* a spatial *motion* vector is ``(ω, v)``: angular velocity (rad/s) and the linear velocity (m/s) of
  the body-fixed point at the frame origin, both in frame coordinates;
* a spatial *force* vector is ``(n, f)``: moment about the frame origin (N·m) and force (N);
* a 4×4 homogeneous transform ``A2B`` maps coordinates in frame B to coordinates in frame A
  (so it is also the pose of B in A).

Batched kernels live in :mod:`hoc_cli.dynamics`; nothing here is on a hot path.
"""
from __future__ import annotations

import numpy as np


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix ``[v]×`` (3, 3) of a 3-vector, so that ``skew(a) @ b == a × b``."""
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def align_z(axis: np.ndarray) -> np.ndarray:
    """Rotation A (3, 3) with ``A @ e_z == axis`` (axis: unit 3-vector).

    Every joint is re-expressed as a motion about (or along) its local z axis; A is the constant
    rotation from the URDF joint frame to that aligned frame. Identity for +z, a half turn about x
    for -z, otherwise the smallest rotation taking e_z to the axis (Rodrigues).
    """
    a = np.asarray(axis, dtype=float)
    if np.allclose(a, (0.0, 0.0, 1.0), atol=1e-15):
        return np.eye(3)
    if np.allclose(a, (0.0, 0.0, -1.0), atol=1e-15):
        return np.diag([1.0, -1.0, -1.0])
    k = np.cross((0.0, 0.0, 1.0), a)
    sin = np.linalg.norm(k)
    cos = a[2]
    k = k / sin
    kx = skew(k)
    return np.eye(3) + sin * kx + (1.0 - cos) * (kx @ kx)


def rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation matrix (3, 3) of ``angle`` rad about the unit ``axis`` (Rodrigues)."""
    kx = skew(np.asarray(axis, dtype=float))
    return np.eye(3) + np.sin(angle) * kx + (1.0 - np.cos(angle)) * (kx @ kx)


def joint_motion(joint_type: str, axis: np.ndarray, value: float) -> np.ndarray:
    """Homogeneous transform (4, 4) of a revolute/continuous (rad) or prismatic (m) joint at ``value``."""
    T = np.eye(4)
    if joint_type == "prismatic":
        T[:3, 3] = np.asarray(axis, dtype=float) * value
    elif joint_type in ("revolute", "continuous"):
        T[:3, :3] = rotation_about(axis, value)
    return T


def motion_transform(A2B: np.ndarray) -> np.ndarray:
    """Plücker transform (6, 6) taking motion vectors from frame A coordinates to frame B coordinates.

    ``A2B`` (4, 4) is the pose of B in A (rotation E, origin r of B in A). For a motion ``(ω, v)`` in
    A: ``ω_B = Eᵀ ω``, ``v_B = Eᵀ (v + ω × r) = Eᵀ v - Eᵀ [r]× ω``. Its transpose maps force vectors
    from B back to A.
    """
    E = A2B[:3, :3]
    r = A2B[:3, 3]
    X = np.zeros((6, 6))
    X[:3, :3] = E.T
    X[3:, 3:] = E.T
    X[3:, :3] = -E.T @ skew(r)
    return X


def spatial_inertia(mass: float, com: np.ndarray, inertia_com: np.ndarray) -> np.ndarray:
    """Spatial inertia (6, 6) about a frame origin from mass (kg), centre of mass (3,) m and the
    rotational inertia about the centre of mass (3, 3) kg·m², all in that frame's coordinates.

    Maps a motion ``(ω, v)`` to the momentum ``(L, p)``: ``p = m (v + ω × c)``,
    ``L = (I_c + m [c]×[c]×ᵀ) ω + m c × v``.
    """
    cx = skew(com)
    I = np.zeros((6, 6))
    I[:3, :3] = inertia_com + mass * cx @ cx.T
    I[:3, 3:] = mass * cx
    I[3:, :3] = mass * cx.T
    I[3:, 3:] = mass * np.eye(3)
    return I
