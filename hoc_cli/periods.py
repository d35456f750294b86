"""Turning points and the period of a free oscillation, read exactly off a Hermite trajectory
(used by ``hoc verify``'s pendulum check against the elliptic-integral period).
"""
from __future__ import annotations

import numpy as np
from numpy.polynomial import polynomial as P

from hoc_cli.elements import HermiteMesh, local_basis
from hoc_cli.errors import NumericalError


def velocity_zeros(mesh: HermiteMesh, coeffs: np.ndarray, joint: int = 0) -> np.ndarray:
    """All times [s] in [0, T] where q̇_h of ``joint`` vanishes, sorted; shape (Z,).

    Found per element as the real roots in [0, 1] of the polynomial q̇_h(s) (degree 2 or 4),
    polished by Newton's method on that polynomial: no sampling error.
    """
    coeffs = mesh.check_coefficients(coeffs)
    basis = local_basis(mesh.order)[1] * mesh.scale(1)[:, None]  # (2m, 6): q̇ as a power series in s
    loc = mesh.local_coefficients(coeffs)[:, :, joint]  # (N, 2m)
    poly = loc @ basis  # (N, 6)
    times: list[float] = []
    for e in range(mesh.N):
        p = np.trim_zeros(poly[e], "b")
        if p.size < 2:
            continue
        dp = P.polyder(p)
        for r in P.polyroots(p):
            if abs(r.imag) > 1e-7:
                continue
            x = r.real
            for _ in range(3):
                d = P.polyval(x, dp)
                if d == 0:
                    break
                x -= P.polyval(x, p) / d
            if -1e-12 <= x <= 1 + 1e-12:
                times.append((e + min(max(x, 0.0), 1.0)) * mesh.h)
    times.sort()
    out: list[float] = []
    for tz in times:  # a root on a shared node is found by both elements
        if not out or tz - out[-1] > 1e-9 * mesh.h:
            out.append(tz)
    return np.array(out)


def oscillation_period(mesh: HermiteMesh, coeffs: np.ndarray, joint: int = 0) -> float:
    """Period [s] of a free, symmetric oscillation from the zeros of q̇_h (turning points).

    Turning points are half a period apart: τ/2 is the least-squares slope of t_k against k.
    Needs at least three turning points (one full period).
    """
    tz = velocity_zeros(mesh, coeffs, joint)
    if tz.size < 3:
        raise NumericalError(f"need at least 3 turning points to measure a period, found {tz.size} in [0, {mesh.T}] s")
    k = np.arange(tz.size, dtype=float)
    slope = np.polyfit(k, tz, 1)[0]
    return 2.0 * float(slope)
