"""Constraint points: where on the mesh limits are imposed, and the linear maps C ↔ values there.

Symbols
-------
N elements, m coefficients per node, n joints, P points. A point lies in element e at local
coordinate s ∈ [0, 1]; B[r, p] (2m,) are the t-derivative-r shape-function values there
(h-scaled, as ``HermiteMesh.shape_values``). Coefficients C (N+1, m, n); element blocks of a
Newton matrix are (N, 2mn, 2mn) in the element coefficient order a·n + j (shape function a,
joint j), the order of ``hoc_cli.problem``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hoc_cli.elements import HermiteMesh


@dataclass(frozen=True, eq=False)
class PointSet:
    """P points (e, s) of a mesh with their shape-function values B (3, P, 2m) and spacing weights.

    ``weight`` (P,) [s] is the time each point stands for (h / per_element), so that penalties
    summed over points approximate integrals over time whatever the point density.
    """

    mesh: HermiteMesh
    e: np.ndarray
    s: np.ndarray
    B: np.ndarray
    weight: np.ndarray

    @classmethod
    def build(cls, mesh: HermiteMesh, e: np.ndarray, s: np.ndarray, weight: np.ndarray) -> "PointSet":
        e = np.asarray(e, dtype=int)
        s = np.asarray(s, dtype=float)
        B = np.stack([mesh.shape_values(s, r, e) for r in range(3)])
        return cls(mesh=mesh, e=e, s=s, B=B, weight=np.asarray(weight, dtype=float))

    @classmethod
    def uniform(cls, mesh: HermiteMesh, per_element: int) -> "PointSet":
        """``per_element`` equally spaced points in every element (s = j/per_element) plus t = T."""
        j = np.arange(per_element)
        e = np.concatenate([np.repeat(np.arange(mesh.N), per_element), [mesh.N - 1]])
        s = np.concatenate([np.tile(j / per_element, mesh.N), [1.0]])
        return cls.build(mesh, e, s, mesh.hs[e] / per_element)

    @property
    def size(self) -> int:
        return int(self.e.size)

    @property
    def t(self) -> np.ndarray:
        """Point times [s], (P,)."""
        return self.mesh.time_of(self.e, self.s)

    def apply(self, C: np.ndarray) -> np.ndarray:
        """q, q̇, q̈ at the points, (3, P, n), for coefficients C (N+1, m, n)."""
        loc = self.mesh.local_coefficients(self.mesh.check_coefficients(C))[self.e]  # (P, 2m, n)
        return np.einsum("rpa,pan->rpn", self.B, loc)

    def transpose(self, G: np.ndarray) -> np.ndarray:
        """Adjoint of ``apply``: sensitivities G (3, P, n) to a coefficient gradient (N+1, m, n)."""
        N, m = self.mesh.N, self.mesh.m
        n = G.shape[-1]
        per_point = np.einsum("rpa,rpn->pan", self.B, G)  # (P, 2m, n)
        gloc = np.zeros((N, 2 * m, n))
        np.add.at(gloc, self.e, per_point)
        out = np.zeros((N + 1, m, n))
        out[:-1] += gloc[:, :m]
        out[1:] += gloc[:, m:]
        return out

    def transpose_q(self, Gq: np.ndarray, which: np.ndarray) -> np.ndarray:
        """``transpose`` of sensitivities to q alone, Gq (P', n) at the points ``which`` (P',; the other points' and
        the q̇, q̈ sensitivities zero): the coefficient gradient (N+1, m, n), the same numbers without the zeros.
        """
        N, m = self.mesh.N, self.mesh.m
        n = Gq.shape[-1]
        per_point = self.B[0, which][:, :, None] * Gq[:, None, :]  # (P', 2m, n)
        gloc = np.zeros((N, 2 * m, n))
        np.add.at(gloc, self.e[which], per_point)
        out = np.zeros((N + 1, m, n))
        out[:-1] += gloc[:, :m]
        out[1:] += gloc[:, m:]
        return out

    def sample_blocks(self, Hs: np.ndarray, which: np.ndarray | None = None) -> np.ndarray:
        """Σ_p Ã_pᵀ Hs_p Ã_p over points: element blocks (N, 2mn, 2mn) of per-point Hessians in (q, q̇, q̈).

        Hs (P', 3n, 3n) for the points ``which`` (indices, default all); Ã_p = B_p ⊗ I_n.
        """
        idx = np.arange(self.size) if which is None else np.asarray(which, dtype=int)
        N, m = self.mesh.N, self.mesh.m
        n = Hs.shape[-1] // 3
        H5 = Hs.reshape(-1, 3, n, 3, n)
        B = self.B[:, idx]  # (3, P', 2m)
        per = np.einsum("rpa,prjsl,spb->pajbl", B, H5, B)  # (P', 2m, n, 2m, n)
        blocks = np.zeros((N, 2 * m, n, 2 * m, n))
        np.add.at(blocks, self.e[idx], per)
        return blocks.reshape(N, 2 * m * n, 2 * m * n)
