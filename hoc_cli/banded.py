"""Block-banded symmetric matrices on the Hermite coefficients: element blocks, assembly, Cholesky.

Each element couples only its two nodes, so a matrix summed from per-element blocks (N, 2mn, 2mn)
placed at offsets e·mn has half-bandwidth 2mn − 1 in the global coefficient order
g = p·m·n + d·n + i (node p, derivative d, joint i; see ``hoc_cli.problem``). ``element_blocks``
turns per-sample Hessians in (q, q̇, q̈) into such blocks; ``BandedSPD.assemble`` sums, restricts to
the free coefficients and factors them. Any term of the cost (or of a penalty added to it) that
is a sum over quadrature samples contributes through these two functions.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.linalg import cho_solve_banded, cholesky_banded

from hoc_cli.elements import QuadratureOperator
from hoc_cli.errors import NumericalError


@lru_cache(maxsize=64)
def expanded_rows(op: QuadratureOperator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Ã = B ⊗ I_n at the G points of an element, (G, 3n, 2mn), and its transpose (G, 2mn, 3n).

    Read-only, cached per operator (every element has the same): row r·n + i, column a·n + j holds
    B[r, g, a] δ_ij (derivative r of (q, q̇, q̈); element coefficient order a, joint j).
    """
    G, L = op.G, op.B.shape[-1] * n
    A = np.einsum("rga,ij->griaj", op.B, np.eye(n)).reshape(G, 3 * n, L)
    AT = np.ascontiguousarray(np.swapaxes(A, 1, 2))
    A.flags.writeable = AT.flags.writeable = False
    return A, AT


def element_blocks(op: QuadratureOperator, Hs: np.ndarray) -> np.ndarray:
    """Σ_g w_g Ãᵀ Hs_g Ã per element, (N, 2mn, 2mn), for per-sample Hessians Hs (K, 3n, 3n).

    Hs[k] is the Hessian of the integrand at sample k in (q, q̇, q̈) (each block n × n, in that
    order); K = N·G samples of ``op`` in element-major order; the quadrature weights w are applied
    here. Ã (3n, 2mn) maps an element's coefficients to (q, q̇, q̈) at a sample: two batched matmuls.
    """
    n = Hs.shape[-1] // 3
    N, G = op.mesh.N, op.G
    A, AT = expanded_rows(op, n)  # (G, 3n, 2mn), (G, 2mn, 3n): the same in every element
    Hw = (Hs * op.w[:, None, None]).reshape(N, G, 3 * n, 3 * n)
    if op.row_scale is None:
        return np.matmul(AT, np.matmul(Hw, A)).sum(axis=1)
    # non-uniform mesh: Ã_e = diag(h_e^(−r)) Ã diag(h_e^(d_a)) (``elements.element_scales``)
    rows = np.repeat(op.row_scale.T, n, axis=1)  # (N, 3n)
    cols = np.repeat(op.col_scale, n, axis=1)  # (N, 2mn)
    Hw = Hw * (rows[:, None, :, None] * rows[:, None, None, :])
    return np.matmul(AT, np.matmul(Hw, A)).sum(axis=1) * (cols[:, :, None] * cols[:, None, :])


@lru_cache(maxsize=64)
def _pair_rows(op: QuadratureOperator) -> np.ndarray:
    """B[r, g, a] B[s, g, b] as a (G·9, 4m²) matrix, row (g, r, s), column (a, b): ``element_blocks_kron``'s
    contraction. Read-only, cached per operator.
    """
    B = op.B
    K = np.einsum("rga,sgb->grsab", B, B).reshape(op.G * 9, -1)
    K.flags.writeable = False
    return K


def element_blocks_kron(op: QuadratureOperator, Hs: np.ndarray) -> np.ndarray:
    """``element_blocks(op, Hs)`` (N, 2mn, 2mn) by the Kronecker structure of Ã = B ⊗ I_n: block entry (a i, b j) =
    Σ_g w_g Σ_(r,s) B[r, g, a] B[s, g, b] Hs_g[r i, s j], one matrix product (4m², G·9) × (G·9, N n²) for all the
    elements, without the products with the zeros of Ã (about a seventh of the arithmetic at n = 7). The same
    numbers to rounding (another order of the sums).
    """
    n = Hs.shape[-1] // 3
    N, G = op.mesh.N, op.G
    L = op.B.shape[-1]
    Hw = (Hs * op.w[:, None, None]).reshape(N, G, 3 * n, 3 * n)
    if op.row_scale is not None:  # non-uniform mesh, as ``element_blocks``
        rows = np.repeat(op.row_scale.T, n, axis=1)  # (N, 3n)
        Hw = Hw * (rows[:, None, :, None] * rows[:, None, None, :])
    H6 = Hw.reshape(N, G, 3, n, 3, n).transpose(1, 2, 4, 0, 3, 5).reshape(G * 9, N * n * n)  # (g r s, e i j)
    out = (_pair_rows(op).T @ H6).reshape(L, L, N, n, n).transpose(2, 0, 3, 1, 4).reshape(N, L * n, L * n)
    if op.row_scale is None:
        return out
    cols = np.repeat(op.col_scale, n, axis=1)  # (N, 2mn)
    return out * (cols[:, :, None] * cols[:, None, :])


@lru_cache(maxsize=16)
def _pattern(E: int, L: int, stride: int, size: int, free: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Where ``BandedSPD.assemble`` puts E element blocks (L, L) at offsets e·stride in the upper band storage
    (L, size), for the free mask ``free`` (its bytes, bool (size,)): (a, b) the upper-triangle indices of a block,
    flat (E·L(L+1)/2,) each entry's index in the storage raveled, keep (L, size) the storage entries that touch no
    fixed coefficient. Read-only, cached: a solve assembles the same pattern at every Newton matrix.
    """
    u = L - 1
    a, b = np.triu_indices(L)
    rows = u + a - b
    cols = (np.arange(E)[:, None] * stride + b[None, :]).ravel()
    flat = np.tile(rows, E) * size + cols
    mask = np.frombuffer(free, dtype=bool)
    d = np.arange(u + 1)[:, None]
    j = np.arange(size)[None, :]
    i = j - (u - d)
    keep = (i >= 0) & mask[np.clip(i, 0, size - 1)] & mask[j]
    for x in (a, b, flat, keep):
        x.flags.writeable = False
    return a, b, flat, keep


@dataclass(frozen=True, eq=False)
class BandedSPD:
    """A symmetric positive-definite banded matrix on the free coefficients, Cholesky-factored.

    ``factor`` is the upper banded Cholesky factor (u + 1, size) of the full matrix (fixed rows and
    columns replaced by a scaled identity), ``free`` (size,) bool marks the free coefficients;
    ``solve(g)`` maps a design-space vector (free coefficients) to P⁻¹ g.
    """

    factor: np.ndarray
    free: np.ndarray
    size: int

    @classmethod
    def assemble(cls, blocks: np.ndarray, stride: int, size: int, free: np.ndarray, shift: float) -> "BandedSPD":
        """Sum diagonal blocks (E, L, L) placed at offsets e·stride; fixed rows/cols become identity.

        The free diagonal is scaled by (1 + shift) and raised by shift·(its mean), a relative
        regularisation; the fixed diagonal entries get that mean. Raises ``NumericalError`` when
        the result is not positive definite.
        """
        E, L, _ = blocks.shape
        u = L - 1
        a, b, flat, keep = _pattern(E, L, stride, size, np.asarray(free, dtype=bool).tobytes())
        ab = np.bincount(flat, weights=blocks[:, a, b].ravel(), minlength=(u + 1) * size).reshape(u + 1, size)
        ab = np.where(keep, ab, 0.0)
        diag = ab[u]
        scale = float(np.mean(diag[free])) if free.any() else 1.0
        ab[u] = np.where(free, diag * (1.0 + shift) + shift * scale, scale)
        try:
            factor = cholesky_banded(ab, lower=False)
        except np.linalg.LinAlgError:
            raise NumericalError("the Gauss-Newton matrix is not positive definite") from None
        return cls(factor=factor, free=free, size=size)

    def solve(self, g: np.ndarray) -> np.ndarray:
        """P⁻¹ g for g (P_free,) on the free coefficients; returns (P_free,)."""
        full = np.zeros(self.size)
        full[self.free] = g
        return cho_solve_banded((self.factor, False), full, check_finite=False)[self.free]
