"""The limits' guard of a real-time update: every returned plan within its kinematic limits, exactly.

Symbols: C (N+1, m, n) a plan's coefficients on its mesh (fixed T), x = C's free entries (P,); a kinematic
row (position, velocity, acceleration, jerk of one joint on one element) g = s (V − b)/σ with V a Bernstein
coefficient of that derivative's polynomial, b the bound moved inwards by ``MARGIN``, σ the limit's size, s
= ±1 (``hoc_cli.goals.active_limits``): dimensionless and linear in x, and g ≤ 0 for all rows implies the
derivative within its bound on the whole element (the Bernstein hull contains the polynomial).

``guard`` returns C itself when every row holds to ``ROW_TOL``; else the projection of x onto the rows
within ``GAP`` of their bound, min ½‖d‖² s.t. A(x + d) + o ≤ 0 and E d = 0 for rows E to keep (the goal rows'
Jacobian: the plan keeps meeting its goal to first order) (a least-distance programme, solved exactly by
``hoc_cli.goals.qp_step.solve_qp``), repeated with every row that the projection broke, up to ``ROUNDS``
times; None when no such projection is found (the caller keeps its previous plan).

``within_limits`` is the exact check of a plan the guard returned: every kinematic Bernstein row at or below its
bound, the rows fixed by the start state included (they are not rows of the guard's programme), implies q, q̇, q̈
and the jerk within their limits on the whole plan (the Bernstein hull), so ``check_limits``' exact extrema are
needed only when such a row is above its bound; the torques are checked as ``check_limits`` does (32 points per
element and the nodes: ``torques_hold``, its numbers without its other kinds). Pure maths: no I/O.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from hoc_cli.constraints.augmented_lagrangian import MARGIN
from hoc_cli.constraints.bounds import KINDS, KINEMATIC, JointLimits
from hoc_cli.constraints.check import CHECK_POINTS_PER_ELEMENT, RELATIVE_TOLERANCE, check_limits
from hoc_cli.constraints.penalty import effective_bounds
from hoc_cli.constraints.points import PointSet
from hoc_cli.elements import local_basis
from hoc_cli.errors import NumericalError
from hoc_cli.goals.active_limits import ActiveRows
from hoc_cli.goals.qp_step import Programme, solve_qp
from hoc_cli.goals.replan_point import row_values
from hoc_cli.goals.replan_qp import row_keys

ROW_TOL = 1e-9  # a row holds when g ≤ this (the margin is 1e-9: the limit itself is then met to the check's 1e-9)
GAP = 0.05  # rows within this of their bound enter the projection
ROUNDS = 4
PUSH = 1e-10  # the projection aims this far inside the rows (rounding)


def worst_row(system, limits, rows, C: np.ndarray) -> float:
    """The largest g over every kinematic row of C (−inf when none is imposed)."""
    return row_values(limits, rows, C).worst()


def guard(system, limits, rows, C: np.ndarray, free: np.ndarray, keep: np.ndarray | None = None,
          near: list | None = None) -> np.ndarray | None:
    """C when its kinematic rows hold, else its projection onto them at the same T, or None (module docstring).

    rows : the mesh's ``LimitRows``; free : (P_all,) bool, the free entries of C.ravel(); keep : (r, P) rows E whose
    values the projection keeps to first order (E d = 0: the goal rows' Jacobian, so that the plan still meets
    its goal), or None; near : an empty list, or the one of an earlier call on the same C: the projection's rows
    (per kind, lower and upper boolean masks) are those in it plus those within ``GAP`` of their bound, and it
    is left holding every row the rounds used (a second projection of C, e.g. without ``keep``, then starts from
    the rows the first one needed instead of finding them again round by round).
    """
    kr = row_values(limits, rows, C)
    if kr.worst() <= ROW_TOL:
        return C
    flat = np.asarray(C, float).ravel().copy()
    lo = [g > -GAP for g in kr.g_lo]
    hi = [g > -GAP for g in kr.g_hi]
    if near:
        lo, hi = [a | b for a, b in zip(lo, near[0])], [a | b for a, b in zip(hi, near[1])]
    E = np.zeros((0, int(np.sum(free)))) if keep is None else np.asarray(keep, float)
    out = None
    for _ in range(ROUNDS):
        rows_now = ActiveRows.where(tuple(lo), tuple(hi))
        A, A_full = rows_now.jacobian(rows, limits, free)
        g = A_full @ flat + rows_now.offsets(limits)
        # the metric is the identity: d = 0 off the columns the rows touch
        cols = np.flatnonzero(np.any(A != 0.0, axis=0) | np.any(E != 0.0, axis=0))
        P = cols.size
        # the metric's factor the identity (U None: no triangular solves); each row transformed alone (keyed)
        E_c = E[:, cols]
        try:
            step = solve_qp(None, np.zeros(P), E_c, np.zeros(E.shape[0]), A[:, cols], -g - PUSH,
                            programme=Programme(None, np.zeros(P), E_c, keyed=True), keys=row_keys(rows_now))
        except NumericalError:
            break
        d = np.zeros(A.shape[1])
        d[cols] = step.d
        flat[free] += d
        kr = row_values(limits, rows, flat.reshape(C.shape))
        if kr.worst() <= ROW_TOL:
            out = flat.reshape(C.shape)
            break
        lo = [a | (b > -GAP) for a, b in zip(lo, kr.g_lo)]
        hi = [a | (b > -GAP) for a, b in zip(hi, kr.g_hi)]
    if near is not None:
        near[:] = [lo, hi]
    return out


def within_limits(system, limits: JointLimits, rows, C: np.ndarray, effort: JointLimits | None,
                  rows_hold: bool = False) -> bool:
    """Whether the plan C (N+1, m, n) on ``rows.mesh`` passes ``check_limits`` (module docstring): every kinematic
    Bernstein row of every element g ≤ ``ROW_TOL`` (else ``check_limits`` on the kinematic kinds decides), and
    ``check_limits`` with ``effort`` (the effort limits alone, or None when there are none). ``rows_hold``: every row
    not fixed by the start state is known to be ≤ ``ROW_TOL`` (C is ``guard``'s), so only the elements holding rows
    fixed by it are evaluated (the same decision).
    """
    mesh = rows.mesh
    loc = mesh.local_coefficients(np.asarray(C, float))
    lo, hi, sig = _kinematic_bounds(limits)
    worst = -np.inf
    for k in range(KINEMATIC):
        if not limits.has(KINDS[k]).any():
            continue
        if rows_hold:  # the rows fixed by the start state (q, q̇ rows of x0 alone: row_values leaves them out)
            el = np.flatnonzero(rows.data[k].any(axis=1)) if k < 2 else np.zeros(0, int)
            if not el.size:
                continue
            part = loc[el] if rows.scale is None else loc[el] * rows.scale[k][el][:, :, None]
            V = np.einsum("ra,ean->ern", rows.rows[k], part)
        else:
            V = rows.apply(k, loc)  # (N, R_k, n)
        with np.errstate(invalid="ignore"):
            worst = max(worst, float(np.max((V - hi[k]) / sig[k])), float(np.max((lo[k] - V) / sig[k])))
    if not worst <= ROW_TOL and not check_limits(system, limits, mesh, C).feasible:
        return False
    return effort is None or torques_hold(system, effort, mesh, C)


def torques_hold(system, effort: JointLimits, mesh, C: np.ndarray) -> bool:
    """``check_limits(system, effort, mesh, C).feasible`` for limits ``effort`` with effort bounds alone (``effort_only``):
    the same torques (inverse dynamics at ``CHECK_POINTS_PER_ELEMENT`` + 1 points of every element, the nodes
    included) against the same bounds and tolerances, without the check's other kinds and its report.
    """
    e, s, unit = _check_grid(mesh.order, mesh.N, CHECK_POINTS_PER_ELEMENT)
    # ``PointSet.build``'s shape values (``HermiteMesh.shape_values``: the h = 1 values times h_e^(d_a − r)), the same
    # numbers with the h = 1 values kept and the elements' factors taken once per element
    B = np.stack([unit[r] * (mesh.scale(r) if mesh.uniform else mesh.scales(r)[e]) for r in range(3)])
    X = PointSet(mesh=mesh, e=e, s=s, B=B, weight=np.ones(e.size)).apply(C)
    u = system.inverse_dynamics(X[0], X[1], X[2])  # (K, n)
    lo, hi, tol_lo, tol_hi = _effort_bounds(effort)
    with np.errstate(invalid="ignore"):  # a bound ±inf: excess −inf; the largest excess is that of the extreme torque
        return not (np.any(np.max(u, axis=0) - hi > tol_hi) or np.any(lo - np.min(u, axis=0) > tol_lo))


@lru_cache(maxsize=16)
def _check_grid(order: str, N: int, per: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``check_limits``' points of N elements, ``per`` + 1 per element, the nodes included: their elements e (K,), local
    coordinates s (K,) and the shape functions' s-derivatives 0..2 there (3, K, 2m) (h = 1, ``HermiteMesh.shape_values``'
    first factor). Read-only, kept: the same on every mesh of N elements.
    """
    e = np.repeat(np.arange(N), per + 1)
    s = np.tile(np.linspace(0.0, 1.0, per + 1), N)
    powers = s[:, None] ** np.arange(6)[None, :]
    unit = np.stack([powers @ local_basis(order)[r].T for r in range(3)])
    for a in (e, s, unit):
        a.flags.writeable = False
    return e, s, unit


@lru_cache(maxsize=16)
def _kinematic_bounds(limits: JointLimits) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``effective_bounds(limits, MARGIN)`` of a ``JointLimits`` (immutable), kept: ``within_limits`` asks every update."""
    return effective_bounds(limits, MARGIN)


@lru_cache(maxsize=16)
def _effort_bounds(effort: JointLimits) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(lo, hi, their tolerances) (n,) each of the effort limits, as ``LimitCheck.tolerance``: 1e-9·max(|b|, 1e-3 σ)."""
    lo, hi = effort.bounds("effort")
    floor = 1e-3 * effort.scale_of("effort")
    return lo, hi, *(RELATIVE_TOLERANCE * np.maximum(np.where(np.isfinite(b), np.abs(b), 0.0), floor) for b in (lo, hi))


def effort_only(limits: JointLimits) -> JointLimits | None:
    """The effort limits of ``limits`` alone (None when no joint has one): ``within_limits``' torque check."""
    if not np.isfinite(limits.effort).any():
        return None
    return JointLimits.from_arrays(limits.joints, effort=limits.effort)
