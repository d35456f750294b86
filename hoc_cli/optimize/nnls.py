"""Non-negative least squares from a given passive set (Lawson & Hanson's active-set method).

Symbols: M (m, k) the matrix, f (m,) the right-hand side, w (k,) ≥ 0 the unknowns minimising ‖M w − f‖; the
passive set S holds the columns with w > 0, the dual vector v = Mᵀ(f − M w) (k,) (v ≤ 0 off S, = 0 on S at the
solution).

The method is Lawson & Hanson's ("Solving Least Squares Problems", 1974, ch. 23, algorithm NNLS): the column with
the largest positive v enters S, the least-squares solution z over S is taken, and while z has a non-positive
entry the iterate moves from w towards z as far as it stays non-negative and the entries that reach zero leave
S; it ends when no column off S has v > 0 (the KKT conditions). Any passive set whose least-squares solution is
positive is a valid start (the residual then decreases strictly at every entering column, so the method still
ends): the passive set of the same problem with fewer columns (a least-distance programme with rows added,
``hoc_cli.goals.qp_step.solve_qp_within``) is one, and from it only the columns that change it are visited.
A given passive set whose least-squares solution has non-positive entries (a guess) loses those entries until it
is positive. The least-squares solutions come from a thin QR factor of M's columns in S (Householder for a given
set), extended by one Gram-Schmidt column (orthogonalised twice) when a column enters; when columns leave, the
factor of the columns before the first one that left is kept and the later ones are appended again (or, with
``retriangulate``, refactored at once by one small QR of their rows of R).

A column enters only when its part orthogonal to the columns in S exceeds ``DEPENDENT`` of its norm and its
least-squares entry is positive, as in Lawson & Hanson's test: a column that fails is passed over at that
iteration (a linearly dependent column, e.g. one of two equal rows of a least-distance programme, never enters
next to the other). Pure maths: no I/O.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg.lapack import dtrtrs

from hoc_cli.errors import NumericalError

DEPENDENT = 1e-12  # a column whose part orthogonal to S is below this fraction of its norm does not enter
DUAL_RTOL = 1e-13  # v_j ≤ this × ‖M_j‖ × ‖f − M w‖: no column enters (the rounding of v)


@dataclass(frozen=True, eq=False)
class NNLSResult:
    """w (k,) ≥ 0, the residual M w − f (m,), the passive set (its column indices, (p,) int) and the iterations
    (columns entered plus inner steps).
    """

    w: np.ndarray
    residual: np.ndarray
    passive: np.ndarray
    iterations: int


class _ThinQR:
    """M[:, S] = Q R for an ordered column list S (Q (m, p) orthonormal columns, R (p, p) upper triangular), in
    buffers of m columns, with Qᵀf (p,) for the least-squares solutions.
    """

    def __init__(self, MT: np.ndarray, f: np.ndarray, cols: list[int], retriangulate: bool = False) -> None:
        self.MT, self.f = MT, f  # MT (k, m): M's columns as contiguous rows
        self.retriangulate = retriangulate  # ``keep``: one small QR instead of appending the later columns again
        m = MT.shape[1]
        self.Q = np.zeros((m, m), order="F")
        self.R = np.zeros((m, m), order="F")
        self.qf = np.zeros(m)
        self.refactor(cols)

    def refactor(self, cols: list[int]) -> None:
        """The factor of ``cols`` (at most m; Householder QR)."""
        self.cols = list(cols)
        p = len(self.cols)
        if p:
            Q, R = np.linalg.qr(self.MT[self.cols].T)
            self.Q[:, :p], self.R[:p, :p] = Q, R
            self.qf[:p] = Q.T @ self.f

    def keep(self, mask: np.ndarray) -> None:
        """The columns where ``mask`` (p,) holds kept, in order: the factor of the columns before the first one
        dropped is unchanged; the later ones are appended again (they stay independent: a subset), or, ``retriangulate``,
        their rows first..p of R (an upper Hessenberg-like block B, (p − first, L)) are factored B = Q_B R_B once and
        Q's columns first..p turned by Q_B (the same factor to rounding, one small QR instead of L appends).
        """
        first = int(np.argmin(mask))
        p = len(self.cols)
        idx = [i for i in range(first, p) if mask[i]]
        later = [self.cols[i] for i in idx]
        self.cols = self.cols[:first]
        if not self.retriangulate:
            for c in later:
                self.append(c, check=False)
            return
        L = len(idx)
        if L:
            QB, RB = np.linalg.qr(self.R[first:p, idx])  # (p − first, L), (L, L)
            self.R[:first, first:first + L] = self.R[:first, idx]
            self.R[first:first + L, first:first + L] = RB
            self.Q[:, first:first + L] = self.Q[:, first:p] @ QB
            self.qf[first:first + L] = QB.T @ self.qf[first:p]
        self.cols += later

    def append(self, j: int, check: bool = True) -> bool:
        """Column j appended (classical Gram-Schmidt, twice); False (nothing changed) when it is dependent (tested
        when ``check``).
        """
        a = self.MT[j]
        p = len(self.cols)
        Q = self.Q[:, :p]
        c = Q.T @ a
        v = a - Q @ c
        c2 = Q.T @ v
        v -= Q @ c2
        rho = float(np.sqrt(v @ v))
        if check and not rho > DEPENDENT * float(np.sqrt(a @ a)):
            return False
        v /= rho
        self.Q[:, p] = v
        self.R[:p, p] = c + c2
        self.R[p, p] = rho
        self.R[p, :p] = 0.0
        self.qf[p] = v @ self.f
        self.cols.append(j)
        return True

    def drop_last(self) -> None:
        self.cols.pop()

    def solve(self) -> np.ndarray:
        """The least-squares solution (p,) of M[:, S] z ≈ f."""
        p = len(self.cols)
        if not p:
            return np.zeros(0)
        z, _ = dtrtrs(self.R[:p, :p], self.qf[:p])
        return z

    def residual(self) -> np.ndarray:
        """The residual f − M[:, S] z (m,) at the least-squares solution z: f − Q Qᵀf."""
        p = len(self.cols)
        return self.f - self.Q[:, :p] @ self.qf[:p]


def nnls(M: np.ndarray, f: np.ndarray, passive: np.ndarray | None = None, max_iter: int | None = None,
         retriangulate: bool = False) -> NNLSResult:
    """Min ‖M w − f‖ over w ≥ 0 (module docstring), from the passive set ``passive`` (column indices (p,) int, e.g.
    the last solution's over fewer columns; None: empty, Lawson & Hanson's own start).

    M : (m, k); f : (m,); max_iter : columns entered plus inner steps at most (3k when None);
    retriangulate : when columns leave S, the factor of the later ones by one small QR of their rows of R (``_ThinQR.keep``)
        instead of appending them again one by one: the same iterates to rounding, fewer numpy calls (the real-time
        steps: hoc's Lawson-Hanson's time is mostly those appends).
    Raises ``NumericalError`` when the iterations run out.
    """
    M = np.asarray(M, float)
    f = np.asarray(f, float)
    m, k = M.shape
    max_iter = 3 * k if max_iter is None else max_iter
    norms = np.linalg.norm(M, axis=0)
    iterations = 0
    MT = np.ascontiguousarray(M.T)
    cols = [] if passive is None else [int(j) for j in passive]
    p = len(cols)
    qrf = _ThinQR(MT, f, cols if p <= m else [], retriangulate)
    if p and not (p <= m and np.all(np.abs(np.diag(qrf.R[:p, :p])) > DEPENDENT * norms[cols])):
        qrf.refactor([])  # dependent columns: appended one by one, each dependent one left out
        for j in cols:
            qrf.append(j)
    z = qrf.solve()
    while z.size and np.min(z) <= 0.0:  # rounding: the least-squares solution over S positive
        qrf.keep(z > 0.0)
        z = qrf.solve()
        iterations += 1
    x = z
    r = qrf.residual()
    out = np.zeros(k, bool)  # S and the columns passed over since the last one entered
    out[qrf.cols] = True
    while k:
        v = MT @ r
        v[out] = -np.inf
        j = int(np.argmax(v))
        if not v[j] > DUAL_RTOL * norms[j] * float(np.sqrt(r @ r)):
            break
        iterations += 1
        if iterations > max_iter:
            raise NumericalError(f"non-negative least squares did not converge in {max_iter} iterations")
        out[j] = True
        if not qrf.append(j):
            continue
        z = qrf.solve()
        if not z[-1] > 0.0:  # rounding: the column does not enter
            qrf.drop_last()
            continue
        x = np.append(x, 0.0)
        while np.min(z) <= 0.0:  # move towards z while w ≥ 0; the entries reaching zero leave S
            iterations += 1
            if iterations > max_iter:
                raise NumericalError(f"non-negative least squares did not converge in {max_iter} iterations")
            neg = z <= 0.0
            ratio = np.full(z.size, np.inf)
            ratio[neg] = x[neg] / (x[neg] - z[neg])
            i = int(np.argmin(ratio))
            x = x + ratio[i] * (z - x)
            keep = x > 0.0
            keep[i] = False
            qrf.keep(keep)
            x = x[keep]
            z = qrf.solve()
        x = z
        r = qrf.residual()
        out[:] = False
        out[qrf.cols] = True
    w = np.zeros(k)
    w[qrf.cols] = x
    return NNLSResult(w=w, residual=M @ w - f, passive=np.array(qrf.cols, int), iterations=iterations)
