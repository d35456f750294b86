"""The discrete optimal-control problem: design vector, cost I(q_h), exact gradient, Newton matrix.

Symbols
-------
n joints; N elements; m = 2 (cubic) or 3 (quintic) coefficients per node and joint;
G Gauss points per element; K = N G quadrature samples; P = (N + 1) m n coefficients.
C (N+1, m, n) Hermite coefficients (see ``hoc_cli.elements``); its C-order flattening
gives the global coefficient index  g = p·m·n + d·n + i  (node p, derivative d, joint i).

Design-vector layout (documented once, here)
--------------------------------------------
x0 fixes a_0 = q(0), b_0 = q̇(0) (C[0, 0:2]); x1 fixes a_N, b_N (C[N, 0:2]). Every other
coefficient (for quintic elements c_0 and c_N too) is free. The design vector x holds
the free coefficients in increasing global index order: x = C.ravel()[free].

Cost
----
I(q_h) = Σ_k w_k L(q_k, q̇_k, q̈_k) over Gauss points, with u = ID(q, q̇, q̈) and
  covariant:  L = ½ uᵀ M(q)⁻¹ u        torque:  L = ½ uᵀ u.
For the covariant cost, with w = M⁻¹u:  dL = wᵀ du − ½ wᵀ dM w, so
  ∂L/∂q = (∂u/∂q)ᵀ w − ½ ∂(wᵀMw)/∂q,   ∂L/∂q̇ = (∂u/∂q̇)ᵀ w,   ∂L/∂q̈ = M w = u.
The coefficient gradient is the transpose of the element operator applied to these.

Hooks for further terms (penalties on the samples, e.g. joint limits)
--------------------------------------------------------------------
``Evaluation`` carries q, q̇, q̈, u at the K Gauss points of ``ControlProblem.op``;
``ControlProblem.gradient_from_samples`` maps per-sample partial derivatives to the design
gradient; ``hoc_cli.banded.element_blocks`` maps per-sample Hessians (``hessian_samples`` for the
cost) to element blocks, which ``positive_definite`` turns into the banded Newton matrix.
``ControlProblem.terms`` holds extra objective terms that ``evaluate`` and ``newton`` add (an
outer loop's penalties, e.g. ``hoc_cli.collision.constraint.CollisionTerms``): each has
``evaluate(C, grad) -> (value, ∂/∂C (N+1, m, n) or None)`` and ``newton_blocks(C) -> (N, 2mn, 2mn)``
(positive semi-definite element blocks), and may have ``curvature_blocks(C) -> (N, 2mn, 2mn) or None``
(the rest of its Hessian, possibly indefinite: added to the Hessian, not to the positive semi-definite
part ``positive_definite`` falls back on). ``ControlProblem.bare_cost`` is I(q_h) without them.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from hoc_cli.banded import BandedSPD, element_blocks
from hoc_cli.costs import COSTS
from hoc_cli.dynamics import mass_cholesky
from hoc_cli.elements import HermiteMesh, QuadratureOperator
from hoc_cli.errors import NumericalError
from hoc_cli.system import System

BANDED_SHIFT = 1e-12  # relative regularisation of the banded Newton matrices (``BandedSPD.assemble``)

__all__ = ["COSTS", "ControlProblem", "Evaluation", "Layout", "SampleGradients", "boundary_coefficients",
           "default_gauss_points", "minimum_jerk_guess"]


def default_gauss_points(order: str) -> int:
    """Gauss points per element: exact for the oscillator's (2·degree)-polynomial integrand, plus margin."""
    return 8 if order == "quintic" else 6


@dataclass(frozen=True, eq=False)
class Layout:
    """Which coefficients are free; packing between C (N+1, m, n) and the design vector x (P_free,)."""

    mesh: HermiteMesh
    n: int
    free: np.ndarray = field(repr=False)  # (P,) bool over the flattened C

    @classmethod
    def build(cls, mesh: HermiteMesh, n: int, free_q1: bool = False, free_dq1: bool = False,
              pinned: tuple[tuple[int, int], ...] = ()) -> "Layout":
        """x0 and x1 fixed; ``free_q1``/``free_dq1`` free the final q/q̇ (end-effector goals);
        ``pinned`` (node p, derivative d) pairs fixed too (via points at nodes).
        """
        mask = np.ones((mesh.N + 1, mesh.m, n), dtype=bool)
        mask[0, 0:2] = False
        mask[-1, 0:2] = False
        mask[-1, 0] = free_q1
        mask[-1, 1] = free_dq1
        for p, d in pinned:
            mask[p, d] = False
        return cls(mesh=mesh, n=n, free=mask.ravel())

    @property
    def size(self) -> int:
        return int(self.free.sum())

    def pack(self, C: np.ndarray) -> np.ndarray:
        """Free coefficients of C as the design vector x."""
        return np.asarray(C, float).ravel()[self.free].copy()

    def unpack(self, x: np.ndarray, C_fixed: np.ndarray) -> np.ndarray:
        """Coefficients C with the free ones from x and the fixed ones from C_fixed."""
        flat = np.array(C_fixed, dtype=np.result_type(x, C_fixed)).ravel()
        flat[self.free] = x
        return flat.reshape(self.mesh.N + 1, self.mesh.m, self.n)


def boundary_coefficients(mesh: HermiteMesh, q0, dq0, q1, dq1) -> np.ndarray:
    """C (N+1, m, n) that is zero except the boundary values a_0, b_0, a_N, b_N."""
    n = len(q0)
    C = np.zeros((mesh.N + 1, mesh.m, n))
    C[0, 0], C[0, 1], C[-1, 0], C[-1, 1] = q0, dq0, q1, dq1
    return C


def minimum_jerk_guess(mesh: HermiteMesh, q0, dq0, q1, dq1) -> np.ndarray:
    """Initial guess: per joint the quintic with q, q̇ of x0 and x1 and q̈ = 0 at both ends, interpolated.

    Returns C (N+1, m, n). For cubic elements the quintic is Hermite-interpolated at the nodes.
    """
    T = mesh.T
    q0, dq0, q1, dq1 = (np.asarray(v, float) for v in (q0, dq0, q1, dq1))
    # q(s) = Σ c_k s^k with s = t/T; conditions on q, q', q'' at s = 0 and s = 1.
    A = np.array([
        [1, 0, 0, 0, 0, 0], [0, 1, 0, 0, 0, 0], [0, 0, 2, 0, 0, 0],
        [1, 1, 1, 1, 1, 1], [0, 1, 2, 3, 4, 5], [0, 0, 2, 6, 12, 20],
    ], dtype=float)
    rhs = np.stack([q0, dq0 * T, np.zeros_like(q0), q1, dq1 * T, np.zeros_like(q0)])  # (6, n)
    coef = np.linalg.solve(A, rhs)  # (6, n)
    s = mesh.nodes / T
    powers = np.stack([s**k for k in range(6)], axis=1)  # (N+1, 6)
    d1 = np.stack([k * s ** max(k - 1, 0) for k in range(6)], axis=1) / T
    d2 = np.stack([k * (k - 1) * s ** max(k - 2, 0) for k in range(6)], axis=1) / T**2
    cols = [powers @ coef, d1 @ coef, d2 @ coef][: mesh.m]
    C = np.stack(cols, axis=1)
    C[0, 0], C[0, 1], C[-1, 0], C[-1, 1] = q0, dq0, q1, dq1
    return C


@dataclass(frozen=True, eq=False)
class Evaluation:
    """Cost and gradient at one design vector, with the samples they came from.

    x (P_free,) design vector; J the cost; grad (P_free,) its gradient (None when not asked for);
    q, dq, ddq, u (K, n): q, q̇, q̈ [rad, rad/s, rad/s²] and the torques u [N·m] at the K = N·G
    Gauss points of ``ControlProblem.op`` (element-major; weights ``op.w`` [s]); noise the rounding
    level of J (u = M q̈ + h loses ~eps·(|M q̈| + |h|) to cancellation; 0 when grad is None).
    """

    x: np.ndarray
    J: float
    grad: np.ndarray | None
    q: np.ndarray = field(repr=False)
    dq: np.ndarray = field(repr=False)
    ddq: np.ndarray = field(repr=False)
    u: np.ndarray = field(repr=False)
    noise: float = 0.0


@dataclass(frozen=True, eq=False)
class SampleGradients:
    """The integrand L and its partial derivatives at K samples (``ControlProblem.sample_gradients``).

    L (K,); gq, gdq, gddq (K, n): ∂L/∂q, ∂L/∂q̇, ∂L/∂q̈; u (K, n) torques; w (K, n) = M⁻¹u (covariant)
    or u (torque); M (K, n, n) mass matrices; Jq, Jv (K, n, n) = ∂u/∂q, ∂u/∂q̇ when asked for, else None.
    """

    L: np.ndarray
    gq: np.ndarray
    gdq: np.ndarray
    gddq: np.ndarray
    u: np.ndarray
    w: np.ndarray
    M: np.ndarray
    Jq: np.ndarray | None = None
    Jv: np.ndarray | None = None


class ControlProblem:
    """min over x of I(q_h) for a ``System`` on a Hermite mesh, with x0, x1 fixed.

    Parameters
    ----------
    system : the dynamics (``RobotSystem`` or an analytic model)
    mesh : HermiteMesh (order, T [s], N)
    q0, dq0, q1, dq1 : (n,) boundary states [rad, rad/s]
    cost : "covariant" (½ uᵀM⁻¹u) or "torque" (½ uᵀu)
    G : Gauss points per element (default ``default_gauss_points``)
    layout : which coefficients are free (default ``Layout.build``: all but x0 and x1); a fixed
        coefficient takes its value from ``C_fixed`` (x0, x1 here; goals may set more)
    """

    def __init__(self, system: System, mesh: HermiteMesh, q0, dq0, q1, dq1, cost: str = "covariant",
                 G: int | None = None, layout: Layout | None = None) -> None:
        if cost not in COSTS:
            raise ValueError(f"cost must be one of {COSTS}, got {cost!r}")
        self.system, self.mesh, self.cost = system, mesh, cost
        self.n = system.n
        self.G = G or default_gauss_points(mesh.order)
        self.op: QuadratureOperator = mesh.quadrature(self.G)
        self.op_h: QuadratureOperator = mesh.quadrature(min(self.G, mesh.m + 3))
        self.layout = Layout.build(mesh, self.n) if layout is None else layout
        self.C_fixed = boundary_coefficients(mesh, q0, dq0, q1, dq1)
        self.boundary = tuple(np.asarray(v, float) for v in (q0, dq0, q1, dq1))
        self.n_evals = 0
        self.terms: tuple = ()  # extra objective terms (module docstring, "Hooks"); set by an outer loop
        self.last: Evaluation | None = None
        self._kept_hessians: tuple | None = None  # (ev, element blocks, per-sample PSD parts): ``_element_hessians``
        self._bare_last: tuple | None = None  # (x, op, I(q_h)) of the last evaluation (``bare_cost``)
        self._cost_last: tuple | None = None  # (x, op, I(q_h), its gradient, noise, q, q̇, q̈, u): the last with gradient
        self._carried: np.ndarray | None = None  # x where the kept Hessian serves the next Newton matrix (``carry_hessian``)

    # -- design vector ---------------------------------------------------------------------------------
    def initial_guess(self) -> np.ndarray:
        return self.layout.pack(minimum_jerk_guess(self.mesh, *self.boundary))

    def coefficients(self, x: np.ndarray) -> np.ndarray:
        return self.layout.unpack(x, self.C_fixed)

    # -- cost and gradient -----------------------------------------------------------------------------
    def sample_gradients(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray,
                         jacobians: bool = True) -> SampleGradients:
        """Per-sample L and its partial derivatives ∂L/∂q, ∂L/∂q̇, ∂L/∂q̈ at samples q, dq, ddq (K, n).

        With ``jacobians`` the gradient is built from the full ∂u/∂q and ∂u/∂q̇ (K, n, n), returned
        too; without, from a cheaper vector-Jacobian product (RNEA reverse sweep), and Jq = Jv = None.
        """
        if not jacobians and self.cost == "covariant":  # the fused reverse sweep
            try:
                u, M, gq, gdq, w = self.system.covariant_gradient_terms(q, dq, ddq)
            except np.linalg.LinAlgError:
                raise NumericalError("the mass matrix is singular or not positive definite along the trajectory") from None
            L = 0.5 * np.einsum("ki,ki->k", u, w)
            return SampleGradients(L=L, gq=gq, gdq=gdq, gddq=u, u=u, w=w, M=M)
        if jacobians:
            u, Jq, Jv, M = self.system.id_derivatives(q, dq, ddq)
        else:
            u, M = self.system.inverse_dynamics(q, dq, ddq), self.system.mass_matrix(q)
            Jq = Jv = None
        w = _spd_solve(M, u) if self.cost == "covariant" else u
        if jacobians:
            gq = np.einsum("kij,ki->kj", Jq, w)
            gdq = np.einsum("kij,ki->kj", Jv, w)
        else:
            _, gq, gdq, _ = self.system.id_vjp(q, dq, ddq, w)
        if self.cost == "covariant":
            gq = gq - 0.5 * self.system.mass_quadratic_grad(q, w)
            gddq = u
        else:
            gddq = np.einsum("kij,ki->kj", M, w)
        L = 0.5 * np.einsum("ki,ki->k", u, w)
        return SampleGradients(L=L, gq=gq, gdq=gdq, gddq=gddq, u=u, w=w, M=M, Jq=Jq, Jv=Jv)

    def evaluate(self, x: np.ndarray, grad: bool = True, keep_gradient: bool = False) -> Evaluation:
        """I(q_h) [(N·m)²·s / (kg·m²) covariant, (N·m)²·s torque] and its gradient with respect to x.

        I(q_h) and its gradient at the last x evaluated with it are kept: an evaluation with gradient at that x
        again (the next inner solve starting where the last one ended) evaluates only the ``terms``.
        ``keep_gradient`` (without ``grad``): I(q_h)'s gradient is made and kept too, for such a next evaluation,
        while the evaluation returned is the one without gradient (the terms' values alone).
        """
        self.n_evals += 1
        C = self.coefficients(x)
        kept = self._cost_last if grad else None
        if kept is not None and kept[1] is self.op and np.array_equal(kept[0], x):
            J, g, noise, q, dq, ddq, u = kept[2:]  # I(q_h) and its gradient at this x: only the terms change
            return self._with_terms(C, x, J, g.copy(), noise, q, dq, ddq, u)
        q, dq, ddq = self.op.apply(C)
        wt = self.op.w
        if not grad and keep_gradient:
            J, g, noise, u = self._cost_gradient(q, dq, ddq)
            self._cost_last = (np.array(x), self.op, J, g, noise, q, dq, ddq, u)
            self._bare_last = (self._cost_last[0], self.op, J)
            if self.terms:
                J += sum(term.evaluate(C, grad=False)[0] for term in self.terms)
            return Evaluation(x=x, J=J, grad=None, q=q, dq=dq, ddq=ddq, u=u)
        if not grad:
            if self.cost == "covariant":
                u, M = self.system.id_and_mass(q, dq, ddq)
                w = _spd_solve(M, u)
            else:
                u = w = self.system.inverse_dynamics(q, dq, ddq)
            J = 0.5 * float(np.dot(wt, np.einsum("ki,ki->k", u, w)))
            if not np.isfinite(J):
                raise NumericalError("the cost is not finite (NaN or inf) along the trajectory")
            self._bare_last = (np.array(x), self.op, J)
            if self.terms:
                J += sum(term.evaluate(C, grad=False)[0] for term in self.terms)
            return Evaluation(x=x, J=J, grad=None, q=q, dq=dq, ddq=ddq, u=u)
        J, g, noise, u = self._cost_gradient(q, dq, ddq)
        self._cost_last = (np.array(x), self.op, J, g.copy(), noise, q, dq, ddq, u)
        self._bare_last = (self._cost_last[0], self.op, J)  # the same number as the evaluation without gradient
        return self._with_terms(C, x, J, g, noise, q, dq, ddq, u)

    def _with_terms(self, C: np.ndarray, x: np.ndarray, J: float, g: np.ndarray, noise: float, q: np.ndarray,
                    dq: np.ndarray, ddq: np.ndarray, u: np.ndarray) -> Evaluation:
        """The evaluation at x (coefficients C) from I(q_h) = J and its gradient g, the ``terms`` added; kept as ``last``."""
        for term in self.terms:
            value, gC = term.evaluate(C, grad=True)
            J, g = J + value, g + self.layout.pack(gC)
        ev = Evaluation(x=x, J=J, grad=g, q=q, dq=dq, ddq=ddq, u=u, noise=noise)
        self.last = ev
        return ev

    def _cost_gradient(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> tuple[float, np.ndarray, float, np.ndarray]:
        """(I(q_h), its gradient (P_free,), the rounding noise of I, u (K, n)) at the samples q, q̇, q̈ (K, n) of ``op``."""
        wt = self.op.w
        s = self.sample_gradients(q, dq, ddq, jacobians=False)
        J = float(np.dot(wt, s.L))
        if not np.isfinite(J):
            raise NumericalError("the cost is not finite (NaN or inf) along the trajectory")
        W = wt[:, None]
        g = self.gradient_from_samples(W * s.gq, W * s.gdq, W * s.gddq)
        M, u, w = s.M, s.u, s.w
        Mddq = np.einsum("kij,kj->ki", M, ddq)
        size = np.abs(Mddq) + np.abs(u - Mddq)
        noise = 64 * np.finfo(float).eps * float(np.dot(wt, np.einsum("ki,ki->k", np.abs(w), size)))
        return J, g, noise, u

    def gradient_from_samples(self, gq: np.ndarray, gdq: np.ndarray, gddq: np.ndarray) -> np.ndarray:
        """The design gradient (P_free,) of Σ_k φ_k(q_k, q̇_k, q̈_k) over the samples of ``self.op``.

        gq, gdq, gddq (K, n) are ∂φ_k/∂q_k, ∂φ_k/∂q̇_k, ∂φ_k/∂q̈_k, with any quadrature weights
        already applied (for the cost: w_k ∂L/∂q_k, …).
        """
        return self.layout.pack(self.op.transpose(gq, gdq, gddq))

    def value(self, x: np.ndarray) -> float:
        """The objective (I(q_h) plus ``terms``) alone (no gradient)."""
        return self.evaluate(x, grad=False).J

    def bare_cost(self, x: np.ndarray) -> float:
        """I(q_h) without ``terms`` (kept from the last evaluation without gradient when that was at x: a limits'
        measure after a polish step prices the point the polish has just evaluated).
        """
        last = self._bare_last
        if last is not None and last[1] is self.op and np.array_equal(x, last[0]):
            return last[2]
        terms, self.terms = self.terms, ()
        try:
            return self.evaluate(x, grad=False).J
        finally:
            self.terms = terms

    # -- Newton matrix -------------------------------------------------------------------------------
    # It is assembled on its own, coarser quadrature (``self.op_h``, G_h = m + 3 points per
    # element: exact for the degree-(2·5) polynomial part of a quintic element's integrand). It
    # only preconditions and estimates the decrement; the cost and gradient keep the full quadrature.
    def _preconditioner_samples(self, ev: Evaluation) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.op_h.apply(self.coefficients(ev.x))

    def sample_hessians(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, rel_step: float = 1e-8) -> np.ndarray:
        """Per-sample Hessian of L in (q, q̇, q̈), shape (K, 3n, 3n), at samples (K, n) ×3.

        See ``_sweep_sample_hessians`` (both costs). Forward differences with relative step 1e-8:
        error typically ~6e-8 relative to the largest entry, up to ~2e-6 (measured over 200 random
        states of the shipped robots).
        """
        return self._sweep_sample_hessians(q, dq, ddq, rel_step)[0]

    def _sweep_sample_hessians(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray,
                               rel_step: float = 1e-8, known: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Hessian of L per sample, (K, 3n, 3n), and its positive semi-definite part Dᵀ S D (K, 3n, 3n).

        Both costs are L(x) = max_w Φ(x, w), x = (q, q̇, q̈), with Φ = wᵀu(x) − ½ wᵀ S⁻¹ w:
        S = M⁻¹ (covariant) gives Φ = wᵀ ID(q, q̇, q̈ − ½w), since ID is affine in q̈; S = I (torque)
        gives Φ = wᵀ ID(q, q̇, q̈) − ½ wᵀw. The maximiser is w = S u, and by the envelope theorem

            ∇²L = Φ_xx + Dᵀ S D,   D = Φ_wx = [∂u/∂q − B, ∂u/∂q̇, M] (covariant; torque: ∂u/∂q),

        with B = ∂(M(q) w)/∂q, where Φ_xx is taken at fixed w: its q- and q̇-columns are those of
        the vector-Jacobian product wᵀ∂ID/∂(q, q̇), its q̈-rows are B (Φ is linear in q̈) and its q̈q̈
        block is zero (for both costs). Everything but M and u (needed first, for w) comes from ONE
        batched call: the vector-Jacobian product of
        ID with λ = w at the acceleration a = q̈ − ½w (covariant) or q̈ (torque), at the sample and
        at its 2n forward-perturbed copies (q_j, then q̇_j, relative step ``rel_step``). Its four
        outputs, differenced, give Φ_xx (from λᵀ∂u/∂q, λᵀ∂u/∂q̇), B (from λᵀ∂u/∂q̈ = M w), ∂u/∂q̇
        and ∂ID(q, q̇, a)/∂q = ∂u/∂q − ½B (covariant) or ∂u/∂q (torque), from the torques. ``known``: (M, u) at these
        samples when already computed (an evaluation's ``SampleGradients``: the same numbers), else computed here
        in one Newton-Euler pass (``System.id_and_mass``).
        """
        K, n = q.shape
        u, M = (known[1], known[0]) if known is not None else self.system.id_and_mass(q, dq, ddq)
        covariant = self.cost == "covariant"
        if covariant:
            Li = _inverse_cholesky(M)  # S = M⁻¹ = Liᵀ Li
            w = _apply_inverse(Li, u[..., None])[..., 0]
            acc = ddq - 0.5 * w
        else:
            w, acc = u, ddq
        eps_q = rel_step * (1.0 + np.abs(q))
        eps_v = rel_step * (1.0 + np.abs(dq))
        E = np.eye(n)
        Qb = np.concatenate([q[None] + E[:, None, :] * eps_q[None], np.broadcast_to(q, (n, K, n)), q[None]])
        Vb = np.concatenate([np.broadcast_to(dq, (n, K, n)), dq[None] + E[:, None, :] * eps_v[None], dq[None]])
        copies = 2 * n + 1
        out = self.system.id_vjp(Qb.reshape(-1, n), Vb.reshape(-1, n),
                                 np.broadcast_to(acc, (copies, K, n)).reshape(-1, n),
                                 np.broadcast_to(w, (copies, K, n)).reshape(-1, n))
        # Z[c, k] = (ID(·, ·, a), λᵀ∂u/∂q, λᵀ∂u/∂q̇, M w) at copy c; columns by forward differences
        Z = np.concatenate(out, axis=1).reshape(copies, K, 4 * n)
        dZq = np.transpose((Z[:n] - Z[-1]) / eps_q.T[:, :, None], (1, 2, 0))  # (K, 4n, n)
        dZv = np.transpose((Z[n:2 * n] - Z[-1]) / eps_v.T[:, :, None], (1, 2, 0))
        B = dZq[:, 3 * n:]
        H = np.zeros((K, 3 * n, 3 * n))
        H[:, :n, :n] = dZq[:, n:2 * n]
        H[:, n:2 * n, :n] = dZq[:, 2 * n:3 * n]
        H[:, :n, n:2 * n] = dZv[:, n:2 * n]
        H[:, n:2 * n, n:2 * n] = dZv[:, 2 * n:3 * n]
        H[:, 2 * n:, :n] = B
        H[:, :n, 2 * n:] = np.swapaxes(B, 1, 2)
        Jq = dZq[:, :n] - 0.5 * B if covariant else dZq[:, :n]
        D = np.concatenate([Jq, dZv[:, :n], M], axis=2)  # (K, n, 3n)
        Y = np.matmul(Li, D) if covariant else D  # Dᵀ S D = Yᵀ Y
        GN = np.matmul(np.swapaxes(Y, 1, 2), Y)
        H += GN
        return 0.5 * (H + np.swapaxes(H, 1, 2)), GN

    def newton(self, ev: Evaluation, extra: np.ndarray | None = None, shift: float = BANDED_SHIFT) -> BandedSPD:
        """The Hessian of I on the free coefficients (block-banded), made positive definite.

        Element blocks of the per-sample Hessians (``hessian_samples``) through ``positive_definite``;
        the blocks of the positive semi-definite part are only formed when needed. ``extra``
        (N, 2mn, 2mn): positive semi-definite element blocks of other terms (limit penalties),
        added to both; the ``terms``' ``curvature_blocks`` (if any) to the Hessian only.
        """
        Hb, GNs = self._element_hessians(ev)
        if self.terms:
            C = self.coefficients(ev.x)
            more = sum(term.newton_blocks(C) for term in self.terms)
            extra = more if extra is None else extra + more
            for term in self.terms:
                curvature = term.curvature_blocks(C) if hasattr(term, "curvature_blocks") else None
                if curvature is not None:
                    Hb = Hb + curvature
        if extra is None:
            return self.positive_definite(Hb, lambda: element_blocks(self.op_h, GNs), shift)
        return self.positive_definite(Hb + extra, lambda: element_blocks(self.op_h, GNs) + extra, shift)

    def _element_hessians(self, ev: Evaluation) -> tuple[np.ndarray, np.ndarray]:
        """(element blocks (N, 2mn, 2mn) of the per-sample Hessians, the per-sample positive semi-definite parts)
        at ev; those of the last ev are kept, so a second Newton matrix at the same point (other ``extra``
        terms, another shift) costs no second Hessian sweep.
        """
        kept, carried = self._kept_hessians, self._carried
        if kept is not None and kept[0] is ev:
            return kept[1], kept[2]
        self._carried = None
        if kept is not None and carried is not None and np.array_equal(ev.x, carried):
            self._kept_hessians = (ev, kept[1], kept[2])
            return kept[1], kept[2]
        Hs, GNs = self.hessian_samples(ev)
        self._kept_hessians = (ev, element_blocks(self.op_h, Hs), GNs)
        return self._kept_hessians[1], GNs

    def carry_hessian(self, x: np.ndarray) -> None:
        """Let the cost's Hessian of the last Newton matrix serve the next one too when that is at x (its terms' blocks
        are made afresh): for a step too small to change it to the Newton matrix's use (the collision loop's final
        limit rounds, after a polish step). Nothing when no Hessian is kept.
        """
        self._carried = None if self._kept_hessians is None else np.array(x)

    def hessian_samples(self, ev: Evaluation, samples: SampleGradients | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Per-sample Hessian of L and its positive semi-definite part, each (K_h, 3n, 3n), at ev.x.

        On the preconditioner quadrature ``self.op_h`` (K_h = N·G_h samples): feed them to
        ``element_blocks(self.op_h, ·)``. The second is Dᵀ S D (see ``_sweep_sample_hessians``; for
        the torque cost the Gauss-Newton matrix), from the same dynamics pass. ``samples``: the ``SampleGradients``
        of ev's own samples (q, q̇, q̈ = ev's), whose torques and mass matrices are used when ``op_h`` is ``op``.
        """
        if samples is not None and self.op_h is self.op and samples.M is not None:
            return self._sweep_sample_hessians(ev.q, ev.dq, ev.ddq, known=(samples.M, samples.u))
        return self._sweep_sample_hessians(*self._preconditioner_samples(ev))

    def positive_definite(self, H: np.ndarray, psd: Callable[[], np.ndarray], shift: float = BANDED_SHIFT) -> BandedSPD:
        """The banded matrix of element blocks H (N, 2mn, 2mn), made positive definite.

        Away from a minimum the Hessian may be indefinite; then μ·GN is added, with GN = ``psd()``
        the element blocks of a positive semi-definite part of H (called only then), and
        μ = 1e-3, 1e-2, … (relative to the traces) until the banded Cholesky factorisation
        succeeds; GN alone last.
        """
        try:
            return self.banded(H, shift)
        except NumericalError:
            from hoc_cli.optimize.modify import gauss_newton_shift

            GN = psd()
            _, factored = gauss_newton_shift(H, GN, lambda M: self.banded(M, shift))
            return factored if factored is not None else self.banded(GN, shift)

    def banded(self, blocks: np.ndarray, shift: float = BANDED_SHIFT) -> BandedSPD:
        """Element blocks (N, 2mn, 2mn) summed, restricted to the free coefficients and factored
        (``shift``: the relative regularisation of ``BandedSPD.assemble``).
        """
        mn = self.mesh.m * self.n
        return BandedSPD.assemble(blocks, stride=mn, size=(self.mesh.N + 1) * mn, free=self.layout.free, shift=shift)


def _inverse_cholesky(M: np.ndarray) -> np.ndarray:
    """L⁻¹ (K, n, n) of the Cholesky factors of SPD matrices M (K, n, n), so M⁻¹ = L⁻ᵀ L⁻¹.

    One batched inverse of small triangular matrices: much cheaper than batched multi-right-hand-side
    solves at this size, and accurate enough for Newton matrices (which only precondition).
    """
    try:
        return np.linalg.inv(mass_cholesky(M))
    except np.linalg.LinAlgError:
        raise NumericalError("the mass matrix is singular or not positive definite along the trajectory") from None


def _apply_inverse(Li: np.ndarray, R: np.ndarray) -> np.ndarray:
    """M⁻¹ R = L⁻ᵀ (L⁻¹ R) for R (K, n, r)."""
    return np.matmul(np.swapaxes(Li, 1, 2), np.matmul(Li, R))


def _spd_solve(M: np.ndarray, u: np.ndarray) -> np.ndarray:
    """W = M⁻¹ u for a batch of SPD matrices (K, n, n) and vectors (K, n), via Cholesky."""
    try:
        Lc = mass_cholesky(M)
    except np.linalg.LinAlgError:
        raise NumericalError("the mass matrix is singular or not positive definite along the trajectory") from None
    y = np.linalg.solve(Lc, u[..., None])
    return np.linalg.solve(np.swapaxes(Lc, -1, -2), y)[..., 0]
