"""Exact extrema of q_h, q̇_h, q̈_h on every element: the polynomials' critical points.

Symbols
-------
N elements, n joints, m coefficients per node, s ∈ [0, 1] the local coordinate of an element,
h = T/N. On element e, the r-th time derivative of q_h is a polynomial of degree ≤ 5 − r in s
(quintic; cubic: ≤ 3 − r); its extrema on [0, 1] are at s = 0, s = 1 or at a real root of its
derivative. The roots come from the eigenvalues of companion matrices (batched over elements
and joints) polished by two Newton steps, so each extremum is found to rounding accuracy.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hoc_cli.elements import HermiteMesh, local_basis


def element_polynomials(mesh: HermiteMesh, C: np.ndarray, deriv: int) -> np.ndarray:
    """Power-series coefficients in s of d^r q_h / dt^r on every element, shape (N, n, 6) (lowest first)."""
    loc = mesh.local_coefficients(mesh.check_coefficients(C))  # (N, 2m, n)
    if not mesh.uniform:  # h_e-scaled coefficients on the h = 1 basis
        return np.einsum("eai,ak->eik", loc * mesh.scales(deriv)[:, :, None], local_basis(mesh.order)[deriv])
    basis = local_basis(mesh.order)[deriv] * mesh.scale(deriv)[:, None]  # (2m, 6), t-derivative
    return np.einsum("eai,ak->eik", loc, basis)


def _polyval(c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Evaluate polynomials c (..., d+1) at points s (..., k) (Horner), result (..., k)."""
    out = np.zeros(np.broadcast_shapes(c.shape[:-1] + (1,), s.shape))
    for k in range(c.shape[-1] - 1, -1, -1):
        out = out * s + c[..., k:k + 1]
    return out


def _critical_points(c: np.ndarray) -> np.ndarray:
    """Candidate maximisers/minimisers in [0, 1] of polynomials c (B, d+1): (B, d+1) points.

    s = 0, s = 1 and the real parts (clipped to [0, 1]) of the roots of c', polished by Newton.
    Extra candidates are harmless: the extremum is the max/min of c over all of them.
    """
    B, D = c.shape
    ends = np.broadcast_to(np.array([0.0, 1.0]), (B, 2))
    dc = c[:, 1:] * np.arange(1, D)  # (B, D-1): c'
    deg = dc.shape[1] - 1
    if deg < 1:
        return ends.copy()
    size = np.max(np.abs(dc), axis=1)
    size = np.where(size > 0, size, 1.0)
    lead = dc[:, -1]
    tiny = 1e-13 * size
    lead = np.where(np.abs(lead) < tiny, np.where(lead < 0, -tiny, tiny), lead)  # degree drop: a far root
    comp = np.zeros((B, deg, deg))
    comp[:, 0, :] = -dc[:, -2::-1] / lead[:, None]
    if deg > 1:
        comp[:, np.arange(1, deg), np.arange(deg - 1)] = 1.0
    roots = np.clip(np.linalg.eigvals(comp).real, 0.0, 1.0)  # (B, deg)
    ddc = dc[:, 1:] * np.arange(1, deg + 1)
    s = roots
    for _ in range(2):
        f, fp = _polyval(dc, s), _polyval(ddc, s)
        step = np.where(np.abs(fp) > 0, f / np.where(fp != 0, fp, 1.0), 0.0)
        s = np.clip(s - step, 0.0, 1.0)
    return np.concatenate([ends, roots, s], axis=1)


@dataclass(frozen=True, eq=False)
class Extrema:
    """Per element and joint: the largest and smallest value of a polynomial on [0, 1].

    max, min : (N, n) values; s_max, s_min : (N, n) local coordinates where they are attained.
    """

    max: np.ndarray
    s_max: np.ndarray
    min: np.ndarray
    s_min: np.ndarray


def extrema(mesh: HermiteMesh, C: np.ndarray, deriv: int) -> Extrema:
    """Exact max and min of d^r q_h/dt^r [rad/s^r] on every element for coefficients C (N+1, m, n)."""
    poly = element_polynomials(mesh, C, deriv)  # (N, n, 6)
    N, n, D = poly.shape
    degree = (5 if mesh.order == "quintic" else 3) - deriv
    c = poly[..., : degree + 1].reshape(N * n, degree + 1)
    s = _critical_points(c)
    v = _polyval(c, s)
    imax, imin = np.argmax(v, axis=1), np.argmin(v, axis=1)
    rows = np.arange(N * n)
    return Extrema(max=v[rows, imax].reshape(N, n), s_max=s[rows, imax].reshape(N, n),
                   min=v[rows, imin].reshape(N, n), s_min=s[rows, imin].reshape(N, n))
