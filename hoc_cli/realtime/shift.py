"""A plan shifted to a later start: its remaining part on N elements whose nodes include the plan's own.

Symbols: n joints, N elements, m = 2 (cubic) or 3 (quintic) coefficients per node (q, q̇[, q̈]) in the time
units of the mesh [rad, rad/s, rad/s²]. A plan in force starts at t0 [s] (absolute) and lasts T [s]; at a
later t [s] its remaining part covers [t, t0 + T], of length T_rem.

The shifted mesh has the nodes t and every node of the plan after t + ``MIN_ELEMENT``·T/N (a node closer
to t would make a very short first element: it is dropped), then the longest element is halved until there
are N elements again. Every new element then lies inside one element of the plan (its ``parent``), on which
the plan is one polynomial of the element's degree, so the Hermite coefficients q, q̇ (, q̈) of the plan at
the new nodes reproduce the remaining part exactly (``exact``), and each new element's Bernstein
coefficients are convex combinations of its parent's (de Casteljau's subdivision): a plan within its
kinematic Bernstein rows stays within them. When a node was dropped, the first element interpolates the
plan across it (a difference of the order of the jump of the highest derivative there). When the new duration
T' differs from T_rem (a free T clipped to its range), the path is kept in s = τ/T' and its time
derivatives of order d are scaled by (T_rem/T')^d (``hoc_cli.free_time.rescale``). Pure maths: no I/O.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hoc_cli.elements import HermiteMesh
from hoc_cli.free_time import rescale

MIN_ELEMENT = 0.2  # a first element shorter than this × the plan's mean element is merged with the next


@dataclass(frozen=True, eq=False)
class Shifted:
    """The shifted plan: ``mesh`` on [0, T'], ``coeffs`` (N+1, m, n), ``parent`` (N,) the plan's element containing
    each new element, ``exact`` whether it is the plan's remaining part itself (no node dropped, T' = T_rem).
    """

    mesh: HermiteMesh
    coeffs: np.ndarray
    parent: np.ndarray
    exact: bool


def shift_plan(mesh: HermiteMesh, C: np.ndarray, t0: float, t: float, T_new: float | None = None,
               N: int | None = None) -> Shifted:
    """The plan (mesh, C) started at t0 [s] shifted to start at t [s] (t0 ≤ t < t0 + mesh.T) on N elements
    (default the plan's) lasting T_new [s] (default the remaining T_rem); module docstring.
    """
    N = mesh.N if N is None else N
    T_rem = t0 + mesh.T - t
    if not 0.0 < T_rem <= mesh.T + 1e-12:
        raise ValueError(f"the shift to t = {t!r} s leaves no part of the plan on [{t0!r}, {t0 + mesh.T!r}] s")
    old = mesh.nodes  # local times of the plan's nodes
    tau = t - t0
    keep = old[old > tau + MIN_ELEMENT * mesh.T / mesh.N]
    dropped = bool(np.any((old > tau) & (old <= tau + MIN_ELEMENT * mesh.T / mesh.N) & (old < mesh.T)))
    if keep.size == 0 or keep[-1] != mesh.T:
        keep = np.append(keep[keep < mesh.T], mesh.T)
    nodes = np.concatenate([[tau], keep])
    while nodes.size < N + 1:
        e = int(np.argmax(np.diff(nodes)))
        nodes = np.insert(nodes, e + 1, 0.5 * (nodes[e] + nodes[e + 1]))
    while nodes.size > N + 1:  # more of the plan's nodes than N: the shortest pair of elements merged
        widths = nodes[2:] - nodes[:-2]
        nodes = np.delete(nodes, int(np.argmin(widths)) + 1)
        dropped = True
    C_rem = np.stack([mesh.evaluate(C, nodes, r) for r in range(mesh.m)], axis=1)
    mids = 0.5 * (nodes[1:] + nodes[:-1])
    parent = np.clip(np.searchsorted(old, mids) - 1, 0, mesh.N - 1)
    local = nodes - tau
    T_out = T_rem if T_new is None else float(T_new)
    if T_out != T_rem:
        C_rem = rescale(C_rem, T_rem, T_out)
        local = local * (T_out / T_rem)
    local[0], local[-1] = 0.0, T_out
    new_mesh = HermiteMesh.from_nodes(mesh.order, local)
    return Shifted(mesh=new_mesh, coeffs=C_rem, parent=parent, exact=not dropped and T_out == T_rem)
