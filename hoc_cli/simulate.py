"""Forward simulation: the paper's Hermite collocation time integrator, and sampling a simulated motion.

The result types are in ``hoc_cli.simulation_results``, the reference (Runge-Kutta) integrator in
``hoc_cli.reference_integrator``.

Symbols
-------
T   duration [s];  N elements;  h = T / N [s];  t_p = p h the nodes
m   coefficients per node and joint: 2 (cubic: a = q, b = q̇), 3 (quintic: a, b, c = q̈)
n   joints;  K time samples;  s ∈ [0, 1] the local coordinate of an element, t = (e + s) h
u   joint torques [N·m] (forces [N] for prismatic joints), shape (K, n)
ID  inverse dynamics u = M(q) q̈ + C(q, q̇) q̇ + g(q)

The time integration algorithm (paper, "Motion Simulations")
-------------------------------------------------------------
Given x(0) = (q0, q̇0) and a torque history u(t), march element by element. In element e the
left-node coefficients L = (a_e, b_e[, c_e]) are known; the m·n right-node coefficients
R = (a_{e+1}, b_{e+1}[, c_{e+1}]) are the unknowns, fixed by the m·n motion equations

    ID(q_h(t_j), q̇_h(t_j), q̈_h(t_j)) − u(t_j) = 0,    t_j = (e + s_j) h,  j = 1 … m,

solved by Newton's method with the analytic Jacobian
∂F_j/∂R_k = (∂u/∂q)_j B0[j, k] + (∂u/∂q̇)_j B1[j, k] + M_j B2[j, k] (B_r the r-th t-derivative of
the right node's shape functions at s_j).

Unknown count (the errata ask for it): a_0 = q0 and b_0 = q̇0 are known; for quintic elements c_0
is not an unknown either, it follows from the motion equation at t = 0, c_0 = FD(q0, q̇0, u(0)).
So there are m·n·N unknowns in all (2nN cubic, 3nN quintic, not 3n(N+1)), solved N·n at a time.

Collocation points (measured, see tests/test_simulate.py and ``DEFAULT_POINTS``):
cubic with the 2 Gauss-Legendre points is 2-stage Gauss collocation, nodal order 4. Quintic with
the 2 interior and the right point of 4-point Gauss-Lobatto: C² continuity carries q̈ from the
previous element, where the right end was collocated, so the motion equation also holds at s = 0
and the element is 4-stage Lobatto IIIA collocation, nodal order 6 (symmetric: no energy drift).
Quintic with 3 Gauss points is only order 4 at the nodes (q̈ at a node is not consistent with the
motion equation), and Radau IIA points give order 4 as well.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from hoc_cli.elements import HermiteMesh, gauss_legendre
from hoc_cli.errors import NumericalError
from hoc_cli.simulation_results import HermiteSimulation, ReferenceSimulation, SimulationStatus
from hoc_cli.system import System
from hoc_cli.torque import TorqueSource
from hoc_cli.trajectory import Trajectory

POINT_KINDS = ("gauss", "lobatto", "radau")
DEFAULT_POINTS = {"cubic": "gauss", "quintic": "lobatto"}
NEWTON_XTOL = 1e-13
NEWTON_MAX_ITER = 25
#: an element whose Newton iteration fails is solved as 2, 4, … up to 2**MAX_SPLIT_DEPTH sub-elements
MAX_SPLIT_DEPTH = 5

__all__ = ["collocation_points", "collocation_residual", "sample", "simulate_hermite"]


# --------------------------------------------------------------------------- collocation points
def collocation_points(order: str, kind: str | None = None) -> np.ndarray:
    """The m local collocation coordinates s_j ∈ (0, 1] of an element, shape (m,).

    kind "gauss": m Gauss-Legendre points. "radau": m Radau IIA points (right end included).
    "lobatto": the m points of (m+1)-point Gauss-Lobatto other than s = 0 (right end included).
    ``None`` picks ``DEFAULT_POINTS[order]`` (the highest nodal order measured).
    """
    m = {"cubic": 2, "quintic": 3}.get(order)
    if m is None:
        raise ValueError(f"order must be 'cubic' or 'quintic', got {order!r}")
    kind = DEFAULT_POINTS[order] if kind is None else kind
    if kind == "gauss":
        return gauss_legendre(m)[0]
    if kind == "radau":  # zeros of P_m(x) − P_{m−1}(x) on [−1, 1] (x = 1 included), mapped to [0, 1]
        c = np.zeros(m + 1)
        c[m], c[m - 1] = 1.0, -1.0
        x = np.sort(np.real(np.polynomial.legendre.legroots(c)))
        return (x + 1.0) / 2.0
    if kind == "lobatto":  # ±1 and the zeros of P'_m on [−1, 1], mapped to [0, 1], without 0
        c = np.zeros(m + 1)
        c[m] = 1.0
        inner = np.sort(np.real(np.polynomial.legendre.legroots(np.polynomial.legendre.legder(c))))
        return np.concatenate([(inner + 1.0) / 2.0, [1.0]])
    raise ValueError(f"collocation point kind must be one of {POINT_KINDS}, got {kind!r}")


# --------------------------------------------------------------------------- Hermite integrator
@dataclass(frozen=True, eq=False)
class _Element:
    """Shape-function values at the collocation points of one element (all elements alike).

    BL, BR: (3, m, m) t-derivative r at point j of the left / right node's shape function k.
    BX: (3, 2m) the element's polynomial at s = 2 (the predictor for the next right node).
    """

    BL: np.ndarray
    BR: np.ndarray
    BX: np.ndarray

    @classmethod
    def build(cls, mesh: HermiteMesh, s: np.ndarray) -> "_Element":
        m = mesh.m
        B = np.stack([mesh.shape_values(s, r) for r in range(3)])  # (3, m, 2m)
        BX = np.stack([mesh.shape_values(np.array([2.0]), r)[0] for r in range(3)])
        return cls(BL=B[:, :, :m].copy(), BR=B[:, :, m:].copy(), BX=BX)


def collocation_residual(
    system: System, el: "_Element", left: np.ndarray, right: np.ndarray, u: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Residual of the motion equations at an element's collocation points and its Jacobian.

    left, right: node coefficients (m, n); u: torques at the m points (m, n).
    Returns F = ID(q_h, q̇_h, q̈_h) − u, shape (m, n) [N·m], and J = ∂F/∂right,
    shape (m, n, m, n) with J[j, i, k, l] = ∂F[j, i] / ∂right[k, l].
    """
    q, dq, ddq = (el.BL[r] @ left + el.BR[r] @ right for r in range(3))
    uh, du_dq, du_ddq, M = system.id_derivatives(q, dq, ddq)
    F = np.asarray(uh) - u
    J = (
        np.einsum("jil,jk->jikl", du_dq, el.BR[0])
        + np.einsum("jil,jk->jikl", du_ddq, el.BR[1])
        + np.einsum("jil,jk->jikl", M, el.BR[2])
    )
    return F, J


def simulate_hermite(
    system: System,
    q0: np.ndarray,
    dq0: np.ndarray,
    torque: TorqueSource,
    mesh: HermiteMesh,
    *,
    points: str | np.ndarray | None = None,
    xtol: float = NEWTON_XTOL,
    max_iter: int = NEWTON_MAX_ITER,
    callback: Callable[[int, int], None] | None = None,
) -> HermiteSimulation:
    """March the Hermite collocation integrator over ``mesh`` from x(0) = (q0, q̇0).

    Parameters
    ----------
    system : the mechanical system (n joints)
    q0, dq0 : (n,) initial positions [rad | m] and velocities [rad/s | m/s]
    torque : u(t), (K,) → (K, n)
    mesh : HermiteMesh (order, T, N)
    points : collocation kind ("gauss" | "lobatto" | "radau"), explicit coordinates (m,) in
        (0, 1], or None for ``DEFAULT_POINTS[order]``
    xtol : Newton stops when the step, scaled to position units (Δa, h Δb, h² Δc), is below
        xtol·(1 + |R|) (the error left is then of order step²); a step that stops shrinking
        below 1e3·xtol is accepted as the round-off floor
    max_iter : Newton iterations allowed per element (and per sub-element)
    callback : called as callback(e, N) after element e is solved (progress)

    An element whose Newton iteration fails (no decrease, too many iterations, a non-finite
    or singular step) is solved as 2, 4, … up to 2**MAX_SPLIT_DEPTH equal sub-elements; the
    result's ``subdivided`` and ``message`` say which.

    Raises
    ------
    NumericalError when an element fails even split into 2**MAX_SPLIT_DEPTH sub-elements, or
    meets a non-finite torque; the message names the element and its time interval.
    """
    started = time.perf_counter()
    m = mesh.m
    q0 = np.asarray(q0, dtype=float).reshape(-1)
    dq0 = np.asarray(dq0, dtype=float).reshape(-1)
    n = q0.size
    if dq0.size != n or system.n != n:
        raise ValueError(f"q0 {q0.shape}, dq0 {dq0.shape} and the system's {system.n} joints disagree")
    s = collocation_points(mesh.order, points) if points is None or isinstance(points, str) else np.asarray(points, float)
    if s.shape != (m,) or np.any(s <= 0) or np.any(s > 1):
        raise ValueError(f"{mesh.order} elements need {m} collocation points in (0, 1], got {s}")
    el = _Element.build(mesh if mesh.uniform else HermiteMesh(mesh.order, float(mesh.hs[0]), 1), s)

    with np.errstate(all="ignore"):  # overflow and NaN are detected and reported below, with the element
        return _march(system, q0, dq0, torque, mesh, el, s, xtol, max_iter, callback, started)


class _NewtonFailure(Exception):
    """One element's Newton iteration failed (the reason is the message); the march may subdivide."""


def _march(system, q0, dq0, torque, mesh, el, s, xtol, max_iter, callback, started) -> HermiteSimulation:
    """The element-by-element loop of ``simulate_hermite`` (arguments checked there)."""
    m, N, n = mesh.m, mesh.N, q0.size
    hs, t_nodes = mesh.hs, mesh.nodes  # element lengths and node times [s] (non-uniform meshes: N: auto plans)
    h = hs[0]
    t_col = mesh.time_of(np.repeat(np.arange(N), m), np.tile(s, N))
    U = np.asarray(torque(t_col), dtype=float).reshape(N, m, n)  # all collocation torques at once
    u0 = np.asarray(torque(np.array([0.0])), dtype=float).reshape(1, n)
    ddq0 = system.forward_dynamics(q0[None], dq0[None], u0)[0]
    if not (np.all(np.isfinite(u0)) and np.all(np.isfinite(ddq0))):
        raise NumericalError("non-finite torque or acceleration at t = 0 s (check x0 and the torque history)")
    bad = np.flatnonzero(~np.all(np.isfinite(U), axis=(1, 2)))
    if bad.size:
        raise NumericalError(_where(int(bad[0]), hs[bad[0]], "the torque history is not finite there",
                                    t_nodes[bad[0]]))

    C = np.zeros((N + 1, m, n))
    C[0, 0], C[0, 1] = q0, dq0
    if m == 3:
        C[0, 2] = ddq0
    scale = (h ** np.arange(m))[:, None]  # a, h b, h² c: all in position units
    total = worst = evaluations = 0
    split = _Splitter(system, mesh, s, torque, xtol, max_iter)
    subdivided: list[tuple[int, int]] = []
    for e in range(N):
        left = C[e]
        if not mesh.uniform and hs[e] != h:  # the element's own length: its shape functions and scales
            h, el = hs[e], _Element.build(HermiteMesh(mesh.order, float(hs[e]), 1), s)
            scale = (h ** np.arange(m))[:, None]
        if e == 0 or (not mesh.uniform and hs[e] > 2 * hs[e - 1]):  # Taylor predictor from the left node
            q, dq = left[0], left[1]
            ddq = ddq0 if e == 0 else left[2] if m == 3 else system.forward_dynamics(
                q[None], dq[None], np.asarray(torque(t_nodes[e:e + 1]), dtype=float).reshape(1, n))[0]
            guess = np.stack([q + h * dq + 0.5 * h * h * ddq, dq + h * ddq, ddq][:m])
        elif mesh.uniform:  # extrapolate the previous element's polynomial to s = 2
            guess = el.BX[:m] @ np.concatenate([C[e - 1], C[e]])
        else:  # the previous element's polynomial at t_{e+1}
            prev = HermiteMesh(mesh.order, float(hs[e - 1]), 1)
            x = np.array([1.0 + hs[e] / hs[e - 1]])
            guess = np.stack([prev.shape_values(x, r)[0] for r in range(m)]) @ np.concatenate([C[e - 1], C[e]])
        try:
            right, iterations, calls = _newton(system, el, left, guess, U[e], scale, xtol, max_iter)
        except _NewtonFailure as first:  # solve the element as 2, 4, … sub-elements
            right, iterations, calls, pieces = split.solve(left, t_nodes[e], h, e, str(first))
            subdivided.append((e, pieces))
        C[e + 1] = right
        total += iterations
        evaluations += calls
        worst = max(worst, iterations)
        if callback is not None:
            callback(e, N)
    wall = time.perf_counter() - started
    message = (f"{N} {mesh.order} elements, {total} Newton iterations (at most {worst} per element), "
               f"{evaluations} dynamics evaluations")
    if subdivided:
        message += "; Newton failed in " + ", ".join(
            f"element {e} (t = {t_nodes[e]:.6g} … {t_nodes[e + 1]:.6g} s), solved as {k} sub-elements"
            for e, k in subdivided)
    return HermiteSimulation(
        mesh=mesh, coeffs=C, points=s, status=SimulationStatus.SUCCESS, newton_iterations=total,
        max_newton_iterations=worst, evaluations=evaluations, wall_time_s=wall, message=message,
        subdivided=tuple(subdivided),
    )


class _Splitter:
    """Solves one element of length h as equal sub-elements, halving where Newton fails again.

    Each sub-element is an element of the same order and collocation points on a shorter span
    (its matrices are cached per length); its predictor is the Taylor polynomial of its left node
    (q̈ there from the forward dynamics for cubic elements, which do not carry it).
    """

    def __init__(self, system: System, mesh: HermiteMesh, s: np.ndarray, torque: TorqueSource, xtol: float,
                 max_iter: int) -> None:
        self.system, self.order, self.m, self.s = system, mesh.order, mesh.m, s
        self.torque, self.xtol, self.max_iter = torque, xtol, max_iter
        self._elements: dict[int, _Element] = {}

    def _element(self, depth: int, length: float) -> _Element:
        if depth not in self._elements:
            self._elements[depth] = _Element.build(HermiteMesh(self.order, length, 1), self.s)
        return self._elements[depth]

    def solve(self, left: np.ndarray, t0: float, h: float, e: int, why: str) -> tuple[np.ndarray, int, int, int]:
        """Right node (m, n) of element e = [t0, t0 + h], Newton steps, evaluations, sub-elements used."""
        total = calls = 0
        pieces = 2
        for depth in range(1, MAX_SPLIT_DEPTH + 1):
            pieces = 2 ** depth
            try:
                node = left
                for k in range(pieces):
                    node, its, c = self._piece(node, t0 + k * h / pieces, h / pieces, depth)
                    total, calls = total + its, calls + c
                return node, total, calls, pieces
            except _NewtonFailure as exc:
                why = str(exc)
        raise NumericalError(_where(e, h, f"{why}, even as {pieces} sub-elements", t0))

    def _piece(self, left: np.ndarray, t0: float, H: float, depth: int) -> tuple[np.ndarray, int, int]:
        el, m = self._element(depth, H), self.m
        q, dq = left[0], left[1]
        if m == 3:
            ddq = left[2]
        else:
            ddq = self.system.forward_dynamics(q[None], dq[None], self.torque(np.array([t0])))[0]
        guess = np.stack([q + H * dq + 0.5 * H * H * ddq, dq + H * ddq, ddq][:m])
        u = np.asarray(self.torque(t0 + self.s * H), dtype=float)
        scale = (H ** np.arange(m))[:, None]
        return _newton(self.system, el, left, guess, u, scale, self.xtol, self.max_iter)


def _newton(
    system: System, el: _Element, left: np.ndarray, guess: np.ndarray, u: np.ndarray, scale: np.ndarray,
    xtol: float, max_iter: int,
) -> tuple[np.ndarray, int, int]:
    """Solve one element's collocation equations for the right node (m, n).

    Newton's method with the analytic Jacobian, globalised by Deuflhard's natural monotonicity
    test (the simplified Newton correction J_k⁻¹ F(x_{k+1}) must shrink, else the step is halved;
    P. Deuflhard, "Newton Methods for Nonlinear Problems", Springer 2004, §3.3). Norms are max
    norms of (Δa, h Δb, h² Δc) [position units]. The last simplified correction is applied when
    it is below xtol·(1 + |R|) (the error left is then of order its square), so a converged
    element costs one Jacobian factorisation per Newton step plus the initial evaluation.

    Returns the right-node coefficients, Newton steps and ``id_derivatives`` calls; raises
    ``_NewtonFailure`` (the reason) when the iteration fails.
    """
    from scipy.linalg import lu_factor, lu_solve

    m, n = guess.shape

    def size(x: np.ndarray) -> float:
        return float(np.max(np.abs(x * scale)))

    def correction(lu, F: np.ndarray) -> np.ndarray:
        return lu_solve(lu, -F.reshape(m * n)).reshape(m, n)

    right = guess
    F, J = collocation_residual(system, el, left, right, u)
    calls = 1
    if not (np.all(np.isfinite(F)) and np.all(np.isfinite(J))):
        raise _NewtonFailure("non-finite residual at the predicted state (motion blew up?)")
    for it in range(1, max_iter + 1):
        lu = lu_factor(J.reshape(m * n, m * n), check_finite=False)
        if not np.all(np.isfinite(lu[0])) or np.min(np.abs(np.diag(lu[0]))) == 0.0:
            raise _NewtonFailure("singular Newton Jacobian")
        delta = correction(lu, F)
        step = size(delta)
        tol = xtol * (1.0 + size(right))
        if not np.isfinite(step):
            raise _NewtonFailure("non-finite Newton step (motion blew up?)")
        if step <= tol:
            return right + delta, it, calls
        lam = 1.0
        while True:
            trial = right + lam * delta
            F_t, J_t = collocation_residual(system, el, left, trial, u)
            calls += 1
            if np.all(np.isfinite(F_t)) and np.all(np.isfinite(J_t)):
                bar = correction(lu, F_t)
                small = size(bar)
                if small <= (1.0 - lam / 4.0) * step or lam * step <= 1e3 * tol:
                    break
            lam *= 0.5
            if lam < 2.0 ** -12:
                raise _NewtonFailure(f"Newton step rejected down to λ = {2 * lam:.2g} (no decrease)")
        right, F, J = trial, F_t, J_t
        if lam == 1.0 and (small <= tol or (small <= 1e3 * tol and small >= 0.5 * step)):
            return right + bar, it, calls  # converged (or at the round-off floor)
    raise _NewtonFailure(f"Newton did not converge in {max_iter} iterations (last step {step:.3g})")


def _where(e: int, h: float, what: str, t0: float | None = None) -> str:
    t0 = e * h if t0 is None else t0
    return (f"Hermite simulation failed in element {e} (t = {t0:.6g} … {t0 + h:.6g} s): {what}; "
            f"more elements (-N) or --integrator rk may get through")


# --------------------------------------------------------------------------- sampling, period
def sample(
    result: HermiteSimulation | ReferenceSimulation,
    system: System,
    torque: TorqueSource,
    t: np.ndarray,
    joints: tuple[str, ...],
) -> Trajectory:
    """The simulated motion at times t (K,) as a ``Trajectory``.

    q, q̇ from the result; q̈ from the Hermite polynomial (hermite) or FD(q, q̇, u) (rk); u is the
    applied torque u(t). A Hermite result keeps its mesh and coefficients.
    """
    t = np.asarray(t, dtype=float)
    u = torque(t)
    if isinstance(result, HermiteSimulation):
        q, dq, ddq = result.mesh.evaluate_all(result.coeffs, t)
        return Trajectory(joints=tuple(joints), t=t, q=q, dq=dq, ddq=ddq, u=u, mesh=result.mesh, coeffs=result.coeffs)
    q, dq = result.state(t)
    ddq = system.forward_dynamics(q, dq, u)
    return Trajectory(joints=tuple(joints), t=t, q=q, dq=dq, ddq=ddq, u=u)
