"""Batched rigid-body dynamics of a :class:`~hoc_cli.model.RobotModel`: inverse dynamics (recursive
Newton-Euler), mass matrix, forward dynamics, analytic derivatives and link poses.

Symbols (SI units; sample axis first in every public array):

====== ================================================================================
K      number of samples (time instants) evaluated together
n      number of movable joints (= bodies); column order = ``model.joint_names``
q      (K, n) joint positions, rad (revolute, continuous) or m (prismatic)
dq     (K, n) joint velocities q̇, rad/s or m/s
ddq    (K, n) joint accelerations q̈, rad/s² or m/s²
u      (K, n) joint torques (N·m) or forces (N): u = M(q) q̈ + h(q, q̇)
M      (K, n, n) joint-space mass matrix, symmetric positive definite, kg·m² / kg·m / kg
h      (K, n) bias forces C(q, q̇) q̇ + g(q): u at q̈ = 0
g      gravity, (3,) m/s² in the root frame (``model.gravity``)
λ      (K, n) weights of a vector-Jacobian product λᵀ ∂u/∂q
v, a   spatial velocity / acceleration (ω, v) of a body, in its own frame
f, F   spatial force (n, f) on one body / transmitted through its joint (subtree sum)
I      (6, 6) spatial inertia of a body about its frame origin
X      (6, 6) Plücker transform of a joint's constant part (``model.tree_motion``)
====== ================================================================================

Implementation. Every joint moves about or along its body's local z axis (see
:mod:`hoc_cli.model.tree`), so the q-dependent part of a joint transform is a plane rotation of
x/y components (cos, sin of q) or a shift along z. Internally arrays are stored *sample axis last*
(``(6, K)`` per body, components as rows) so that each numpy operation streams over K contiguous
values and the constant 6 × 6 transforms and inertias apply as one BLAS product ``(6, 6) @ (6, K)``;
the only Python loops are over bodies. Derivatives are computed by forward-mode differentiation of
the same recursion, with all 3n tangent directions (∂/∂q, ∂/∂q̇, ∂/∂q̈) carried together in a
``(6, D, K)`` array; the ∂/∂q̈ block is the mass matrix. The algorithm is the recursive
Newton-Euler algorithm as described by Featherstone, *Rigid Body Dynamics Algorithms* (2008), ch. 5.
"""
from __future__ import annotations

import numpy as np

from .model.tree import RobotModel

#: samples processed together by the derivative kernels (bounds the (6, 3n, K) tangent arrays)
CHUNK = 512


# --------------------------------------------------------------------------- input checking
def _batch(model: RobotModel, name: str, x) -> np.ndarray:
    """(K, n) float array from (K, n) or (n,) input; ValueError naming the argument otherwise."""
    arr = np.asarray(x, dtype=float)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != model.n:
        raise ValueError(f"{name}: expected shape (K, {model.n}) or ({model.n},) for joints "
                         f"{list(model.joint_names)}, got {np.shape(x)}")
    return arr


def _inputs(model: RobotModel, **arrays):
    """Check every array, require a common K; returns (list of (n, K) contiguous arrays, K, 1-D?)."""
    out = []
    K = None
    one_d = all(np.ndim(v) == 1 for v in arrays.values())
    for name, value in arrays.items():
        arr = _batch(model, name, value)
        if K is None:
            K = arr.shape[0]
        elif arr.shape[0] != K:
            first = next(iter(arrays))
            raise ValueError(f"{name}: has {arr.shape[0]} samples but {first} has {K}")
        out.append(np.ascontiguousarray(arr.T))
    return out, K, one_d


def _shape_out(x: np.ndarray, one_d: bool) -> np.ndarray:
    return x[0] if one_d else x


# --------------------------------------------------------------------------- joint kernels
# A (6, ...) array is viewed as (2, 3, ...): [angular|linear] × [x, y, z].

def _motion_in(m: np.ndarray, prismatic: bool, c, s, q) -> None:
    """In place: motion vectors in the joint's constant frame → the moved body frame.

    Revolute: rotate by Rz(q)ᵀ (x' = c x + s y, y' = c y − s x). Prismatic: shift the origin by
    q e_z (v' = v − q e_z × ω).
    """
    if prismatic:
        m[3] += q * m[1]
        m[4] -= q * m[0]
    else:
        m3 = m.reshape((2, 3) + m.shape[1:])
        x = m3[:, 0]
        y = m3[:, 1]
        t = c * x
        t += s * y
        y *= c
        y -= s * x
        x[...] = t


def _force_out(f: np.ndarray, prismatic: bool, c, s, q) -> np.ndarray:
    """Force vectors in the moved body frame → the joint's constant frame (new array)."""
    out = f.copy()
    if prismatic:
        out[0] -= q * f[4]
        out[1] += q * f[3]
    else:
        o3 = out.reshape((2, 3) + f.shape[1:])
        f3 = f.reshape((2, 3) + f.shape[1:])
        o3[:, 0] = c * f3[:, 0]
        o3[:, 0] -= s * f3[:, 1]
        o3[:, 1] = s * f3[:, 0]
        o3[:, 1] += c * f3[:, 1]
    return out


def _cross_force_add(out: np.ndarray, v: np.ndarray, h: np.ndarray) -> None:
    """In place ``out += v ×* h`` = (ω × h_n + v_lin × h_f, ω × h_f) for spatial v (motion), h (force)."""
    w0, w1, w2, l0, l1, l2 = v
    n0, n1, n2, f0, f1, f2 = h
    out[0] += w1 * n2 - w2 * n1 + l1 * f2 - l2 * f1
    out[1] += w2 * n0 - w0 * n2 + l2 * f0 - l0 * f2
    out[2] += w0 * n1 - w1 * n0 + l0 * f1 - l1 * f0
    out[3] += w1 * f2 - w2 * f1
    out[4] += w2 * f0 - w0 * f2
    out[5] += w0 * f1 - w1 * f0


def _matmul6(X: np.ndarray, m: np.ndarray) -> np.ndarray:
    """(6, 6) @ (6, ...) as one BLAS product."""
    return (X @ m.reshape(6, -1)).reshape(m.shape)


# --------------------------------------------------------------------------- recursions
class _Pass:
    """Nominal RNEA quantities of one batch, kept for the tangent (derivative) pass."""

    __slots__ = ("c", "s", "q", "dq", "VA", "VAc", "RF", "tau")


def _rnea(model: RobotModel, q, dq, ddq, gravity: bool, keep: bool = False) -> _Pass:
    """Recursive Newton-Euler on (n, K) arrays; ``dq`` may be None (zero velocity)."""
    n, K = q.shape
    P = _Pass()
    P.q = q
    P.dq = dq
    P.c = np.cos(q)
    P.s = np.sin(q)
    prism = model.is_prismatic
    VA = [None] * n  # (6, 2, K): [:, 0] velocity, [:, 1] acceleration
    VAc = [None] * n
    f = [None] * n
    base = np.zeros((6, 2, 1))
    if gravity:
        base[3:, 1, 0] = -model.gravity
    for i in model.order:
        p = model.parent[i]
        src = base if p < 0 else VA[p]
        m = _matmul6(model.tree_motion[i], src)
        if m.shape[2] != K:
            m = np.repeat(m, K, axis=2)
        _motion_in(m, prism[i], P.c[i], P.s[i], q[i])
        if keep:
            VAc[i] = m.copy()
        v = m[:, 0]
        a = m[:, 1]
        if dq is not None:
            w = dq[i]
            if prism[i]:
                a[3] += w * v[1]
                a[4] -= w * v[0]
                v[5] += w
            else:
                a[0] += w * v[1]
                a[1] -= w * v[0]
                a[3] += w * v[4]
                a[4] -= w * v[3]
                v[2] += w
        a[5 if prism[i] else 2] += ddq[i]
        VA[i] = m
        h = _matmul6(model.inertia[i], m)
        fi = h[:, 1].copy()
        if dq is not None:
            _cross_force_add(fi, v, h[:, 0])
        f[i] = fi
    tau = np.empty((n, K))
    RF = [None] * n
    for i in model.order[::-1]:
        tau[i] = f[i][5 if prism[i] else 2]
        p = model.parent[i]
        if p >= 0 or keep:
            RF[i] = _force_out(f[i], prism[i], P.c[i], P.s[i], q[i])
            if p >= 0:
                f[p] += model.tree_motion[i].T @ RF[i]
    P.VA = VA
    P.VAc = VAc
    P.RF = RF
    P.tau = tau
    return P


def _tangent(model: RobotModel, P: _Pass, blocks: tuple[str, ...]) -> np.ndarray:
    """Forward-mode derivative of :func:`_rnea` along unit directions of the listed blocks
    (``'q'``, ``'dq'``, ``'ddq'``, n directions each). Returns dτ (n, D, K), D = n·len(blocks)."""
    n, K = P.q.shape
    D = n * len(blocks)
    off = {b: k * n for k, b in enumerate(blocks)}
    prism = model.is_prismatic
    has_v = P.dq is not None
    dVA = [None] * n
    df = [None] * n
    for i in model.order:
        p = model.parent[i]
        if p < 0:
            dm = np.zeros((6, 2, D, K))
        else:
            dm = _matmul6(model.tree_motion[i], dVA[p])
            _motion_in(dm, prism[i], P.c[i][None], P.s[i][None], P.q[i][None])
        mc = P.VAc[i]  # nominal, before the joint's own velocity terms
        v = P.VA[i][:, 0]
        if "q" in off:
            j = off["q"] + i
            if prism[i]:
                dm[3, :, j] += mc[1]
                dm[4, :, j] -= mc[0]
            else:
                dm[[0, 3], :, j] += mc[[1, 4]]
                dm[[1, 4], :, j] -= mc[[0, 3]]
        dv = dm[:, 0]
        da = dm[:, 1]
        if has_v:
            w = P.dq[i][None]
            if prism[i]:
                da[3] += w * dv[1]
                da[4] -= w * dv[0]
            else:
                da[0] += w * dv[1]
                da[1] -= w * dv[0]
                da[3] += w * dv[4]
                da[4] -= w * dv[3]
        if "dq" in off:
            j = off["dq"] + i
            if has_v:
                if prism[i]:
                    da[3, j] += v[1]
                    da[4, j] -= v[0]
                else:
                    da[0, j] += v[1]
                    da[1, j] -= v[0]
                    da[3, j] += v[4]
                    da[4, j] -= v[3]
            dv[5 if prism[i] else 2, j] += 1.0
        if "ddq" in off:
            da[5 if prism[i] else 2, off["ddq"] + i] += 1.0
        dVA[i] = dm
        dh = _matmul6(model.inertia[i], dm)
        dfi = dh[:, 1].copy()
        if has_v or "dq" in off:
            h_v = model.inertia[i] @ v
            _cross_force_add(dfi, dv, h_v[:, None])
            _cross_force_add(dfi, v[:, None], dh[:, 0])
        df[i] = dfi
    dtau = np.empty((n, D, K))
    for i in model.order[::-1]:
        dtau[i] = df[i][5 if prism[i] else 2]
        p = model.parent[i]
        if p < 0:
            continue
        r = _force_out(df[i], prism[i], P.c[i][None], P.s[i][None], P.q[i][None])
        if "q" in off:
            j = off["q"] + i
            if prism[i]:
                fo = P.RF[i]
                r[0, j] -= fo[4]
                r[1, j] += fo[3]
            else:
                fo = P.RF[i]
                r[[0, 3], j] -= fo[[1, 4]]
                r[[1, 4], j] += fo[[0, 3]]
        df[p] += _matmul6(model.tree_motion[i].T, r)
    return dtau


def _chunks(K: int):
    for start in range(0, K, CHUNK):
        yield slice(start, min(K, start + CHUNK))


# --------------------------------------------------------------------------- public kernels
def inverse_dynamics(model: RobotModel, q, dq, ddq, gravity: bool = True) -> np.ndarray:
    """Joint torques u (K, n) = M(q) q̈ + C(q, q̇) q̇ + g(q), by recursive Newton-Euler.

    Args:
        q, dq, ddq: (K, n) positions, velocities, accelerations (or (n,) for one sample, then
            the result is (n,)).
        gravity: False drops the gravity term g(q).
    Returns:
        u: (K, n) N·m (revolute) or N (prismatic).
    """
    (qT, dqT, ddqT), K, one_d = _inputs(model, q=q, dq=dq, ddq=ddq)
    P = _rnea(model, qT, dqT, ddqT, gravity)
    return _shape_out(P.tau.T.copy(), one_d)


def bias_forces(model: RobotModel, q, dq) -> np.ndarray:
    """Bias forces h (K, n) = C(q, q̇) q̇ + g(q) = ID(q, q̇, 0), N·m or N."""
    (qT, dqT), K, one_d = _inputs(model, q=q, dq=dq)
    P = _rnea(model, qT, dqT, np.zeros_like(qT), True)
    return _shape_out(P.tau.T.copy(), one_d)


def gravity_forces(model: RobotModel, q) -> np.ndarray:
    """Gravity torques g (K, n) = ID(q, 0, 0), N·m or N."""
    (qT,), K, one_d = _inputs(model, q=q)
    P = _rnea(model, qT, None, np.zeros_like(qT), True)
    return _shape_out(P.tau.T.copy(), one_d)


def mass_matrix(model: RobotModel, q) -> np.ndarray:
    """Joint-space mass matrix M (K, n, n) at positions q (K, n); symmetric positive definite.

    Column j is the (gravity-free, zero-velocity) Newton-Euler response to q̈ = e_j, all columns
    propagated together.
    """
    (qT,), K, one_d = _inputs(model, q=q)
    out = np.empty((K, model.n, model.n))
    for sl in _chunks(K):
        P = _rnea(model, qT[:, sl], None, np.zeros_like(qT[:, sl]), False, keep=True)
        dtau = _tangent(model, P, ("ddq",))
        out[sl] = np.transpose(dtau, (2, 0, 1))
    return _shape_out(out, one_d)


def forward_dynamics(model: RobotModel, q, dq, u) -> np.ndarray:
    """Joint accelerations q̈ (K, n) = M(q)⁻¹ (u − h(q, q̇)) by a Cholesky solve per sample.

    Args:
        q, dq: (K, n) state; u: (K, n) applied joint torques/forces (N·m or N).
    Raises:
        numpy.linalg.LinAlgError: if M is not positive definite at some sample.
    """
    (qT, dqT, uT), K, one_d = _inputs(model, q=q, dq=dq, u=u)
    h = _rnea(model, qT, dqT, np.zeros_like(qT), True).tau.T
    M = mass_matrix(model, qT.T)
    L = np.linalg.cholesky(M)
    rhs = (uT.T - h)[:, :, None]
    y = np.linalg.solve(L, rhs)
    ddq = np.linalg.solve(np.swapaxes(L, 1, 2), y)[:, :, 0]
    return _shape_out(ddq, one_d)


def id_derivatives(model: RobotModel, q, dq, ddq, gravity: bool = True):
    """Inverse dynamics and its partial derivatives.

    Returns:
        (u, du_dq, du_ddq, M): u (K, n); du_dq (K, n, n) with ``du_dq[k, i, j] = ∂u_i/∂q_j``;
        du_ddq (K, n, n) = ∂u/∂q̇ (derivative with respect to the *velocity* ``dq``);
        M (K, n, n) = ∂u/∂q̈, the mass matrix.
    """
    (qT, dqT, ddqT), K, one_d = _inputs(model, q=q, dq=dq, ddq=ddq)
    n = model.n
    u = np.empty((K, n))
    du_dq = np.empty((K, n, n))
    du_ddq = np.empty((K, n, n))
    M = np.empty((K, n, n))
    for sl in _chunks(K):
        P = _rnea(model, qT[:, sl], dqT[:, sl], ddqT[:, sl], gravity, keep=True)
        dtau = _tangent(model, P, ("q", "dq", "ddq"))
        u[sl] = P.tau.T
        du_dq[sl] = np.transpose(dtau[:, :n], (2, 0, 1))
        du_ddq[sl] = np.transpose(dtau[:, n:2 * n], (2, 0, 1))
        M[sl] = np.transpose(dtau[:, 2 * n:], (2, 0, 1))
    return tuple(_shape_out(x, one_d) for x in (u, du_dq, du_ddq, M))


def id_vjp(model: RobotModel, q, dq, ddq, lam, gravity: bool = True):
    """Vector-Jacobian products of inverse dynamics.

    Args:
        q, dq, ddq: (K, n) state and acceleration; lam: (K, n) weights λ.
    Returns:
        (u, gq, gdq): u (K, n); gq (K, n) = λᵀ ∂u/∂q; gdq (K, n) = λᵀ ∂u/∂q̇, per sample.
    """
    (qT, dqT, ddqT, lT), K, one_d = _inputs(model, q=q, dq=dq, ddq=ddq, lam=lam)
    n = model.n
    u = np.empty((K, n))
    gq = np.empty((K, n))
    gdq = np.empty((K, n))
    for sl in _chunks(K):
        P = _rnea(model, qT[:, sl], dqT[:, sl], ddqT[:, sl], gravity, keep=True)
        dtau = _tangent(model, P, ("q", "dq"))
        g = np.einsum("ik,idk->dk", lT[:, sl], dtau)
        u[sl] = P.tau.T
        gq[sl] = g[:n].T
        gdq[sl] = g[n:].T
    return tuple(_shape_out(x, one_d) for x in (u, gq, gdq))


def mass_quadratic_grad(model: RobotModel, q, v) -> np.ndarray:
    """∂/∂q (vᵀ M(q) v) (K, n) with v (K, n) held fixed.

    Since M(q) v = ID(q, 0, v) without gravity, the gradient is vᵀ ∂ID(q, 0, v)/∂q (factor 1).
    """
    (qT, vT), K, one_d = _inputs(model, q=q, v=v)
    out = np.empty((K, model.n))
    for sl in _chunks(K):
        P = _rnea(model, qT[:, sl], None, vT[:, sl], False, keep=True)
        dtau = _tangent(model, P, ("q",))
        out[sl] = np.einsum("ik,idk->kd", vT[:, sl], dtau)
    return _shape_out(out, one_d)


def link_poses(model: RobotModel, q) -> dict[str, np.ndarray]:
    """Pose (K, 4, 4) of every URDF link (merged and fixed-base links included) in the root-link
    frame, keyed by link name; translations in m."""
    (qT,), K, one_d = _inputs(model, q=q)
    n = model.n
    body = [None] * n
    c, s = np.cos(qT), np.sin(qT)
    for i in model.order:
        J = np.zeros((K, 4, 4))
        J[:, 3, 3] = 1.0
        if model.joint_types[i] == "prismatic":
            J[:, 0, 0] = J[:, 1, 1] = J[:, 2, 2] = 1.0
            J[:, 2, 3] = qT[i]
        else:
            J[:, 0, 0] = c[i]
            J[:, 0, 1] = -s[i]
            J[:, 1, 0] = s[i]
            J[:, 1, 1] = c[i]
            J[:, 2, 2] = 1.0
        p = model.parent[i]
        base = model.tree_transform[i] if p < 0 else body[p] @ model.tree_transform[i]
        body[i] = base @ J
    out = {}
    for name, b, offset in zip(model.link_names, model.link_body, model.link_offset):
        T = np.broadcast_to(offset, (K, 4, 4)).copy() if b < 0 else body[b] @ offset
        out[name] = _shape_out(T, one_d)
    return out
