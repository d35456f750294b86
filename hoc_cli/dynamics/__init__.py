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
J      (K, 6, n) frame Jacobian of a link (``frame_jacobian``): [v; ω] = J q̇, rows 0:3 the linear
       velocity of the link origin (m/s), rows 3:6 the angular velocity (rad/s), root-link frame
====== ================================================================================

Implementation. Every joint moves about or along its body's local z axis (see
:mod:`hoc_cli.model.tree`), so the q-dependent part of a joint transform mixes only the x/y
components: m ← α m + β D m with (α, β) = (cos q, sin q) (revolute) or (1, q) (prismatic) and D a
constant generator. Internally arrays are stored *sample axis last*, per body as
``(rows, channels, K)``, and every body's arrays are slices of one ``(n, rows, channels, K)``
array, so that (a) each numpy operation streams over K contiguous values, (b) a joint step is one
BLAS product with a constant matrix that stacks the 6 × 6 transform with its D product, plus two
or three element-wise operations, and (c) everything that is not a recursion (body forces, the
adjoints of the velocity products, the gradient read-out) runs for all bodies in one batched
operation. The only Python loops are the recursions over bodies.

* ``inverse_dynamics``: the recursive Newton-Euler algorithm (Featherstone, *Rigid Body Dynamics
  Algorithms*, 2008, ch. 5), velocity and acceleration carried together.
* ``mass_matrix``: the same recursion applied to the n unit accelerations at once (gravity and
  velocity off), each body carrying only the columns of its ancestors.
* ``id_vjp`` (λᵀ∂u/∂q, λᵀ∂u/∂q̇ and λᵀ∂u/∂q̈ = Mλ), ``mass_quadratic_grad``: one reverse (adjoint)
  sweep of the recursion, O(n) per sample; ``id_derivatives``: the same sweep seeded with the n
  unit vectors, giving ∂u/∂q, ∂u/∂q̇ and ∂u/∂q̈ = M row by row (from 32 samples on, the root-to-leaves half and the local adjoints
  carry at each body only the seeds of its ancestors, the only nonzero ones).
* ``id_and_mass``: u and M from one pass (the unit-acceleration columns ride along).
* ``mass_cholesky``: batched Cholesky factors of M that also reject a mass matrix singular to
  working precision (a pivot ≤ 1e-14 of its largest diagonal entry), which a plain factorisation
  can let through by rounding.
* ``covariant_gradient_terms``: u and M in one pass (the unit-acceleration columns ride along with
  the Newton-Euler pass), w = M⁻¹u, and the gradient of ½ uᵀM⁻¹u as one reverse sweep at the
  shifted acceleration q̈ − ½ w.
* ``link_poses``, ``frame_jacobian``, ``link_velocity``, ``link_velocity_derivatives``, ``link_motion``: forward
  kinematics of a link, batched over samples (:mod:`.kinematics`; J's rows 0:3 are the linear
  velocity of the link origin, rows 3:6 the angular velocity, both in the root-link frame).

Modules: :mod:`._layout` (input checks, chunk sizes, storage layout, per-model constants),
:mod:`._passes` (the Newton-Euler forward pass, body forces, subtree sums, read-outs),
:mod:`._adjoint` (the reverse sweep: vector-Jacobian products and full Jacobians),
:mod:`.kinematics` (link poses, frame Jacobians, link velocities). This module holds the public
functions.
"""
from __future__ import annotations

import numpy as np

from ..model.tree import RobotModel
from ._adjoint import _jac_work, _jacobians_into, _vjp_rows
from ._layout import (
    DERIV_CHUNK,
    ID_CHUNK,
    JAC_MIN_K,
    MASS_CHUNK,
    VJP_CHUNK,
    _chunks,
    _consts,
    _inputs,
    _shape_out,
)
from ._passes import (
    _h_and_mass,
    _mass_from,
    _newton_euler,
    _shift_acceleration,
    _tau,
    _tau_of,
)
from .kinematics import (
    frame_jacobian,
    link_motion,
    link_poses,
    link_velocity,
    link_velocity_derivatives,
)

__all__ = [
    "SINGULAR_PIVOT", "bias_forces", "covariant_gradient_terms", "forward_dynamics",
    "frame_jacobian", "gravity_forces", "id_and_mass", "id_derivatives", "id_vjp", "id_vjp_kept", "inverse_dynamics",
    "inverse_dynamics_kept",
    "link_motion", "link_poses", "link_velocity", "link_velocity_derivatives", "mass_cholesky", "mass_matrix",
    "mass_quadratic_grad",
]


#: a Cholesky pivot L_ii² below this fraction of the largest diagonal entry of M means M is singular
#: to working precision (M⁻¹u would be rounding noise): a point mass on a joint axis, for example.
SINGULAR_PIVOT = 1e-14


def mass_cholesky(M: np.ndarray) -> np.ndarray:
    """Lower Cholesky factors (K, n, n) of mass matrices M (K, n, n).

    Raises
    ------
        numpy.linalg.LinAlgError: if some M is not positive definite, or singular to working
        precision (a pivot L_ii² ≤ ``SINGULAR_PIVOT`` · max_j M_jj).
    """
    L = np.linalg.cholesky(M)
    if M.shape[-1]:
        piv = np.diagonal(L, axis1=-2, axis2=-1) ** 2
        scale = np.max(np.diagonal(M, axis1=-2, axis2=-1), axis=-1, keepdims=True)
        if np.any(piv <= SINGULAR_PIVOT * scale):
            raise np.linalg.LinAlgError("the mass matrix is singular to working precision")
    return L


def inverse_dynamics(model: RobotModel, q, dq, ddq, gravity: bool = True) -> np.ndarray:
    """Joint torques u (K, n) = M(q) q̈ + C(q, q̇) q̇ + g(q), by recursive Newton-Euler.

    Parameters
    ----------
    q, dq, ddq
        (K, n) positions, velocities, accelerations (or (n,) for one sample, then
        the result is (n,)).
    gravity
        False drops the gravity term g(q).

    Returns
    -------
        u: (K, n) N·m (revolute) or N (prismatic).
    """
    (qT, dqT, ddqT), _, one_d = _inputs(model, q=q, dq=dq, ddq=ddq)
    return _shape_out(_tau(model, qT, dqT, ddqT, gravity), one_d)


def bias_forces(model: RobotModel, q, dq) -> np.ndarray:
    """Bias forces h (K, n) = C(q, q̇) q̇ + g(q) = ID(q, q̇, 0), N·m or N."""
    (qT, dqT), _, one_d = _inputs(model, q=q, dq=dq)
    return _shape_out(_tau(model, qT, dqT, None, True), one_d)


def gravity_forces(model: RobotModel, q) -> np.ndarray:
    """Gravity torques g (K, n) = ID(q, 0, 0), N·m or N."""
    (qT,), _, one_d = _inputs(model, q=q)
    return _shape_out(_tau(model, qT, None, None, True), one_d)


def mass_matrix(model: RobotModel, q) -> np.ndarray:
    """Joint-space mass matrix M (K, n, n) at positions q (K, n); symmetric positive definite.

    Column j is the (gravity-free, zero-velocity) Newton-Euler response to q̈ = e_j, all columns
    propagated together (each body carrying only its ancestors' columns).
    """
    (qT,), K, one_d = _inputs(model, q=q)
    C = _consts(model)
    out = np.empty((K, model.n, model.n))
    if model.n:
        for sl in _chunks(K, MASS_CHUNK):
            _mass_from(C, _newton_euler(C, qT[:, sl], None, None, False, cols=True), out[sl])
    return _shape_out(out, one_d)


def id_and_mass(model: RobotModel, q, dq, ddq) -> tuple[np.ndarray, np.ndarray]:
    """Torques u (K, n) = ID(q, q̇, q̈) (gravity included) and mass matrices M (K, n, n) in one pass.

    The unit-acceleration columns of M ride along with the Newton-Euler pass of u: the same
    operations on each value as ``inverse_dynamics`` and ``mass_matrix``, so the same numbers (bit
    for bit, measured, except in a chunk of a single sample, whose one-column products BLAS may
    sum in another order), at about the price of one pass instead of two.
    """
    (qT, dqT, ddqT), K, one_d = _inputs(model, q=q, dq=dq, ddq=ddq)
    u, M = _bias_and_mass(model, qT, dqT, ddqT, K)
    return _shape_out(u, one_d), _shape_out(M, one_d)


def _bias_and_mass(model: RobotModel, qT: np.ndarray, dqT: np.ndarray, ddqT: np.ndarray | None,
                   K: int) -> tuple[np.ndarray, np.ndarray]:
    """(ID(q, q̇, q̈) (K, n), with ``ddqT`` None the bias h(q, q̇); M(q) (K, n, n)) from joint-major inputs (n, K),
    chunk by chunk (``MASS_CHUNK`` samples) in one Newton-Euler pass each.
    """
    C = _consts(model)
    n = model.n
    h = np.empty((K, n))
    M = np.empty((K, n, n))
    if n:
        for sl in _chunks(K, MASS_CHUNK):
            _h_and_mass(C, qT[:, sl], dqT[:, sl], None if ddqT is None else ddqT[:, sl], h[sl], M[sl])
    return h, M


def forward_dynamics(model: RobotModel, q, dq, u) -> np.ndarray:
    """Joint accelerations q̈ (K, n) = M(q)⁻¹ (u − h(q, q̇)) by a Cholesky solve per sample.

    Parameters
    ----------
    q, dq
        (K, n) state; u: (K, n) applied joint torques/forces (N·m or N).

    Raises
    ------
        numpy.linalg.LinAlgError: if M is not positive definite at some sample.
    """
    (qT, dqT, uT), K, one_d = _inputs(model, q=q, dq=dq, u=u)
    h, M = _bias_and_mass(model, qT, dqT, None, K)
    L = np.linalg.cholesky(M)
    rhs = (uT.T - h)[:, :, None]
    y = np.linalg.solve(L, rhs)
    ddq = np.linalg.solve(np.swapaxes(L, 1, 2), y)[:, :, 0]
    return _shape_out(ddq, one_d)


def id_derivatives(model: RobotModel, q, dq, ddq, gravity: bool = True):
    """Inverse dynamics and its partial derivatives.

    Returns
    -------
        (u, du_dq, du_ddq, M): u (K, n); du_dq (K, n, n) with ``du_dq[k, i, j] = ∂u_i/∂q_j``;
        du_ddq (K, n, n) = ∂u/∂q̇ (derivative with respect to the *velocity* ``dq``);
        M (K, n, n) = ∂u/∂q̈, the mass matrix.
    """
    (qT, dqT, ddqT), K, one_d = _inputs(model, q=q, dq=dq, ddq=ddq)
    C = _consts(model)
    n = model.n
    u = np.empty((K, n))
    du_dq = np.empty((K, n, n))
    du_ddq = np.empty((K, n, n))
    M = np.empty((K, n, n))
    if n and K:
        chunk = max(JAC_MIN_K, min(DERIV_CHUNK, DERIV_CHUNK * 49 // (n * n)))
        work = _jac_work(C, min(K, chunk)) if K >= JAC_MIN_K else None
        for sl in _chunks(K, chunk):
            P = _newton_euler(C, qT[:, sl], dqT[:, sl], ddqT[:, sl], gravity, cols=False)
            _jacobians_into(C, P, work, du_dq[sl], du_ddq[sl], M[sl])
            u[sl] = _tau_of(C, P).T
    return tuple(_shape_out(x, one_d) for x in (u, du_dq, du_ddq, M))


def id_vjp(model: RobotModel, q, dq, ddq, lam, gravity: bool = True):
    """Vector-Jacobian products of inverse dynamics with respect to all three inputs.

    Parameters
    ----------
    q, dq, ddq
        (K, n) state and acceleration; lam: (K, n) weights λ.

    Returns
    -------
        (u, gq, gdq, gddq): u (K, n); gq (K, n) = λᵀ ∂u/∂q; gdq (K, n) = λᵀ ∂u/∂q̇;
        gddq (K, n) = λᵀ ∂u/∂q̈ = M(q) λ, per sample.
    """
    (qT, dqT, ddqT, lT), K, one_d = _inputs(model, q=q, dq=dq, ddq=ddq, lam=lam)
    C = _consts(model)
    n = model.n
    u = np.empty((K, n))
    gq = np.empty((K, n))
    gdq = np.empty((K, n))
    gddq = np.empty((K, n))
    for sl in _chunks(K, VJP_CHUNK):
        P = _newton_euler(C, qT[:, sl], dqT[:, sl], ddqT[:, sl], gravity, cols=False)
        gq[sl], gdq[sl], gddq[sl] = _vjp_rows(C, P, lT[:, sl])
        u[sl] = _tau_of(C, P).T
    return tuple(_shape_out(x, one_d) for x in (u, gq, gdq, gddq))


def inverse_dynamics_kept(model: RobotModel, q, dq, ddq) -> tuple[np.ndarray, object]:
    """``inverse_dynamics`` (gravity included) and what :func:`id_vjp_kept` takes to run ``id_vjp`` at the same
    (q, q̇, q̈) without a second Newton-Euler pass.

    Returns
    -------
        (u (K, n), kept): kept holds the finished pass when K ≤ ``ID_CHUNK`` (one chunk, as ``id_vjp`` would make
        it: the same numbers), else the inputs (``id_vjp_kept`` then runs ``id_vjp``).
    """
    (qT, dqT, ddqT), K, one_d = _inputs(model, q=q, dq=dq, ddq=ddq)
    if K > ID_CHUNK or K > VJP_CHUNK or not model.n or not K:
        return _shape_out(_tau(model, qT, dqT, ddqT, True), one_d), (q, dq, ddq)
    P = _newton_euler(_consts(model), qT, dqT, ddqT, True, cols=False)
    return _shape_out(np.ascontiguousarray(_tau_of(_consts(model), P).T), one_d), P


def id_vjp_kept(model: RobotModel, kept, lam) -> tuple[np.ndarray, ...]:
    """``id_vjp`` at the (q, q̇, q̈) of an :func:`inverse_dynamics_kept` call (its ``kept``), weights lam (K, n):
    (u, gq, gdq, gddq), each (K, n), the same numbers.
    """
    if isinstance(kept, tuple):
        return id_vjp(model, *kept, lam)
    (lT,), K, one_d = _inputs(model, lam=lam)
    C = _consts(model)
    out = (_tau_of(C, kept).T,) + _vjp_rows(C, kept, lT)
    return tuple(_shape_out(np.ascontiguousarray(x), one_d) for x in out)


def mass_quadratic_grad(model: RobotModel, q, v) -> np.ndarray:
    """∂/∂q (vᵀ M(q) v) (K, n) with v (K, n) held fixed.

    Since M(q) v = ID(q, 0, v) without gravity, the gradient is vᵀ ∂ID(q, 0, v)/∂q (factor 1).
    """
    (qT, vT), K, one_d = _inputs(model, q=q, v=v)
    C = _consts(model)
    out = np.empty((K, model.n))
    for sl in _chunks(K, VJP_CHUNK):
        P = _newton_euler(C, qT[:, sl], None, vT[:, sl], False, cols=False)
        out[sl] = _vjp_rows(C, P, vT[:, sl])[0]
    return _shape_out(out, one_d)


def covariant_gradient_terms(model: RobotModel, q, dq, ddq, return_w: bool = False):
    """Everything the covariant cost L = ½ uᵀ M(q)⁻¹ u needs per sample, in one fused pass.

    With u = ID(q, q̇, q̈) (gravity included) and w = M⁻¹ u:
        gq  = wᵀ ∂u/∂q − ½ ∂(wᵀ M w)/∂q   (= ∂L/∂q),
        gdq = wᵀ ∂u/∂q̇                     (= ∂L/∂q̇);   ∂L/∂q̈ = u.
    Because ID is affine in q̈, both are one vector-Jacobian product of ID at the shifted
    acceleration q̈ − ½ w (same velocity), with weights w. The mass matrix is computed in the same
    forward/backward pass as u (its unit-acceleration columns ride along), and the shifted pass
    reuses the velocities and velocity products.

    Parameters
    ----------
    q, dq, ddq
        (K, n) (or (n,)) positions, velocities, accelerations.
    return_w
        also return w = M⁻¹ u (K, n).

    Returns
    -------
        (u, M, gq, gdq) — u (K, n), M (K, n, n), gq (K, n), gdq (K, n) — plus w if ``return_w``.
        Equal (to rounding) to inverse_dynamics, mass_matrix, id_vjp(q, q̇, q̈, w)[1:3] and
        id_vjp(..)[1] − ½ mass_quadratic_grad(q, w).

    Raises
    ------
        numpy.linalg.LinAlgError: if M is not positive definite, or singular to working precision
        (see ``mass_cholesky``), at some sample.
    """
    (qT, dqT, ddqT), K, one_d = _inputs(model, q=q, dq=dq, ddq=ddq)
    C = _consts(model)
    n = model.n
    u = np.empty((K, n))
    M = np.empty((K, n, n))
    w = np.empty((K, n))
    gq = np.empty((K, n))
    gdq = np.empty((K, n))
    if n:
        for sl in _chunks(K, MASS_CHUNK):
            P = _h_and_mass(C, qT[:, sl], dqT[:, sl], ddqT[:, sl], u[sl], M[sl])
            Lc = mass_cholesky(M[sl])
            y = np.linalg.solve(Lc, u[sl, :, None])
            ws = np.linalg.solve(np.swapaxes(Lc, 1, 2), y)[:, :, 0]
            w[sl] = ws
            wT = np.ascontiguousarray(ws.T)
            _shift_acceleration(C, P, wT)  # the same pass at acceleration q̈ − ½ w
            gq[sl], gdq[sl], _ = _vjp_rows(C, P, wT)
    res = (u, M, gq, gdq, w) if return_w else (u, M, gq, gdq)
    return tuple(_shape_out(x, one_d) for x in res)
