"""Bernstein enclosures of q_h, q̇_h, q̈_h: finitely many linear bounds that hold on whole elements.

Symbols
-------
N elements, m coefficients per node, n joints, s ∈ [0, 1] the local coordinate, h = T/N.
On element e the r-th time derivative of q_h is a polynomial p of degree d = deg − r in s
(deg = 5 quintic, 3 cubic). Split [0, 1] into ``pieces`` equal parts; on each, p has Bernstein
coefficients β_0 … β_d, linear in the element's 2m·n Hermite coefficients, and

    min_i β_i <= p(s) <= max_i β_i on that part

(the convex-hull property; Farouki 2012, "The Bernstein polynomial basis: a centennial
retrospective", §2). Bounding every β_i therefore bounds p at EVERY s: a plan that meets these
inequalities meets its limits exactly, with no sampling. The enclosure is tight where p is nearly
linear on a part (its gap shrinks like (h/pieces)² as the mesh refines), and exact where a limit
is active on a whole element (p constant there).
"""
from __future__ import annotations

from functools import lru_cache
from math import comb

import numpy as np

from hoc_cli.elements import HermiteMesh, local_basis

PIECES = 2


@lru_cache(maxsize=None)
def _power_to_bernstein(d: int) -> np.ndarray:
    """(d+1, d+1) map from power coefficients c_j (of σ^j) to Bernstein coefficients β_i on [0, 1]."""
    A = np.zeros((d + 1, d + 1))
    for i in range(d + 1):
        for j in range(i + 1):
            A[i, j] = comb(i, j) / comb(d, j)
    return A


@lru_cache(maxsize=None)
def _reparametrise(d: int, a: float, b: float) -> np.ndarray:
    """(d+1, d+1) map from power coefficients in s to those in σ, with s = a + (b − a) σ."""
    R = np.zeros((d + 1, d + 1))
    L = b - a
    for j in range(d + 1):  # s^j = Σ_k C(j, k) a^(j−k) L^k σ^k
        for k in range(j + 1):
            R[k, j] = comb(j, k) * a ** (j - k) * L**k
    return R


def bernstein_rows(mesh: HermiteMesh, deriv: int, pieces: int = PIECES) -> tuple[np.ndarray, np.ndarray]:
    """Rows R (pieces·(d+1), 2m) mapping an element's local coefficients (per joint) to Bernstein
    coefficients of d^r q_h/dt^r on each part, and each row's part index (pieces·(d+1),)."""
    d = (5 if mesh.order == "quintic" else 3) - deriv
    power = (local_basis(mesh.order)[deriv] * mesh.scale(deriv)[:, None])[:, : d + 1]  # (2m, d+1): p = Σ_a C_a power[a]
    rows, part = [], []
    for k in range(pieces):
        M = _power_to_bernstein(d) @ _reparametrise(d, k / pieces, (k + 1) / pieces)  # (d+1, d+1)
        rows.append(M @ power.T)  # (d+1, 2m)
        part.extend([k] * (d + 1))
    return np.concatenate(rows), np.array(part)
