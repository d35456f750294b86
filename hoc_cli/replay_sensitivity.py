"""How far a replay's final state x(T) = (q(T), q̇(T)) can move under its own numerical errors: the
linearisation of the Hermite collocation integrator (``hoc_cli.simulate``) along a trajectory, and
the miss it explains (``hoc simulate --check``; derivation in docs/accuracy.md, "What the replay
check proves").

Symbols: N elements, m coefficients per node and joint (2 cubic, 3 quintic), n joints; a node's
coefficients R = (a, b[, c]) (m, n) flattened row-major to m·n; the collocation equations of
element e are F_e(L, R) = ID(q_h, q̇_h, q̈_h)(t_j) − u(t_j) = 0 at its m points t_j.

Implicit function theorem: an error δL in the left node, δU (m·n) in the torques at the points, or
δF left in the residual (Newton's tolerance, rounding) moves the right node by

    δR = D_e δL + J_e⁻¹ (δU − δF),   J_e = ∂F_e/∂R,   D_e = −J_e⁻¹ ∂F_e/∂L.

The products G_e = P D_{N−1} ⋯ D_e (P picks a and b of the last node: q(T), q̇(T)) carry an error at
node e to x(T): G_e is the replay's discrete state-transition matrix Φ(T, t_e). A replay's own
local errors are what Newton leaves in each element's equations (the residual F_e measured at the
nodes it computed; an element it had to subdivide is budgeted at Newton's stopping test, xtol·(1 +
|R|) in the scaled units (a, h b, h² c)), the rounding of the residual, and the torque history's own
representation error (a sampled torque's interpolation). Summed with triangle inequalities over the
elements, they bound the miss that the integrator and the torque's representation can cause,
whatever the dynamics' sensitivity; a torque history that is wrong by δu moves x(T) by about
Σ_e G_{e+1} J_e⁻¹ δU_e instead, with δU_e ~ δu, far more than that bound.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hoc_cli.elements import HermiteMesh
from hoc_cli.system import System
from hoc_cli.torque import TorqueSource

EPS = float(np.finfo(float).eps)
#: an explained miss above LINEAR_LIMIT · (1 + max |x(T)|) is beyond the linearisation's reach: the
#: replay cannot resolve the final state (``hoc simulate --check`` then fails)
LINEAR_LIMIT = 0.1
#: multiple of machine epsilon times the size of the inverse-dynamics terms taken as the rounding
#: error of one evaluation of the collocation residual (sums of n products in the RNEA)
ROUNDING_FACTOR = 16.0


@dataclass(frozen=True, eq=False)
class ReplaySensitivity:
    """The replay's linearisation along a trajectory.

    node_gain : (N + 1,) ‖G_e S_e⁻¹‖∞: the largest change of any component of x(T) [rad, m, rad/s,
        m/s] per unit error in node e measured in Newton's scaled units (a, h b, h² c), h the length
        of the element that ends at node e (node 0: the first element's)
    state_gain : (N + 1,) ‖G_e[:, :2n]‖∞: the same per unit error in (q, q̇) at node e, unscaled;
        its maximum is the amplification ‖Φ(T, t)‖∞
    torque_gain : (N,) ‖G_{e+1} J_e⁻¹‖∞: change of x(T) per N·m (or N) of error in the torques at
        element e's collocation points
    rounding : (N,) the residual's rounding error in element e [N·m]: ``ROUNDING_FACTOR`` · eps ·
        the largest inverse-dynamics term (|u|, ‖M‖ |q̈|, ‖∂u/∂q̇‖ |q̇|) at its points
    node_size : (N + 1,) max |R S| of each node in scaled units (Newton's 1 + |R| uses it)
    transition : (2n, 2n) G_0 restricted to (q, q̇) of node 0: ∂x(T)/∂x(0) of the replay
    """

    node_gain: np.ndarray
    state_gain: np.ndarray
    torque_gain: np.ndarray
    rounding: np.ndarray
    node_size: np.ndarray
    transition: np.ndarray

    @property
    def amplification(self) -> float:
        """The amplification max over t of ‖Φ(T, t)‖∞ along the trajectory (1 at t = T)."""
        return float(np.max(self.state_gain))

    def newton_bound(self, xtol: float, elements: np.ndarray | None = None) -> float:
        """Miss [rad, m, rad/s, m/s] that Newton's stopping test can leave: the right node of each
        element (of ``elements``, default all) within xtol · (1 + |R|) in scaled units, carried to x(T).
        """
        e = np.arange(self.torque_gain.size) if elements is None else np.asarray(elements, dtype=int)
        return float(np.sum(self.node_gain[e + 1] * xtol * (1.0 + self.node_size[e + 1])))

    def rounding_bound(self) -> float:
        """Miss that rounding in the collocation residual (and in the torque history) can cause."""
        return float(np.sum(self.torque_gain * self.rounding))

    def torque_bound(self, torque_error: np.ndarray) -> float:
        """Miss that a torque error of at most ``torque_error`` (N,) [N·m or N] per element can cause."""
        return float(np.sum(self.torque_gain * np.asarray(torque_error, dtype=float)))

    def state_bound(self, state_error: np.ndarray) -> float:
        """Miss that an error of at most ``state_error`` (N,) in (q, q̇) at each node 1 … N can cause."""
        return float(np.sum(self.state_gain[1:] * np.asarray(state_error, dtype=float)))


def replay_sensitivity(system: System, mesh: HermiteMesh, coeffs: np.ndarray, points: np.ndarray,
                       torque: TorqueSource) -> ReplaySensitivity:
    """Linearise the Hermite collocation march on ``mesh`` with collocation coordinates ``points``
    (m,) and torque history ``torque`` about the trajectory ``coeffs`` (N + 1, m, n) (the replay's
    own, or a plan's).

    One batched inverse-dynamics-derivative evaluation at the N·m points, N batched (m·n)² solves,
    and a backward product of N (2n × m·n)(m·n × m·n) matrices.
    """
    C = mesh.check_coefficients(np.asarray(coeffs, dtype=float))
    N, m, n = C.shape[0] - 1, mesh.m, C.shape[2]
    s = np.asarray(points, dtype=float)
    e = np.repeat(np.arange(N), m)
    BL = np.stack([mesh.shape_values(np.tile(s, N), r, e) for r in range(3)]).reshape(3, N, m, 2 * m)
    loc = mesh.local_coefficients(C)  # (N, 2m, n)
    q, dq, ddq = (np.einsum("ejk,ekn->ejn", BL[r], loc).reshape(N * m, n) for r in range(3))
    u, du_dq, du_ddq, M = (np.asarray(a, dtype=float) for a in system.id_derivatives(q, dq, ddq))
    applied = np.asarray(torque(mesh.time_of(e, np.tile(s, N))), dtype=float).reshape(N * m, n)
    grads = [a.reshape(N, m, n, n) for a in (du_dq, du_ddq, M)]

    def jacobian(side: slice) -> np.ndarray:  # ∂F/∂(node), (N, m·n, m·n): [e, (j, i), (k, l)]
        out = sum(np.einsum("ejil,ejk->ejikl", g, BL[r][:, :, side]) for r, g in enumerate(grads))
        return out.reshape(N, m * n, m * n)

    JR, JL = jacobian(slice(m, 2 * m)), jacobian(slice(0, m))
    JR_inv = np.linalg.inv(JR)
    D = -JR_inv @ JL
    hs = mesh.hs
    scale = np.concatenate([hs[:1], hs])[:, None] ** np.arange(m)[None, :]  # (N + 1, m): node e's h^k
    inv_scale = np.repeat(1.0 / scale, n, axis=1)  # (N + 1, m·n)

    G = np.eye(m * n)[: 2 * n]  # node N: x(T) = its a and b
    node_gain, state_gain, torque_gain = np.empty(N + 1), np.empty(N + 1), np.empty(N)
    for k in range(N, -1, -1):
        node_gain[k] = np.max(np.sum(np.abs(G * inv_scale[k]), axis=1))
        state_gain[k] = np.max(np.sum(np.abs(G[:, : 2 * n]), axis=1))
        if k > 0:
            torque_gain[k - 1] = np.max(np.sum(np.abs(G @ JR_inv[k - 1]), axis=1))
            G = G @ D[k - 1]

    terms = np.maximum(np.maximum(np.abs(u), np.abs(applied)), np.maximum(np.abs(M).sum(axis=2) * np.abs(ddq).max(axis=1, keepdims=True),
                                              np.abs(du_ddq).sum(axis=2) * np.abs(dq).max(axis=1, keepdims=True)))
    rounding = ROUNDING_FACTOR * EPS * terms.reshape(N, m * n).max(axis=1)
    node_size = np.max(np.abs(C * scale[:, :, None]), axis=(1, 2))
    return ReplaySensitivity(node_gain=node_gain, state_gain=state_gain, torque_gain=torque_gain,
                             rounding=rounding, node_size=node_size,
                             transition=(G[:, : 2 * n]).copy())


def representation_error(torque: TorqueSource, mesh: HermiteMesh, points: np.ndarray) -> np.ndarray:
    """An estimate of the torque history's own representation error in each element, (N,) [N·m or N].

    A ``SampledTorque`` through K samples: max |u − u₂| at the element's collocation points, u₂ the
    same interpolation through every other sample (and the last). Halving the samples multiplies a
    cubic spline's error by 16 where the torque is smooth, and by at least 2 at the kinks of a planned
    torque (it is only C⁰ at element nodes), so |u − u₂| exceeds u's own error; a linear interpolant
    (error O(Δt²)) is compared with the cubic spline through the same samples. Exact histories (a
    plan's Hermite torque, a constant): zeros, their rounding is in ``ReplaySensitivity.rounding``.
    """
    from hoc_cli.torque import SampledTorque

    N, m = mesh.N, np.asarray(points).size
    if not isinstance(torque, SampledTorque):
        return np.zeros(N)
    if torque.kind == "linear":
        other = SampledTorque(torque.t, torque.u, kind="cubic")
    else:
        keep = np.unique(np.append(np.arange(0, torque.t.size, 2), torque.t.size - 1))
        other = SampledTorque(torque.t[keep], torque.u[keep], kind="cubic")
    t = mesh.time_of(np.repeat(np.arange(N), m), np.tile(np.asarray(points, dtype=float), N))
    return np.abs(torque(t) - other(t)).reshape(N, -1).max(axis=1)


def collocation_residuals(system: System, mesh: HermiteMesh, coeffs: np.ndarray, points: np.ndarray,
                          torque: TorqueSource) -> np.ndarray:
    """Max |ID(q_h, q̇_h, q̈_h) − u| at each element's collocation points (N,) [N·m or N]: what the
    collocation equations leave at the trajectory ``coeffs`` (N + 1, m, n) (a replay's Newton residual).
    """
    C = mesh.check_coefficients(np.asarray(coeffs, dtype=float))
    N, m, n = C.shape[0] - 1, mesh.m, C.shape[2]
    e, s = np.repeat(np.arange(N), m), np.tile(np.asarray(points, dtype=float), N)
    t = mesh.time_of(e, s)
    B = [mesh.shape_values(s, r, e) for r in range(3)]  # (N·m, 2m)
    loc = mesh.local_coefficients(C)[e]  # (N·m, 2m, n)
    q, dq, ddq = (np.einsum("kj,kjn->kn", b, loc) for b in B)
    F = np.asarray(system.inverse_dynamics(q, dq, ddq), dtype=float) - np.asarray(torque(t), dtype=float).reshape(N * m, n)
    return np.abs(F).reshape(N, m * n).max(axis=1)
