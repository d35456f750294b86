"""Meshes with the via times as nodes: N elements of [0, T] with a node at each fraction s of T.

A via is met exactly when its time is a node (a joint via then pins that node's coefficients; a link via
stays an augmented-Lagrangian row, evaluated at the node). ``via_fractions`` splits [0, 1] at the via
fractions into sub-intervals and shares the N elements among them, at least one each, greedily to the
sub-interval whose elements are longest (which makes the longest element as short as possible); the
elements of a sub-interval are equal. When every via already lies on a node of the uniform mesh the
shares are the uniform mesh's and the mesh stays uniform. The nodes are fractions of T, so the mesh
scales with a free T (``scaled_mesh``) and the vias stay nodes. Pure maths: no I/O.
"""
from __future__ import annotations

import numpy as np

from hoc_cli.elements import HermiteMesh

NODE_TOL = 1e-9  # a fraction s is on a node when |s − t_p/T| <= this


def node_index(s: float, mesh: HermiteMesh, tol: float = NODE_TOL) -> int | None:
    """The interior node p (0 < p < N) at the fraction s of the duration, or None when no node is there."""
    if mesh.uniform:
        p = round(s * mesh.N)
        return p if abs(s * mesh.N - p) <= tol and 0 < p < mesh.N else None
    fractions = mesh.nodes / mesh.T
    p = int(np.argmin(np.abs(fractions - s)))
    return p if abs(fractions[p] - s) <= tol and 0 < p < mesh.N else None


def via_fractions(N: int, fractions) -> np.ndarray | None:
    """Node fractions (N + 1,) from 0 to 1 with a node at each fraction in ``fractions`` (0 < s < 1),
    or None when the uniform mesh of N elements has them all.

    Raises ValueError when N is smaller than the number of sub-intervals (each needs an element).
    """
    s = np.unique(np.asarray([float(v) for v in fractions], float))
    s = s[(s > NODE_TOL) & (s < 1.0 - NODE_TOL)]
    if all(abs(v * N - round(v * N)) <= NODE_TOL for v in s):
        return None
    keep = np.concatenate([[True], np.diff(s) > NODE_TOL]) if s.size else np.zeros(0, bool)
    bounds = np.concatenate([[0.0], s[keep], [1.0]])
    lengths = np.diff(bounds)
    k = lengths.size
    if N < k:
        raise ValueError(f"{k - 1} via times split the duration into {k} intervals, each needs an element: "
                         f"expected N >= {k}, got N = {N}")
    share = np.ones(k, int)
    for _ in range(N - k):
        share[np.argmax(lengths / share)] += 1
    parts = [np.linspace(a, b, n + 1)[:-1] for a, b, n in zip(bounds[:-1], bounds[1:], share)]
    return np.concatenate(parts + [[1.0]])


def scaled_mesh(order: str, T: float, N: int, fractions: np.ndarray | None) -> HermiteMesh:
    """The mesh of N elements of [0, T] [s] with nodes at ``fractions`` · T (None: uniform)."""
    if fractions is None:
        return HermiteMesh(order, T, N)
    nodes = np.asarray(fractions, float) * T
    nodes[0], nodes[-1] = 0.0, T
    return HermiteMesh.from_nodes(order, nodes)


def via_mesh(order: str, T: float, N: int, fractions) -> HermiteMesh:
    """N elements of [0, T] [s] with a node at each fraction s in ``fractions`` (``via_fractions``)."""
    return scaled_mesh(order, T, N, via_fractions(N, fractions))


def mesh_fractions(mesh: HermiteMesh) -> np.ndarray | None:
    """The node fractions t_p/T (N + 1,) of a non-uniform mesh, None for a uniform one."""
    return None if mesh.uniform else mesh.nodes / mesh.T
