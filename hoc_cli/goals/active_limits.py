"""Sets of kinematic limit rows for a warm replan: the candidates of its QP steps and their working set.

At a constrained optimum the position, velocity and acceleration limits that bind are Bernstein rows
at their (inward-moved) bound, each with a multiplier μ ≥ 0 (``hoc_cli.constraints.penalty``). A replan
(``hoc_cli.goals.replan_qp``) imposes the rows near their bound as linear inequalities of each step's
quadratic programme; the rows with μ > 0 form its working set, whose μ·g enter the Lagrangian. This
module gathers such rows, their values, Jacobians and Gram blocks, and reports them in the augmented
Lagrangian's per-kind layout (``PenaltyValue``).

Symbols: N elements, m coefficients per node, n joints, P the flattened C (N+1, m, n); a row is
(kind k ∈ {0, 1, 2}, element e, Bernstein row r, joint j, side s = +1 upper / −1 lower), its value
g = s (V − b) / σ with V the Bernstein coefficient, b the bound moved inwards by the margin, σ the
limit's size (``effective_bounds``): dimensionless, linear in C at a fixed mesh. Pure maths: no I/O.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from hoc_cli.constraints.augmented_lagrangian import MARGIN
from hoc_cli.constraints.bounds import KINDS, KINEMATIC, JointLimits
from hoc_cli.constraints.penalty import EFFORT, LimitRows, LimitTerms, PenaltyValue, effective_bounds


@dataclass(frozen=True, eq=False)
class ActiveRows:
    """A set of kinematic limit rows, each (kind, element, row, joint, side); arrays of shape (a,)."""

    kind: np.ndarray
    elem: np.ndarray
    row: np.ndarray
    joint: np.ndarray
    side: np.ndarray

    @property
    def size(self) -> int:
        return int(self.kind.size)

    @classmethod
    def empty(cls) -> "ActiveRows":
        z = np.zeros(0, int)
        return cls(z, z, z, z, z)

    @classmethod
    def where(cls, lo: tuple[np.ndarray, ...], hi: tuple[np.ndarray, ...]) -> "ActiveRows":
        """The rows where the boolean arrays ``lo``/``hi`` (per kind 0..2, shape (N, R_k, n)) are True, kind by kind,
        the lower rows before the upper ones, each in (element, row, joint) order.
        """
        masks = [mask for k in range(KINEMATIC) for mask in (lo[k], hi[k])]
        table = _row_table(tuple(np.shape(mask) for mask in masks))
        return cls(*table[:, np.flatnonzero(np.concatenate([np.ravel(mask) for mask in masks]))])

    def keep(self, mask: np.ndarray) -> "ActiveRows":
        return ActiveRows(*(a[mask] for a in self._fields()))

    def _fields(self) -> tuple[np.ndarray, ...]:
        return self.kind, self.elem, self.row, self.joint, self.side

    def gather(self, lo: tuple[np.ndarray, ...], hi: tuple[np.ndarray, ...]) -> np.ndarray:
        """Per-row values (a,) from per-kind arrays of the lower and upper rows (shape (N, R_k, n))."""
        out = np.zeros(self.size)
        for k in range(KINEMATIC):
            for side, arr in ((-1, lo[k]), (1, hi[k])):
                sel = (self.kind == k) & (self.side == side)
                out[sel] = arr[self.elem[sel], self.row[sel], self.joint[sel]]
        return out

    def scatter(self, values: np.ndarray, rows: LimitRows, n: int) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
        """(lo, hi): per kind (all four), arrays of the kind's row shape holding ``values`` (a,) at the rows."""
        lo = [np.zeros(rows.shape(k, n)) for k in range(len(KINDS))]
        hi = [np.zeros(rows.shape(k, n)) for k in range(len(KINDS))]
        for k in range(KINEMATIC):
            for side, arr in ((-1, lo[k]), (1, hi[k])):
                sel = (self.kind == k) & (self.side == side)
                np.add.at(arr, (self.elem[sel], self.row[sel], self.joint[sel]), values[sel])
        return tuple(lo), tuple(hi)

    def jacobian(self, rows: LimitRows, limits: JointLimits, free: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(A (a, P_free), A_full (a, P)): g = A_full · C.ravel() + ``offsets``; A its free columns."""
        mesh = rows.mesh
        m, n = mesh.m, limits.n
        a = self.size
        size = (mesh.N + 1) * m * n
        A = np.zeros((a, size))
        if a == 0:
            return A[:, free], A
        # the element's local coefficient l (node e + l // m, derivative l % m) of the row's joint: C.ravel()[(e m + l) n + j]
        first = np.arange(0, a * size, size) + self.elem * (m * n) + self.joint  # (a,)
        # one entry per (row, column): the 2m columns of a row differ
        A.ravel()[first[:, None] + np.arange(0, 2 * m * n, n)[None, :]] = self._coefficients(rows, limits)
        return A[:, free], A

    def gram_blocks(self, rows: LimitRows, limits: JointLimits, rho: float) -> np.ndarray:
        """Element blocks (N, 2mn, 2mn) of ρ AᵀA (each row touches one element and one joint): added to the
        Newton matrix, they make it positive definite on the rows' span without changing the KKT step.
        """
        mesh = rows.mesh
        m, n = mesh.m, limits.n
        blocks = np.zeros((mesh.N, 2 * m, n, 2 * m, n))
        if self.size:
            coef = self._coefficients(rows, limits)  # (a, 2m)
            outer = rho * coef[:, :, None] * coef[:, None, :]  # (a, 2m, 2m)
            np.add.at(blocks.transpose(0, 2, 4, 1, 3), (self.elem, self.joint, self.joint), outer)
        return blocks.reshape(mesh.N, 2 * m * n, 2 * m * n)

    def _coefficients(self, rows: LimitRows, limits: JointLimits) -> np.ndarray:
        """∂g/∂(element-local coefficients of the row's joint), (a, 2m)."""
        _, _, sig = _bounds(limits)
        coef = np.zeros((self.size, 2 * rows.mesh.m))
        for k in range(KINEMATIC):
            sel = self.kind == k
            if not sel.any():
                continue
            c = rows.rows[k][self.row[sel]]
            if rows.scale is not None:
                c = c * rows.scale[k][self.elem[sel]]
            coef[sel] = c * (self.side[sel] / sig[k, self.joint[sel]])[:, None]
        return coef

    def offsets(self, limits: JointLimits) -> np.ndarray:
        """−s b / σ per row (a,): g = A_full · C.ravel() + offsets."""
        lo, hi, sig = _bounds(limits)
        b = np.where(self.side > 0, hi[self.kind, self.joint], lo[self.kind, self.joint])
        return -self.side * b / sig[self.kind, self.joint]


@lru_cache(maxsize=16)
def _row_table(shapes: tuple[tuple[int, ...], ...]) -> np.ndarray:
    """(kind, element, row, joint, side) (5, R) of every row of masks of these shapes (per kind, lower then upper),
    raveled and concatenated in that order: ``ActiveRows.where``'s rows are its columns where the masks hold. Read-only.
    """
    parts = []
    for i, shape in enumerate(shapes):
        e, r, j = np.indices(shape).reshape(3, -1)
        parts.append(np.stack([np.full(e.size, i // 2), e, r, j, np.full(e.size, 1 if i % 2 else -1)]))
    table = np.concatenate(parts, axis=1).astype(int)
    table.flags.writeable = False
    return table


@lru_cache(maxsize=16)
def _bounds(limits: JointLimits) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``effective_bounds(limits, MARGIN)`` of a ``JointLimits`` (immutable), kept: the rows' Jacobians and
    offsets ask for it several times per step.
    """
    return effective_bounds(limits, MARGIN)


def from_multipliers(pv: PenaltyValue | None) -> ActiveRows | None:
    """The kinematic rows with a positive multiplier in ``pv``; None when an effort multiplier is
    positive (effort rows are not linear: the replan keeps them as penalty terms) or ``pv`` is None.
    """
    if pv is None:
        return None
    if np.any(pv.mu_lo[EFFORT] > 0) or np.any(pv.mu_hi[EFFORT] > 0):
        return None
    return ActiveRows.where(tuple(m > 0 for m in pv.mu_lo[:KINEMATIC]), tuple(m > 0 for m in pv.mu_hi[:KINEMATIC]))


def all_rows(system, limits: JointLimits, rows: LimitRows, C: np.ndarray) -> PenaltyValue:
    """Every kinematic row's g (lower, upper; −inf where not imposed) at C, multipliers zero."""
    n = limits.n
    working = np.zeros((len(KINDS), n), bool)
    working[:KINEMATIC] = True
    zeros = tuple(np.zeros(rows.shape(k, n)) for k in range(len(KINDS)))
    return LimitTerms(system, limits, rows, working, zeros, zeros, 1.0, MARGIN).evaluate(C, grad=False)


def kinematic_rows(limits: JointLimits, rows: LimitRows, C: np.ndarray) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
    """(g_lo, g_hi): every kinematic row's g at C, per kind (N, R_k, n), −inf where not imposed (an infinite bound, q and
    q̇ rows set by x0 and x1 alone): ``all_rows``' kinematic kinds, the same numbers, without the effort points.
    """
    lo, hi, sig = _bounds(limits)
    loc = rows.mesh.local_coefficients(C)
    g_lo, g_hi = [], []
    for k in range(KINEMATIC):
        V = rows.apply(k, loc)
        data = rows.data[k][:, :, None] if k < 2 else np.zeros((1, 1, 1), bool)
        g_hi.append(np.where(data | ~np.isfinite(hi[k]), -np.inf, (V - hi[k]) / sig[k]))
        g_lo.append(np.where(data | ~np.isfinite(lo[k]), -np.inf, (lo[k] - V) / sig[k]))
    return tuple(g_lo), tuple(g_hi)


def penalty_value(active: ActiveRows, mu: np.ndarray, everything: PenaltyValue, rows: LimitRows, n: int) -> PenaltyValue:
    """A ``PenaltyValue`` holding the active rows' multipliers μ (a,) ≥ 0 (rounded up from −0) and every
    row's g, as the augmented Lagrangian reports its outcome (for dJ*/dT, the summary, the next replan).
    """
    mu_lo, mu_hi = active.scatter(np.maximum(mu, 0.0), rows, n)
    return PenaltyValue(0.0, None, everything.g_lo, everything.g_hi, mu_lo, mu_hi)
