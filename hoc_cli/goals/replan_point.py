"""The Lagrangian of a warm replan at one (x, T): values, gradients and the rows, for its Newton steps.

ℒ = I + Φ_limits + λ·c + weight·T: I the cost on the previous plan's quadrature, Φ the limits'
augmented-Lagrangian terms at fixed multipliers (or none), c the goal rows and, when given, a set of
kinematic limit rows held with multipliers (``ActiveRows``). x are the free Hermite coefficients in the
s = t/T domain. Pure maths: no I/O.
"""
from __future__ import annotations

import copy
import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.linalg import cho_solve_banded

from hoc_cli.constraints.augmented_lagrangian import MARGIN
from hoc_cli.constraints.bounds import KINEMATIC
from hoc_cli.constraints.penalty import LimitRows, LimitTerms, effective_bounds
from hoc_cli.constraints.prolong import Duals
from hoc_cli.elements import HermiteMesh, QuadratureOperator
from hoc_cli.errors import NumericalError
from hoc_cli.free_time import (
    cost_time_column,
    fixed_coefficient_correction,
    fixed_coefficient_motion,
    limits_time_derivative,
    row_time_derivatives,
)
from hoc_cli.goals.active_limits import ActiveRows
from hoc_cli.goals.mesh import scaled_mesh
from hoc_cli.goals.plan import GoalProblem
from hoc_cli.goals.terms import GoalTerms, point_set
from hoc_cli.problem import Evaluation

VIOLATION_FLOOR = 1e-3  # a step may raise the goal rows' violation up to this (m, rad, m/s): T moves them nonlinearly


@dataclass(eq=False)
class LagrangianPoint:
    """The Lagrangian at (x, T): the problem, x, C, J, its gradient g (P,), the goal rows c (r,), D (r, P),
    F = ∂ℒ/∂T + weight at fixed s-domain free coefficients (F_I: of the cost and weight alone), the limit
    terms and their value, the limit rows of the mesh, the goal residuals.
    """

    problem: GoalProblem
    x: np.ndarray
    C: np.ndarray
    J: float
    ev: object
    g: np.ndarray
    c: np.ndarray
    D: np.ndarray
    F: float
    lt: object
    pv: object
    rows: object
    res: list | None
    F_I: float = 0.0
    where: object = None
    samples: object = None  # the cost's ``SampleGradients`` at ev's samples
    held: np.ndarray | None = None  # A_full (a, P) of the working set's rows (``ActiveRows.jacobian``), when given
    curvature_samples: list | None = None  # the goal rows' derivatives at the Newton blocks' perturbed points
    # (``GoalTerms.residuals_with_samples``), when evaluated with the derivatives


def point_problem(system, order, N, T, q0, dq0, goals, cost, G, limits, cache: dict, fractions=None) -> tuple:
    """(problem, limit rows, the goal points' ``PointSet``) of ``evaluate_point`` at T, kept in ``cache``: built for
    the first T, rescaled from it for the others (``problem_on``, ``rows_on``).
    """
    if T not in cache:
        mesh = scaled_mesh(order, T, N, fractions)
        other = next(iter(cache.values()), None)  # the same problem at another T: its parts rescaled
        problem = problem_on(other[0], mesh) if other is not None else None
        if problem is None:
            problem = GoalProblem(system, mesh, q0, dq0, goals, cost=cost, G=G)
            problem.op_h = problem.op  # the Newton matrix on the cost's own quadrature: the exact Hessian
        rows = None
        if limits is not None:
            rows = rows_on(other[1], mesh) if other is not None else None
            rows = limit_rows(mesh, problem.layout.free, limits.n) if rows is None else rows
        cache[T] = (problem, rows, point_set(mesh, problem.points) if problem.points else None)
    return cache[T]


def goal_violation(system, order, N, T, C, q0, dq0, goals, cost, G, limits, cache: dict, fractions=None,
                   slope: bool = False) -> float:
    """The largest |c| over the goal rows at coefficients C on [0, T] (0 without rows): ``evaluate_point``'s goal rows alone,
    the same numbers (its problem from the same ``cache``), without the dynamics (``goal_values``, ``slope`` as there).
    """
    c = goal_values(system, order, N, T, C, q0, dq0, goals, cost, G, limits, cache, fractions, slope)[2]
    return float(np.max(np.abs(c), initial=0.0))


def goal_values(system, order, N, T, C, q0, dq0, goals, cost, G, limits, cache: dict, fractions=None,
                slope: bool = False) -> tuple:
    """(the mesh's limit rows at T, C (N+1, m, n) with the fixed coefficients set, the goal rows c (r,)) at coefficients
    C on [0, T]: ``evaluate_point``'s numbers (its problem from the same ``cache``) without the dynamics and the rows'
    Jacobian. The rows' pass (with the samples of their curvature and, ``slope``: a free T, of their T column) is kept
    on the problem: the point's evaluation, when it follows, reuses it.
    """
    problem, rows, where = point_problem(system, order, N, T, q0, dq0, goals, cost, G, limits, cache, fractions)
    x = problem.layout.pack(C)
    C = problem.coefficients(x)
    if not problem.points:
        return rows, C, np.zeros(0)
    res = _goal_rows_kept(problem, x)
    if res is None:  # with the samples of the rows' curvature: the same pass, kept for the point's evaluation
        lam = [np.zeros(p.residual.size) for p in problem.points]
        V1 = fixed_coefficient_motion(problem.layout.free, C, T)[0] if slope else None
        res = GoalTerms(problem.mesh, problem.points, lam, 0.0, where).residuals_with_samples(C, V1)
        problem._rows_kept = (problem.op, np.array(x), res)
    return rows, C, np.concatenate([r[0] for r in res[0]])


def _goal_rows_kept(problem, x: np.ndarray) -> tuple | None:
    """The goal rows (``GoalTerms.residuals_with_samples``) that ``goal_values`` kept on ``problem`` at x, or None."""
    kept = getattr(problem, "_rows_kept", None)
    return kept[2] if kept is not None and kept[0] is problem.op and np.array_equal(kept[1], x) else None


def evaluate_point(system, order, N, T, C, q0, dq0, goals, cost, G, lam, limits, limit_state, weight, slope,
                   cache: dict, active: ActiveRows | None = None, fractions=None, derivatives: bool = True,
                   value: bool = True) -> LagrangianPoint:
    """Evaluate the Lagrangian ℒ = I + Φ_limits + λ·c and its derivatives at coefficients C on [0, T]: one
    dynamics sweep for I, ∇I and ∂I/∂T, one forward kinematics of the goal rows, one limits evaluation.
    ``cache`` keeps the problem and limit rows of each T (they depend on the mesh only); ``fractions``: the
    mesh's nodes as fractions of T (None: N equal elements). ``derivatives`` False (no limit terms): J, the rows
    c and their Jacobian D only, the cost by inverse dynamics alone (``GoalProblem.value``'s numbers); g, ``samples``
    and ``ev``'s gradient None, F and F_I NaN (a point where no step starts: a real-time update's last); ``value``
    False too: no dynamics at all, J NaN and ``ev`` None, c and D the goal rows' alone (a point whose cost is read
    later, if ever). The dynamics and goal rows of the last point evaluated with derivatives are kept on its problem:
    the same x again (the next replan's first point, on the same ``cache``) reuses them.
    """
    if not derivatives:
        return _point_values(system, order, N, T, C, q0, dq0, goals, cost, G, lam, limits, cache, active, fractions,
                             value)
    problem, rows, where = point_problem(system, order, N, T, q0, dq0, goals, cost, G, limits, cache, fractions)
    mesh = problem.mesh
    lt = pv = None
    npts = len(problem.points)
    if limit_state is not None and active is None:
        working, mu_lo, mu_hi, rho_l = limit_state
        lt = LimitTerms(system, limits, rows, working, mu_lo, mu_hi, rho_l, MARGIN)
        lt = None if lt.empty else lt
    x = problem.layout.pack(C)
    C = problem.coefficients(x)
    op = problem.op
    kept = getattr(problem, "_point_kept", None)  # the last point's dynamics and goal rows on this problem
    if kept is not None and kept[0] is op and np.array_equal(kept[1], x):
        q, dq, ddq, s, J, rows_kept = kept[2:]
    else:
        q, dq, ddq = op.apply(C)
        s = problem.sample_gradients(q, dq, ddq, jacobians=False)
        J, rows_kept = float(np.dot(op.w, s.L)), _goal_rows_kept(problem, x)
        if not np.isfinite(J):
            raise NumericalError("the cost is not finite (NaN or inf) along the trajectory")
    Wt = op.w[:, None]
    Gc = op.transpose(Wt * s.gq, Wt * s.gdq, Wt * s.gddq)  # ∂I/∂C (N+1, m, n)
    dT = float(np.dot(op.w, s.L - np.einsum("ki,ki->k", s.gdq, dq) - 2 * np.einsum("ki,ki->k", s.gddq, ddq))) / T
    F_I = dT + fixed_coefficient_correction(problem.layout.free, C, Gc, T) + weight if slope else 0.0
    G_all = Gc
    value = J
    if lt is not None:
        pv = lt.evaluate(C)
        G_all = G_all + pv.grad
        value += pv.value
        if slope:
            dl, Gl = limits_time_derivative(Duals(rows, pv.mu_lo, pv.mu_hi), system, limits, C)
            dT, Gc = dT + dl, Gc + Gl
    c, D = np.zeros(0), np.zeros((0, x.size))
    res = samples = None
    if problem.points:
        terms = GoalTerms(mesh, problem.points, lam[:npts], 0.0, where)
        # and those of the goal rows' curvature (with a free T: and of their T column), in the same pass
        if rows_kept is None:
            rows_kept = terms.residuals_with_samples(C, fixed_coefficient_motion(problem.layout.free, C, T)[0]
                                                     if slope else None)
        res, samples = rows_kept
        rows_kept = res, samples
        c, dc = terms.jacobian(C, res)
        D = dc.reshape(len(c), -1)[:, problem.layout.free]
        if slope:
            dg, Gg = terms.time_derivative(C, T, res)
            dT, Gc = dT + dg, Gc + Gg
    A_full = None
    if active is not None:  # the working set's limit rows, linear equalities g = A x + const
        A, A_full = active.jacobian(rows, limits, problem.layout.free)
        c = np.concatenate([c, A_full @ C.ravel() + active.offsets(limits)])
        D = np.vstack([D, A])
        if slope and active.size:  # g = A_full·C + offsets; a row of d^k q/dt^k scales as T^-k at fixed s-domain C
            mu = np.asarray(lam[npts], float)
            values = A_full @ C.ravel()
            dT = dT - float(np.dot(mu * active.kind, values)) / T
            Gc = Gc + (mu @ A_full).reshape(C.shape)
    problem._point_kept = (op, np.array(x), q, dq, ddq, s, J, rows_kept)
    g = problem.layout.pack(G_all)
    if D.size:
        g = g + D.T @ np.concatenate(lam)
    F = dT + fixed_coefficient_correction(problem.layout.free, C, Gc, T) + weight if slope else 0.0
    ev = Evaluation(x=x, J=value, grad=g, q=q, dq=dq, ddq=ddq, u=s.u)
    return LagrangianPoint(problem, x, C, J, ev, g, c, D, F, lt, pv, rows, res, F_I, where, s, A_full, samples)


def _point_values(system, order, N, T, C, q0, dq0, goals, cost, G, lam, limits, cache: dict, active, fractions,
                  value: bool = True):
    """``evaluate_point`` without derivatives (its ``derivatives`` False): J, c, D at (T, C) (``value`` False: J NaN, the
    goal rows alone).
    """
    problem, rows, where = point_problem(system, order, N, T, q0, dq0, goals, cost, G, limits, cache, fractions)
    x = problem.layout.pack(C)
    C = problem.coefficients(x)
    ev = problem.evaluate(x, grad=False) if value else None
    c, D, res = np.zeros(0), np.zeros((0, x.size)), None
    npts = len(problem.points)
    if problem.points:
        terms = GoalTerms(problem.mesh, problem.points, lam[:npts], 0.0, where)
        res = terms.residuals(C)
        c, dc = terms.jacobian(C, res)
        D = dc.reshape(len(c), -1)[:, problem.layout.free]
    A_full = None
    if active is not None and value:  # (without the value: the goal rows alone)
        A, A_full = active.jacobian(rows, limits, problem.layout.free)
        c = np.concatenate([c, A_full @ C.ravel() + active.offsets(limits)])
        D = np.vstack([D, A])
    return LagrangianPoint(problem, x, C, ev.J if ev is not None else math.nan, ev, None, c, D, math.nan, None, None, rows,
                           res, math.nan, where, None, A_full)


@dataclass(frozen=True, eq=False)
class TimeColumn:
    """The T row and column of the Hessian of ℒ in (x, T) at a ``LagrangianPoint`` and the rows' T columns, along the
    rescaled family (fixed s-domain free coefficients): b = ∂∇ℒ/∂T (P,), h = ∂²ℒ/∂T² (the T derivative of F), the goal
    rows' c_T (r,) and the working set's rows' (a,); b None and h NaN when only the rows' columns were asked for.
    """

    b: np.ndarray | None
    h: float
    c_T: np.ndarray
    held_T: np.ndarray


def time_column(pt: LagrangianPoint, lam: list, active: ActiveRows | None, Hs: np.ndarray | None) -> TimeColumn:
    """The exact ``TimeColumn`` of ℒ = I + λ·c + μ·g_A (+ weight·T) at ``pt`` (``evaluate_point`` with ``lam``,
    ``active`` and no limit terms), from Hs (K, 3n, 3n), the cost's per-sample Hessians at pt's samples
    (``problem.hessian_samples(pt.ev)``: ``op_h`` is ``op`` here): the cost's part by ``free_time.cost_time_column``,
    the goal rows' by ``GoalTerms.time_column``, the working set's rows (linear in x, T^−k along the family) by
    ``free_time.row_time_derivatives``: b gains −Aᵀ(μ·k)/T, h gains Σ μ g''. Hs None (or the Newton matrix on another
    quadrature than the cost's): the rows' columns alone.
    """
    problem = pt.problem
    if problem.op_h is not problem.op:
        Hs = None
    T, free = problem.mesh.T, problem.layout.free
    V1, V2 = fixed_coefficient_motion(free, pt.C, T)
    column, h = None, math.nan
    if Hs is not None:
        column, h = cost_time_column(problem.op, T, (pt.ev.q, pt.ev.dq, pt.ev.ddq), pt.samples, Hs, V1, V2)
    npts = len(problem.points)
    c_T = np.zeros(0)
    if problem.points:
        terms = GoalTerms(problem.mesh, problem.points, lam[:npts], 0.0, pt.where)
        if Hs is None:
            c_T = terms.time_slopes(pt.C, T, V1, pt.res)
        else:
            c_T, goal_column, goal_h = terms.time_column(pt.C, T, V1, V2, pt.res, samples=pt.curvature_samples)
            column, h = column + goal_column, h + goal_h
    b = None if column is None else problem.layout.pack(column)
    held_T = np.zeros(0)
    if active is not None and active.size:
        A_full, mu = pt.held, np.asarray(lam[npts], float)
        held_T, second = row_time_derivatives(A_full @ pt.C.ravel(), active.kind, T, A_full @ V1.ravel(),
                                              A_full @ V2.ravel())
        if b is not None:
            b = b - A_full[:, free].T @ (mu * active.kind) / T
            h += float(mu @ second)
    return TimeColumn(b, h, c_T, held_T)


@dataclass(frozen=True, eq=False)
class KinematicRows:
    """Every kinematic row's g at some C, per kind k < ``KINEMATIC``: ``g_lo``, ``g_hi`` (N, R_k, n) each, −inf where
    the bound is absent or the row is fixed by x0 alone (as ``active_limits.all_rows``' kinematic kinds).
    """

    g_lo: tuple[np.ndarray, ...]
    g_hi: tuple[np.ndarray, ...]

    def worst(self) -> float:
        """The largest g (−inf when no row is imposed)."""
        return max(float(np.max(g, initial=-np.inf)) for g in self.g_lo + self.g_hi)


def row_values(limits, rows: LimitRows, C: np.ndarray, ratio: float = 1.0) -> KinematicRows:
    """The kinematic rows' values at coefficients C (N+1, m, n) on ``rows.mesh`` (``KinematicRows``): the numbers of
    ``active_limits.all_rows`` without the effort rows and the penalty terms. ``ratio`` T/T' ≠ 1: those of the same
    s-domain trajectory on [0, T'] (``free_time.rescale(C, T, T')`` on the mesh's rows at T', to rounding): a row of
    d^k q/dt^k, k = 0, 1, 2, scales as ratio^k, and the rows at T serve.
    """
    lo, hi, sig = _bounds(limits)
    loc = rows.mesh.local_coefficients(np.asarray(C, float))
    g_lo, g_hi = [], []
    for k in range(KINEMATIC):
        shape = rows.shape(k, limits.n)
        if not (np.isfinite(lo[k]).any() or np.isfinite(hi[k]).any()):
            g_lo.append(np.full(shape, -np.inf))
            g_hi.append(g_lo[-1])
            continue
        V = rows.apply(k, loc)
        if ratio != 1.0 and k:
            V = V * ratio**k
        off = rows.data[k][:, :, None] if k < 2 else np.zeros((1, 1, 1), bool)  # q, q̇ rows of x0 alone: data
        g_hi.append(np.where(off | ~np.isfinite(hi[k]), -np.inf, (V - hi[k]) / sig[k]))
        g_lo.append(np.where(off | ~np.isfinite(lo[k]), -np.inf, (lo[k] - V) / sig[k]))
    return KinematicRows(tuple(g_lo), tuple(g_hi))


@lru_cache(maxsize=16)
def _bounds(limits) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``effective_bounds(limits, MARGIN)`` of a ``JointLimits`` (immutable), kept."""
    return effective_bounds(limits, MARGIN)


def _same_fractions(a, b) -> bool:
    """Whether non-uniform meshes a and b have N elements of the same order at the same node fractions (b.T / a.T
    times a's nodes, to rounding).
    """
    if a.uniform or b.uniform or a.N != b.N or a.order != b.order:
        return False
    return bool(np.max(np.abs(a.nodes * (b.T / a.T) - b.nodes)) <= 1e-15 * b.T)


def _same_uniform(a, b) -> bool:
    """Whether a and b are uniform meshes of N elements of the same order (at any T)."""
    return a.uniform and b.uniform and a.N == b.N and a.order == b.order


def problem_on(problem: GoalProblem, mesh) -> GoalProblem | None:
    """``problem`` (an ``evaluate_point`` problem: ``op_h`` is ``op``) on ``mesh``, a mesh with the same node fractions
    at another T (both uniform, or both non-uniform), or None when the meshes are not so related. A shallow copy whose
    quadrature is rescaled instead of rebuilt: the operator holds the h = 1 basis with the element scales h_e^(d_a) and
    h_e^(−r) (``elements.element_scales``), or on a uniform mesh the basis with those factors of its h applied (column a
    of ``B[r]`` scales as h^(d_a − r)), and every h_e, sample time and weight scales with T; the layout and the fixed
    coefficients (t-domain values) do not depend on T.
    """
    op = problem.op
    if problem.op_h is not op:
        return None
    ratio = mesh.T / problem.mesh.T
    d = np.tile(np.arange(mesh.m), 2).astype(float)
    if op.col_scale is None and _same_uniform(problem.mesh, mesh):
        B = op.B * ratio ** (d[None, None, :] - np.arange(3.0)[:, None, None])
        return _with_operator(problem, mesh, QuadratureOperator(mesh=mesh, G=op.G, t=op.t * ratio, w=op.w * ratio, B=B))
    if op.col_scale is None or not _same_fractions(problem.mesh, mesh):
        return None
    op_new = QuadratureOperator(mesh=mesh, G=op.G, t=op.t * ratio, w=op.w * ratio, B=op.B,
                                col_scale=op.col_scale * ratio**d, row_scale=op.row_scale * ratio ** -np.arange(3.0)[:, None])
    return _with_operator(problem, mesh, op_new)


def _with_operator(problem: GoalProblem, mesh, op: QuadratureOperator) -> GoalProblem:
    """A shallow copy of ``problem`` on ``mesh`` with the quadrature ``op`` (as ``op`` and ``op_h``)."""
    out = copy.copy(problem)
    out.mesh, out.op, out.op_h, out.last = mesh, op, op, None
    return out


def limit_rows(mesh, free: np.ndarray, n: int) -> LimitRows:
    """``LimitRows.build(mesh, free, n)``; on a non-uniform mesh its rows, parts and data (those of h = 1: they
    depend on the order, N and the free mask only) are kept from an earlier mesh of the same kind, and only the
    elements' scales are the mesh's own (each real-time update has a new mesh of the same kind).
    """
    if mesh.uniform:
        return LimitRows.build(mesh, free, n)
    unit = _unit_rows(mesh.order, mesh.N, n, np.asarray(free, bool).tobytes())
    return LimitRows(mesh, unit.rows, unit.part, unit.data, unit.pieces, tuple(mesh.scales(r) for r in range(len(unit.rows))))


@lru_cache(maxsize=16)
def _unit_rows(order: str, N: int, n: int, free: bytes) -> LimitRows:
    """The ``LimitRows`` of a non-uniform mesh of N elements of ``order`` (its rows, parts and data; not its scales)."""
    fractions = np.linspace(0.0, 1.0, N + 1) ** 1.5  # any non-uniform mesh
    mesh = HermiteMesh.from_nodes(order, fractions)
    return LimitRows.build(mesh, np.frombuffer(free, bool).copy(), n)


def rows_on(rows: LimitRows | None, mesh) -> LimitRows | None:
    """The limit rows of ``mesh`` from those of another mesh with the same node fractions (another T), or None
    when they cannot be reused: on a non-uniform mesh the rows are those of h = 1 with the elements' scales
    h_e^(d − r) (``LimitRows.build``), on a uniform one those of its h (column a of kind r as h^(d_a − r)), and every
    h_e scales with T.
    """
    if rows is None:
        return None
    ratio = mesh.T / rows.mesh.T
    d = np.tile(np.arange(mesh.m), 2)
    if rows.scale is None and _same_uniform(rows.mesh, mesh):  # rows of h: column a of kind r scales as h^(d_a − r)
        R = tuple(R * ratio ** (d - r).astype(float)[None, :] for r, R in enumerate(rows.rows))
        return LimitRows(mesh, R, rows.part, rows.data, rows.pieces, None)
    if rows.scale is None or not _same_fractions(rows.mesh, mesh):
        return None
    scale = tuple(sc * ratio ** (d - r).astype(float) for r, sc in enumerate(rows.scale))
    return LimitRows(mesh, rows.rows, rows.part, rows.data, rows.pieces, scale)


def solve_many(W, B: np.ndarray) -> np.ndarray:
    """W⁻¹ B for B (P, k) by one banded back-substitution of W's factor (``BandedSPD``)."""
    full = np.zeros((W.size, B.shape[1]))
    full[W.free] = B
    return cho_solve_banded((W.factor, False), full, check_finite=False)[W.free]


def dense_factor(W) -> np.ndarray:
    """The upper Cholesky factor U (P_free, P_free) of a ``BandedSPD`` W = UᵀU on its free coefficients."""
    ab = W.factor
    free = np.asarray(W.free, bool)
    dst, src = _free_band_indices(ab.shape[0] - 1, ab.shape[1], free.tobytes())
    P = int(np.count_nonzero(free))
    U = np.zeros((P, P))
    U.ravel()[dst] = ab.ravel()[src]  # ab[u - d, j] = U[j - d, j], the free rows and columns alone
    return U


@lru_cache(maxsize=32)
def _free_band_indices(u: int, n: int, free: bytes) -> tuple[np.ndarray, np.ndarray]:
    """(flat positions in U (P, P), flat positions in ab (u + 1, n)) of the entries U[j − d, j] = ab[u − d, j] whose row
    and column are both free (``free`` (n,) bool as bytes; P of them).
    """
    rows, cols, band = _band_indices(u, n)
    mask = np.frombuffer(free, bool)
    keep = mask[rows] & mask[cols]
    pos = np.cumsum(mask) - 1
    P = int(np.count_nonzero(mask))
    return pos[rows[keep]] * P + pos[cols[keep]], band[keep] * n + cols[keep]


@lru_cache(maxsize=32)
def _band_indices(u: int, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rows, columns, band rows) of the entries U[j − d, j] = ab[u − d, j] of an upper band of width u (n, n)."""
    d = np.concatenate([np.full(n - k, k) for k in range(u + 1)])
    j = np.concatenate([np.arange(k, n) for k in range(u + 1)])
    return j - d, j, u - d


def damped_trial(trial_at: Callable[[float], tuple[float, "LagrangianPoint"]], goal_rows: int,
                 violation: float, floor: float = VIOLATION_FLOOR,
                 accept: Callable[[float, float, "LagrangianPoint"], bool] | None = None,
                 violation_at: Callable[[float], float] | None = None,
                 ) -> tuple["LagrangianPoint | None", float, float, float]:
    """A Newton step halved (down to 1/32) while it raises the goal rows' violation above
    max(``violation``, ``floor``) (far steps leave the model) or ``accept(alpha, T, point)`` says no. ``trial_at(alpha)`` gives (T, point)
    of the step scaled by alpha; the first ``goal_rows`` entries of the point's rows are the goal rows'.
    ``violation_at(alpha)``, when given, is that violation alone (``goal_violation``, the same number): a step it
    rejects is halved without evaluating its point (the dynamics), except the last (alpha < 0.05), which is returned.
    Returns (point or None when it could not be evaluated, T, alpha, its violation).
    """
    alpha = 1.0
    while True:
        if violation_at is not None and alpha >= 0.05:
            try:
                v_pre = violation_at(alpha)
            except NumericalError:
                v_pre = math.inf
            if not v_pre <= max(violation, floor):
                alpha *= 0.5
                continue
        try:
            T_try, trial = trial_at(alpha)
            v_try = float(np.max(np.abs(trial.c[:goal_rows]), initial=0.0))
        except NumericalError:
            T_try, trial, v_try = math.nan, None, math.inf
        if (trial is not None and v_try <= max(violation, floor) and (accept is None or accept(alpha, T_try, trial))) \
                or alpha < 0.05:
            return trial, T_try, alpha, v_try
        alpha *= 0.5
