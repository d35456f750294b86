"""Goal residuals at one instant: c(q, q̇, T) = 0 for a joint state, a link pose, a moving target.

Symbols
-------
n joints; q, q̇ (n,) joint positions and velocities at the instant [rad, rad/s]; T the duration [s]
(a moving target is where it is at the final time T). Each residual returns
(c (r,), ∂c/∂q (r, n), ∂c/∂q̇ (r, n), ∂c/∂T (r,)), the last the explicit dependence on T only.

Frames (``hoc_cli.dynamics.kinematics``): p(q) (3,) the link origin and R(q) (3, 3) its rotation in
the root-link frame; J(q) (6, n) the frame Jacobian, rows 0:3 ∂p/∂q, rows 3:6 the angular part
(δθ = J_ω δq, a rotation δR = [δθ]× R). The orientation residual is

    e = vee(A − Aᵀ) / √(1 + tr A),  A = R R̄ᵀ,   so e = 2 sin(θ/2) · axis of the rotation from R̄ to R,

zero only at R = R̄ (``orientation_residual``; ½ vee(A − Aᵀ) = sin θ · axis would vanish at θ = π
too); ∂e/∂q = (∂e/∂δθ) J_ω, which is J_ω at the goal. A target moving with constant acceleration a is at
p̄(T) = p0 + v0 T + ½ a T², with velocity v̄(T) = v0 + a T.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hoc_cli.dynamics import link_motion, link_poses


def quaternion_matrix(wxyz) -> np.ndarray:
    """Rotation matrix (3, 3) of a unit quaternion (w, x, y, z) (normalised here)."""
    w, x, y, z = np.asarray(wxyz, float) / np.linalg.norm(wxyz)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def rotation_angle(R: np.ndarray, R_goal: np.ndarray) -> float:
    """The angle [rad] of the rotation R R̄ᵀ (0 when the orientations agree), accurate near 0."""
    A = R @ R_goal.T
    s = 0.5 * np.linalg.norm([A[2, 1] - A[1, 2], A[0, 2] - A[2, 0], A[1, 0] - A[0, 1]])
    c = 0.5 * (np.trace(A) - 1.0)
    return float(np.arctan2(s, c))


GENERATORS = np.array([[[0, 0, 0], [0, 0, -1], [0, 1, 0]],
                        [[0, 0, 1], [0, 0, 0], [-1, 0, 0]],
                        [[0, -1, 0], [1, 0, 0], [0, 0, 0]]], float)  # [e_k]×


def orientation_residual(R: np.ndarray, R_goal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(e (3,), ∂e/∂δθ (3, 3)): e = vee(A − Aᵀ)/√(1 + tr A) = 2 sin(θ/2)·axis, A = R R̄ᵀ (root frame).

    Zero only at R = R̄ (θ = 0; the rotation by π is a pole, not a spurious zero); ≈ θ·axis near the
    goal. For a rotation δR = [δθ]× R: δA = [δθ]× A, δ vee(A − Aᵀ) = (tr A·I − A) δθ and
    δ tr A = tᵀδθ with t_k = tr([e_k]× A), so ∂e/∂δθ = (tr A·I − A)/g − f tᵀ/(2g³), f = vee(A − Aᵀ), g = √(1 + tr A).
    """
    A = R @ R_goal.T
    f = np.array([A[2, 1] - A[1, 2], A[0, 2] - A[2, 0], A[1, 0] - A[0, 1]])
    tr = np.trace(A)
    g = np.sqrt(max(1.0 + tr, 1e-12))
    t = np.einsum("kij,ji->k", GENERATORS, A)
    return f / g, (tr * np.eye(3) - A) / g - np.outer(f, t) / (2 * g**3)


@dataclass(frozen=True, eq=False)
class JointResidual:
    """c = (q − q̄[, q̇ − q̇̄]): a joint state; ``dq`` None leaves q̇ free."""

    q: np.ndarray
    dq: np.ndarray | None = None

    @property
    def size(self) -> int:
        return self.q.size * (1 if self.dq is None else 2)

    def __call__(self, q: np.ndarray, dq: np.ndarray, T: float):
        n = self.q.size
        eye, zero = np.eye(n), np.zeros((n, n))
        if self.dq is None:
            return q - self.q, eye, zero, np.zeros(n)
        c = np.concatenate([q - self.q, dq - self.dq])
        return c, np.vstack([eye, zero]), np.vstack([zero, eye]), np.zeros(2 * n)


@dataclass(frozen=True, eq=False)
class FrameResidual:
    """A link's pose, possibly of a moving target: rows (position 3)(orientation 3)(velocity 3).

    model : RobotModel; link : URDF link name; position : (3,) p0 [m]; orientation : (3, 3) R̄ or
    None; velocity, acceleration : (3,) of the target [m/s, m/s²] (zero for a fixed goal);
    match_velocity : the link origin's linear velocity equals the target's v̄(T).
    """

    model: object
    link: str
    position: np.ndarray
    orientation: np.ndarray | None = None
    velocity: np.ndarray | None = None
    acceleration: np.ndarray | None = None
    match_velocity: bool = False

    @property
    def size(self) -> int:
        return 3 + (3 if self.orientation is not None else 0) + (3 if self.match_velocity else 0)

    def _motion(self) -> tuple[np.ndarray, np.ndarray]:
        z = np.zeros(3)
        return (z if self.velocity is None else np.asarray(self.velocity, float),
                z if self.acceleration is None else np.asarray(self.acceleration, float))

    def target(self, T: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(p̄(T) [m], v̄(T) [m/s]) of the target at time T: each (3,), or (k, 3) at times T (k, 1)."""
        v0, a = self._motion()
        return self.position + v0 * T + 0.5 * a * T**2, v0 + a * T

    def pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(p (3,), R (3, 3)) of the link at q (n,)."""
        P = link_poses(self.model, q)[self.link]
        return P[:3, 3], P[:3, :3]

    def __call__(self, q: np.ndarray, dq: np.ndarray, T: float):
        c, cq, cv, cT = self.batch(np.asarray(q, float)[None], np.asarray(dq, float)[None], T)
        return c[0], cq[0], cv[0], cT

    def batch(self, q: np.ndarray, dq: np.ndarray, T: float | np.ndarray):
        """The residual at K instants together: q, dq (K, n) → (c (K, r), ∂c/∂q (K, r, n), ∂c/∂q̇ (K, r, n),
        ∂c/∂T (r,)) (the forward kinematics batched over the K samples). T (K,) instead of a float: each sample's own
        duration, and ∂c/∂T (K, r) (the same numbers as K calls with a float T).
        """
        K, n = q.shape
        v0, a = self._motion()
        if np.ndim(T):  # the target's terms per sample, as ``target`` computes them for one T
            T = np.asarray(T, float)[:, None]
            p_goal, v_goal = self.position + v0 * T + 0.5 * a * T**2, v0 + a * T
        else:
            p_goal, v_goal = self.target(T)
        zero = np.zeros((K, 3, n))
        P, V, dV_dq, J = link_motion(self.model, q, dq, self.link)  # one pass along the link's chain
        c, cq, cv, cT = [P[:, :3, 3] - p_goal], [J[:, :3]], [zero], [-(v0 + a * T)]
        if self.orientation is not None:
            e, de = zip(*(orientation_residual(R, self.orientation) for R in P[:, :3, :3]))
            c.append(np.array(e))
            cq.append(np.matmul(np.array(de), J[:, 3:]))
            cv.append(zero)
            cT.append(np.zeros(np.shape(cT[0])))
        if self.match_velocity:
            c.append(V[:, :3] - v_goal)
            cq.append(dV_dq[:, :3])
            cv.append(J[:, :3])
            cT.append(np.broadcast_to(-a, np.shape(cT[0])))
        return (np.concatenate(c, axis=1), np.concatenate(cq, axis=1), np.concatenate(cv, axis=1),
                np.concatenate(cT, axis=-1))


def reach(model, link: str) -> tuple[np.ndarray, float] | None:
    """(o (3,) [m], r [m]): the link origin stays within the ball of radius r about o for every q, or None
    when the chain to the link has a prismatic joint (no such bound).

    o is the origin of the first moving joint of the chain (fixed in the root frame); every joint
    origin o_k lies on its axis, so it is fixed in both the parent and the child body, and the
    distances |o_{k+1} − o_k| (and from the last one to the link origin) do not depend on q:
    |p(q) − o| ≤ Σ_k |o_{k+1} − o_k| + |p − o_last| (the triangle inequality along the chain).
    """
    from hoc_cli.dynamics.kinematics import body_poses, chain_to_root, link_body

    b, offset = link_body(model, link)
    if b < 0:
        return None
    chain = chain_to_root(model, b)
    if any(model.joint_types[j] == "prismatic" for j in chain):
        return None
    poses = body_poses(model, np.zeros((model.n, 1)), chain)
    points = [poses[j][0, :3, 3] for j in chain] + [(poses[b][0] @ offset)[:3, 3]]
    return points[0], float(sum(np.linalg.norm(b - a) for a, b in zip(points[:-1], points[1:])))
