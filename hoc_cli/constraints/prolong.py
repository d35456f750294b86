"""Augmented-Lagrangian multipliers carried from one mesh to another (coarse to fine, or the same mesh).

Symbols
-------
A multiplier μ of a row stands for the time w [s] the row stands for (``LimitRows.weight``): a limit
active along an arc has multipliers whose density μ/w per unit time converges as the mesh refines
(to the continuous problem's multiplier function), while μ itself shrinks with w. So the density is
what transfers: a row of the new mesh takes the density of the old mesh's row at its time, times its
own w.

Kinematic rows (Bernstein coefficients, ``bernstein.py``) come in ``pieces`` parts per element, each
part with the same d + 1 rows; a new row (element e', part p', i-th row of the part) takes the old
row i of the old part containing the midpoint of (e', p'). Effort rows (points) take the nearest old
point. On the same mesh the map is the identity.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hoc_cli.constraints.bounds import KINDS
from hoc_cli.constraints.penalty import EFFORT, LimitRows


@dataclass(frozen=True, eq=False)
class Duals:
    """Multipliers of one solve on its rows: the warm start of the next solve's augmented Lagrangian.

    rows : the LimitRows they belong to; mu_lo, mu_hi : per kind, the kind's row shape (≥ 0).
    """

    rows: LimitRows
    mu_lo: tuple[np.ndarray, ...]
    mu_hi: tuple[np.ndarray, ...]


def _kinematic(old: LimitRows, mu: np.ndarray, new: LimitRows, k: int) -> np.ndarray:
    """Multipliers (N', R, n) on ``new``'s rows of kind k from ``mu`` (N, R, n) on ``old``'s."""
    R = new.rows[k].shape[0]
    if old.rows[k].shape[0] != R or old.pieces != new.pieces:
        return np.zeros((new.mesh.N, R, mu.shape[-1]))  # another element order: no transfer
    P = new.pieces
    part = new.part[k]  # (R,)
    within = np.arange(R) - np.searchsorted(part, part)  # index of each row within its part
    first = np.searchsorted(old.part[k], np.arange(P))  # first old row of each part
    e_new = np.arange(new.mesh.N)
    mid = new.mesh.time_of(e_new[:, None], (np.arange(P)[None, :] + 0.5) / P)  # (N', P) part midpoints [s]
    e_old, s_old = old.mesh.element_of(mid.ravel())
    p_old = np.minimum((s_old * P).astype(int), P - 1)
    e_old, p_old = e_old.reshape(mid.shape), p_old.reshape(mid.shape)  # (N', P)
    r_old = first[p_old[:, part]] + within[None, :]  # (N', R)
    e_rows = e_old[:, part]  # (N', R)
    ratio = new.mesh.hs[:, None] / old.mesh.hs[e_rows]  # w'/w: both are h / R
    return mu[e_rows, r_old] * ratio[:, :, None]


def _effort(old: LimitRows, mu: np.ndarray, new: LimitRows) -> np.ndarray:
    """Multipliers (P', n) at ``new``'s effort points from ``mu`` (P, n) at ``old``'s (nearest point in time)."""
    t_old, t_new = old.points.t, new.points.t
    order = np.argsort(t_old, kind="stable")
    ts = t_old[order]
    i = np.clip(np.searchsorted(ts, t_new), 1, ts.size - 1)
    nearest = order[np.where(t_new - ts[i - 1] <= ts[i] - t_new, i - 1, i)]
    ratio = new.points.weight / old.points.weight[nearest]
    return mu[nearest] * ratio[:, None]


def same_mesh(a: LimitRows, b: LimitRows) -> bool:
    """Whether two row sets lie on the same mesh (element order, count and lengths)."""
    ma, mb = a.mesh, b.mesh
    return ma.order == mb.order and ma.N == mb.N and np.allclose(ma.hs, mb.hs, rtol=1e-12, atol=0.0)


def prolong(duals: Duals, rows: LimitRows) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
    """(λ_lo, λ_hi) on ``rows`` (per kind, the kind's row shape) from ``duals`` on another (or the same) mesh.

    Rows fixed by x0/x1 alone (``rows.data``) get 0.
    """
    old = duals.rows
    if old is rows:
        return tuple(m.copy() for m in duals.mu_lo), tuple(m.copy() for m in duals.mu_hi)
    out = []
    for mus in (duals.mu_lo, duals.mu_hi):
        side = []
        for k in range(len(KINDS)):
            if not np.any(mus[k]):
                n = mus[k].shape[-1]
                side.append(np.zeros(rows.shape(k, n)))
            elif k == EFFORT:
                side.append(_effort(old, mus[k], rows))
            else:
                lam = _kinematic(old, mus[k], rows, k)
                side.append(np.where(rows.data[k][:, :, None], 0.0, lam) if k < 2 else lam)
        out.append(tuple(side))
    return out[0], out[1]
