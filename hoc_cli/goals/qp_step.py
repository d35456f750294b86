"""One SQP step of a warm replan: the inequality-constrained quadratic programme, solved exactly and densely.

The replan's unknowns are few (P ≈ 100-300 free coefficients, plus T when it is free), so its quadratic
model is solved with dense linear algebra. With the model's matrix H = UᵀU (Cholesky), the programme

    min_d  gᵀd + ½ dᵀHd    subject to   E d = e   (goal rows, linearised),   A d ≤ b   (limit rows)

becomes, in y = U d, the least-distance problem min ½‖y − y0‖² (y0 = −U⁻ᵀg) over the same rows. The
equalities are eliminated with an orthonormal basis Z of the null space of EU⁻¹ (y = y_p + Z z, y_p the
minimum-norm solution, which is orthogonal to Z), leaving min ½‖u‖² subject to G u ≥ h with z = Zᵀy0 + u;
that least-distance programme is solved by one non-negative least-squares problem (Lawson & Hanson,
"Solving Least Squares Problems", 1974, ch. 23): w ≥ 0 minimising ‖[Gᵀ; hᵀ] w − (0, …, 0, 1)‖ gives
u = Gᵀμ with μ = w / (1 − hᵀw), the rows' multipliers. Lawson-Hanson is an active-set method with finite
termination that is indifferent to linearly dependent active rows (a limit active along a whole element makes
its Bernstein rows dependent), so the step's working set is exact at every step: no multiplier rounds.
Pure maths: no I/O.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, lstsq, qr, solve_triangular
from scipy.linalg.lapack import dormqr, dpotrf, dtrtrs

from hoc_cli.errors import NumericalError
from hoc_cli.optimize.nnls import nnls as warm_nnls

NNLS_ITER = 50  # Lawson-Hanson iterations per row of the least-distance programme before it is given up
KKT_RTOL = 1e-9  # an NNLS answer's dual v_j above this × ‖M_j‖ × ‖residual‖ (or in size, where w_j > 0): not a minimiser


@dataclass(frozen=True, eq=False)
class QPStep:
    """The step d (P,), the equality rows' multipliers ν (r,), the inequality rows' μ (k,) ≥ 0, and the
    model's decrease −(gᵀd + ½dᵀHd) ≥ 0.
    """

    d: np.ndarray
    nu: np.ndarray
    mu: np.ndarray
    decrease: float


def upper_factor(H: np.ndarray) -> np.ndarray:
    """The upper Cholesky factor U of H = UᵀU (P, P); ``NumericalError`` when H is not positive definite."""
    if not (isinstance(H, np.ndarray) and H.dtype == np.float64 and H.ndim == 2 and H.size and H.shape[0] == H.shape[1]):
        try:
            return np.triu(cho_factor(H, lower=False, check_finite=False)[0])
        except np.linalg.LinAlgError:
            raise NumericalError("the replan's quadratic model is not positive definite") from None
    # LAPACK's dpotrf as ``cho_factor`` calls it (the same numbers), its lower triangle zeroed, C-ordered as np.triu's
    # result (the triangular solves take the same path), without SciPy's argument checks
    U, info = dpotrf(H, lower=0, clean=1)
    if info != 0:
        raise NumericalError("the replan's quadratic model is not positive definite")
    return np.ascontiguousarray(U)


def bordered_factor(U: np.ndarray, b: np.ndarray, h: float) -> np.ndarray:
    """The upper factor of [[UᵀU, b], [bᵀ, h]] from U's (one more row and column); ``NumericalError`` when
    that matrix is not positive definite.
    """
    v = solve_triangular(U, b, trans="T", check_finite=False)
    s = h - float(v @ v)
    if not s > 0:
        raise NumericalError("the replan's quadratic model is not positive definite")
    P = U.shape[0]
    out = np.zeros((P + 1, P + 1))
    out[:P, :P], out[:P, P], out[P, P] = U, v, np.sqrt(s)
    return out


def solve_qp(U: np.ndarray, g: np.ndarray, E: np.ndarray, e: np.ndarray, A: np.ndarray, b: np.ndarray,
             programme: "Programme | None" = None, keys: np.ndarray | None = None) -> QPStep:
    """Min gᵀd + ½dᵀHd subject to E d = e and A d ≤ b (see the module docstring).

    Parameters
    ----------
    U : (P, P) the upper Cholesky factor of the symmetric positive definite H = UᵀU (``upper_factor``), or None for
        H = I (a projection: no triangular solves).
    g : (P,)
    E, e : (r, P), (r,) equality rows (r may be 0; dependent rows are allowed when consistent).
    A, b : (k, P), (k,) inequality rows (k may be 0).
    programme : ``Programme(U, g, E)`` when the caller keeps one (its work is shared with the caller's other
        programmes of the same U, g, E: the same result).
    keys : (k,) int, one key per row of A, with a keyed ``programme`` (``Programme(..., keyed=True)``).

    Raises
    ------
    NumericalError
        The rows admit no step, or the least-distance programme did not converge in ``NNLS_ITER`` iterations per
        row (the callers end their steps there with a status, as after any failed step).
    """
    el = programme if programme is not None else Programme(U, g, E)
    y_p = el.particular(e)
    if not A.shape[0]:
        return el.step(A, np.zeros(0), np.zeros(0), np.ones(0), 1.0, y_p)
    M, scale, size = el.rows(A, b, y_p, keys=keys)
    w = (_cold_nnls(M, repair=True) if el.keyed else _cold_nnls(M))
    return el.step(A, w, M @ w - _unit(M), scale, size, y_p)


def _unit(M: np.ndarray) -> np.ndarray:
    """The least-distance programme's right-hand side f = (0, …, 0, 1) (m,)."""
    f = np.zeros(M.shape[0])
    f[-1] = 1.0
    return f


def _cold_nnls(M: np.ndarray, repair: bool = False) -> np.ndarray:
    """The w ≥ 0 minimising ‖M w − f‖ from no active row, its cap ``NNLS_ITER`` per column: scipy's Lawson-Hanson
    (compiled), its answer kept when it meets the KKT conditions (``_minimises``), else ``hoc_cli.optimize.nnls``'s.
    SciPy's reimplementation (1.15 on) can end at a point that is not the minimiser, without a warning
    (scipy/scipy#25389): on the lbr7 catch's programme at its own optimum (``hoc plan --init`` from its plan) SciPy
    1.17.1's returned a step that broke its rows by 0.018 and raised the model by 3.9, where the minimiser is the
    zero step; hoc's own NNLS finds it. ``repair``: hoc's starts from SciPy's passive set (its columns with w > 0,
    a guess: those whose least-squares entries are not positive leave first) instead of none (the real-time steps:
    on the lbr7 catch's updates 14 iterations instead of 33, the same minimiser), and refactors the columns after one
    that leaves by one small QR (``nnls(..., retriangulate=True)``: the same iterates to rounding, fewer numpy calls).
    """
    from scipy.optimize import nnls  # imported on first use (0.25 s)

    cap = max(1, NNLS_ITER * M.shape[1])
    f = _unit(M)
    try:
        w = nnls(M, f, maxiter=cap)[0]
    except RuntimeError:  # its iteration cap (scipy raises): hoc's, with the same cap, decides
        w = None
    if w is not None and _minimises(M, f, w):
        return w
    try:
        return warm_nnls(M, f, passive=np.flatnonzero(w > 0.0) if repair and w is not None else None, max_iter=cap,
                         retriangulate=repair).w
    except NumericalError:  # the callers' failed step, not a crash
        raise NumericalError(f"the replan's quadratic programme did not converge in {cap} iterations") from None


def _minimises(M: np.ndarray, f: np.ndarray, w: np.ndarray) -> bool:
    """Whether w (k,) meets the KKT conditions of min ‖M w − f‖ over w ≥ 0 to ``KKT_RTOL``: w ≥ 0, and the dual
    v = Mᵀ(f − M w) at most ``KKT_RTOL``·‖M_j‖·‖f − M w‖ everywhere, and as small in size where w > 0.
    """
    r = f - M @ w
    v = M.T @ r
    tol = KKT_RTOL * np.linalg.norm(M, axis=0) * max(float(np.linalg.norm(r)), 1e-300)
    return bool(np.all(w >= 0.0) and np.all(v <= tol) and np.all(np.abs(v[w > 0.0]) <= tol[w > 0.0]))


def _reflect(Qr: np.ndarray, tau: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Qᵀ X (m, k) for Q the product of the Householder reflectors (Qr (m, j), tau (j,)) of a QR in LAPACK's form."""
    out, _, info = dormqr("L", "T", Qr, tau, np.asfortranarray(X), max(1, 64 * X.shape[1]))
    if info != 0:
        raise NumericalError("the replan's limit rows could not be transformed")
    return out


def _solve_upper(U: np.ndarray | None, X: np.ndarray, trans: str) -> np.ndarray:
    """U⁻¹ X (``trans`` "N") or U⁻ᵀ X ("T") for the upper triangular U (P, P), X (P,) or (P, k); U None: the identity
    (X itself, the same numbers as a triangular solve with the identity).
    """
    if U is None:
        return X
    if not (U.dtype == X.dtype == np.float64 and U.ndim == 2 and X.size and X.shape[0] == U.shape[0]):
        return solve_triangular(U, X, trans=trans, check_finite=False)
    # LAPACK's dtrtrs as ``solve_triangular`` calls it (the same call, hence the same numbers), without its argument
    # checks and batching wrapper: each programme makes a few such solves of small systems
    t = 1 if trans == "T" else 0
    if U.flags.f_contiguous:
        x, info = dtrtrs(U, X, lower=0, trans=t)
    else:  # the transposed system, as SciPy solves it for a C-ordered U
        x, info = dtrtrs(U.T, X, lower=1, trans=1 - t)
    if info != 0:
        raise np.linalg.LinAlgError(f"singular triangular factor (dtrtrs info {info})")
    return x


class Programme:
    """The programmes of one model (U, g) and one set of equality rows E (module docstring): the equality rows
    eliminated once, y = U d = y_p + Z z, z = z0 + u (y_p, the particular part, per right-hand side e), and the
    last inequality rows A transformed once (A U⁻¹, their least-distance rows): what a programme's rounds over
    more rows and its second-order correction (other e and b, the same A) share. U, g, E and the A passed are
    not to be changed while the object is in use.
    """

    def __init__(self, U: np.ndarray, g: np.ndarray, E: np.ndarray, keyed: bool = False) -> None:
        self.U, self.g, self.E = U, g, E
        self.keyed = keyed
        y0 = -_solve_upper(U, g, "T")
        self._raw = None  # keyed: the Householder reflectors of Q (Eh.T = Q R Πᵀ), the rank, R and Π
        if E.shape[0]:
            self.Eh = _solve_upper(U, E.T, "T").T  # E U⁻¹ (r, P)
            if keyed:
                (Qr, tau), R, perm = qr(self.Eh.T, pivoting=True, mode="raw", check_finite=False)
                rank = int(np.sum(np.abs(np.diag(R)) > 1e-12 * max(abs(R[0, 0]), 1e-300))) if R.size else 0
                self._raw = (Qr, tau, rank, R, perm)
                self.Z = None
                self.z0 = self._apply_q(y0[:, None], "T")[rank:, 0]
            else:
                Q, R, _ = qr(self.Eh.T, pivoting=True)  # Eh.T = Q R Πᵀ
                rank = int(np.sum(np.abs(np.diag(R)) > 1e-12 * max(abs(R[0, 0]), 1e-300))) if R.size else 0
                self.Z = Q[:, rank:]
        else:  # no equality rows: Z = I, whose products are skipped (the same numbers)
            self.Eh, self.Z, self.z0 = None, None, y0
        if self.Z is not None:
            self.z0 = self.Z.T @ y0
        self._A: np.ndarray | None = None
        self._rows: tuple = ()
        self._slot: dict = {}  # keyed: the buffer column of each row key transformed so far
        self._buf: tuple = ()  # keyed: (Ahᵀ (P, c), Gᵀ normalised (P − rank, c), norms (c,), A U⁻¹ Z z0 (c,))
        self._basis: tuple | None = None  # keyed: (touched columns T (t,), B = Zᵀ U⁻ᵀ I_T (P − rank, t), R_B (t, t))
        self._refl: list = []  # keyed: the Householder reflectors of B = W R_B, per block of T: (Qr, tau, row offset)
        self._basis_of = None  # keyed: the A whose touched columns ``_basis`` covers (None: not compressed)
        self._compressed = False  # keyed: whether the last ``rows`` were compressed (``step`` reads them so)

    def _apply_q(self, X: np.ndarray, trans: str) -> np.ndarray:
        """Q X (``trans`` "N") or Qᵀ X ("T") for X (P, k), by the keyed programme's Householder reflectors."""
        Qr, tau = self._raw[:2]
        X = np.asfortranarray(X)
        lwork = max(1, 64 * X.shape[1])
        out, _, info = dormqr("L", trans, Qr, tau, X, lwork)
        if info != 0:
            raise NumericalError("the replan's equality rows could not be eliminated")
        return out

    def particular(self, e: np.ndarray) -> np.ndarray:
        """y_p (P,): the minimum-norm solution of E U⁻¹ y = e (orthogonal to Z)."""
        if self.Eh is None:
            return np.zeros(self.g.size)
        if self._raw is not None and self._raw[2] == self.Eh.shape[0]:  # full row rank: y_p = Q₁ R⁻ᵀ Πᵀ e
            Qr, tau, rank, R, perm = self._raw
            c = solve_triangular(R[:rank, :rank], np.asarray(e, float)[perm], trans="T", check_finite=False)
            return self._apply_q(np.concatenate([c, np.zeros(self.g.size - rank)])[:, None], "N")[:, 0]
        return lstsq(self.Eh, e, cond=1e-12, check_finite=False)[0]

    def _transformed(self, A: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(A U⁻¹ (k, P), its part A U⁻¹ Z z0 (k,), the rows G = −A U⁻¹ Z normalised (k, P − rank), their norms (k,))."""
        if A is not self._A:
            Ah = _solve_upper(self.U, A.T, "T").T  # A U⁻¹ (k, P)
            G = -(Ah @ self.Z) if self.Z is not None else -Ah
            scale = np.maximum(np.linalg.norm(G, axis=1), 1e-300)  # rows normalised: w's scale per row
            Zz0 = self.Z @ self.z0 if self.Z is not None else self.z0
            self._A, self._rows = A, (Ah, Ah @ Zz0, G / scale[:, None], scale)
        return self._rows

    def _keyed_rows(self, A: np.ndarray, idx: np.ndarray, keys: np.ndarray) -> tuple:
        """``_transformed``'s arrays of the rows A[idx] whose keys are ``keys`` (idx.size,): each key's row transformed
        once per programme (the rows of a key must be the same in every A passed), Gᵀ and Ahᵀ as columns.
        """
        slot = self._slot
        missing = [i for i, key in enumerate(keys.tolist()) if key not in slot]
        if missing:
            rows = idx[missing]
            AhT = _solve_upper(self.U, A[rows].T, "T")  # (A U⁻¹)ᵀ (P, k')
            rank = self._raw[2] if self._raw is not None else 0
            QA = self._apply_q(AhT, "T")[rank:] if self._raw is not None else AhT  # (A U⁻¹ Z)ᵀ
            scale = np.maximum(np.sqrt(np.einsum("ij,ij->j", QA, QA)), 1e-300)
            part = self.z0 @ QA
            new = (AhT, -QA / scale, scale, part)
            c0 = len(slot)
            self._buf = new if not slot else tuple(np.concatenate([o, n], axis=-1) for o, n in zip(self._buf, new))
            for i, key in enumerate(keys[missing].tolist()):
                slot[key] = c0 + i
        pos = np.fromiter((slot[key] for key in keys.tolist()), int, keys.size)
        AhT, GsT, scale, part = self._buf
        return AhT[:, pos], GsT[:, pos], scale[pos], part[pos]

    def _touched_basis(self, A: np.ndarray) -> tuple | None:
        """The keyed programme's compression for the rows of A (k, P): (T, B, R_B) with T the columns any row of A
        touches (t,), B = Zᵀ U⁻ᵀ I_T (P − rank, t) and R_B (t, t) upper triangular with B = W R_B (W orthonormal
        columns), or None when t is above half of P − rank (the QR of B would cost what the smaller NNLS saves).
        Every least-distance column Gᵀ_j = −B A_j[T]ᵀ lies in the range of B, so ‖Gᵀ w‖ = ‖R_B A[:, T]ᵀ w‖ for every
        w: the NNLS over [R_B A[:, T]ᵀ; hᵀ] (t + 1 rows) has the NNLS over [Gᵀ; hᵀ]'s objective. The basis of a
        programme grows with the columns of the A passed: the columns an A touches outside it are appended to T
        (T is in that order, not sorted), their columns of B computed alone and R_B extended by a block column (the
        new columns reflected by the last QR's Householder reflectors, then a QR of the rows below R_B).
        """
        if A is self._basis_of:
            return self._basis
        touched = np.flatnonzero(np.any(A != 0.0, axis=0))
        old = self._basis
        new = touched if old is None else touched[~np.isin(touched, old[0])]
        if old is not None and not new.size:
            self._basis_of = A
            return old
        t0 = 0 if old is None else old[0].size
        if 2 * (t0 + new.size) > self.z0.size:  # the QR of B would cost what the smaller NNLS saves
            return None
        I_new = np.zeros((self.g.size, new.size), order="F")
        I_new[new, np.arange(new.size)] = 1.0
        X = _solve_upper(self.U, I_new, "T")  # U⁻ᵀ I_new (P, t')
        B_new = self._apply_q(X, "T")[self._raw[2]:] if self._raw is not None else X
        if old is None:
            (Qr, tau), R = qr(B_new, mode="raw", check_finite=False)
            self._refl = [(Qr, tau, 0)]
            basis = (new, B_new, R)
        else:
            Y = np.asfortranarray(B_new)
            for Qr, tau, off in self._refl:  # Qᵀ B_new by the reflectors so far
                Y[off:] = _reflect(Qr, tau, Y[off:])
            (Qr, tau), R22 = qr(Y[t0:], mode="raw", check_finite=False)
            self._refl.append((Qr, tau, t0))
            R = np.zeros((t0 + new.size, t0 + new.size))
            R[:t0, :t0], R[:t0, t0:], R[t0:, t0:] = old[2], Y[:t0], R22
            basis = (np.concatenate([old[0], new]), np.hstack([old[1], B_new]), R)
        self._basis, self._basis_of = basis, A
        return basis

    def rows(self, A: np.ndarray, b: np.ndarray, y_p: np.ndarray, size: float | None = None,
             idx: np.ndarray | None = None, keys: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, float]:
        """The least-distance rows G u ≥ h of A d ≤ b (k rows; ``idx``: of the rows A[idx] ≤ b[idx] only) as the
        NNLS matrix M = [Gᵀ; hᵀ] (P − rank + 1, k), each row divided by its scale ‖G_j‖ (k,) and h by ``size``
        (None: h's largest entry): (M, scale, size). ``keys`` (k,) int: a keyed programme's row keys of A (required
        there, ignored otherwise).
        """
        basis = self._touched_basis(A) if self.keyed else None
        self._compressed = basis is not None
        if basis is not None:  # M (t + 1, k): the rows in the touched columns' basis (``_touched_basis``)
            idx = np.arange(A.shape[0]) if idx is None else np.asarray(idx)
            cols, _, R = basis
            Ai = A[idx]
            GsT = -(R @ Ai[:, cols].T)
            scale = np.maximum(np.sqrt(np.einsum("ij,ij->j", GsT, GsT)), 1e-300)
            GsT /= scale
            h = -(b[idx] - Ai @ self._shifted(y_p))
        elif self.keyed:
            idx = np.arange(A.shape[0]) if idx is None else np.asarray(idx)
            AhT, GsT, scale, AhZz0 = self._keyed_rows(A, idx, np.asarray(keys)[idx])
            h = -(b[idx] - y_p @ AhT - AhZz0)
        else:
            Ah, AhZz0, Gs, scale = self._transformed(A)
            if idx is not None:
                Ah, AhZz0, Gs, scale, b = Ah[idx], AhZz0[idx], Gs[idx], scale[idx], b[idx]
            GsT = Gs.T
            h = -(b - Ah @ y_p - AhZz0)
        hs = h / scale
        # and h to a unit largest entry: the test of r[-1] = −1/(1 + ‖u‖²) below then reads ‖u‖ relative to
        # the rows' own size, not to the model's units (a step of 1e11 in y is as feasible as one of 1)
        if size is None:
            size = max(float(np.max(np.abs(hs))), 1e-300)
        hs = hs / size
        return np.vstack([GsT, hs[None, :]]), scale, size

    def _shifted(self, y_p: np.ndarray) -> np.ndarray:
        """U⁻¹ (y_p + Z z0) (P,): the rows' values A U⁻¹ (y_p + Z z0) at u = 0 are A times it."""
        if self.Z is not None:
            y = y_p + self.Z @ self.z0
        elif self._raw is not None:
            y = y_p + self._apply_q(np.concatenate([np.zeros(self.g.size - self.z0.size), self.z0])[:, None], "N")[:, 0]
        else:  # no equality rows: Z = I
            y = y_p + self.z0
        return _solve_upper(self.U, y, "N")

    def step(self, A: np.ndarray, w: np.ndarray, r: np.ndarray, scale: np.ndarray, size: float, y_p: np.ndarray) -> QPStep:
        """The step from the NNLS solution w (k,) ≥ 0 of the rows A (k, P) (``rows``' scale and size) and its
        residual r = M w − f, with the particular part y_p of the equality rows' right-hand side.
        """
        if A.shape[0]:
            if abs(r[-1]) < 1e-12:
                raise NumericalError("the replan's limit rows admit no step")
            if self._compressed:  # Gᵀ w = −B A[:, T]ᵀ (w / scale): u in the full null space
                cols, B, _ = self._basis
                u = (B @ (A[:, cols].T @ (w / scale))) / r[-1] * size
            else:
                u = -r[:-1] / r[-1] * size
            mu = (w / (-r[-1])) / scale * size
        else:
            u, mu = np.zeros(self.z0.size), np.zeros(0)
        U, g, E = self.U, self.g, self.E
        if self.Z is not None:
            y = y_p + self.Z @ (self.z0 + u)
        elif self._raw is not None:  # keyed: Z (z0 + u) = Q [0; z0 + u]
            y = y_p + self._apply_q(np.concatenate([np.zeros(self.g.size - self.z0.size), self.z0 + u])[:, None], "N")[:, 0]
        else:  # no equality rows: Z = I
            y = y_p + (self.z0 + u)
        d = _solve_upper(U, y, "N")
        nu = np.zeros(0)
        if E.shape[0]:
            stationarity = -((y if U is None else U.T @ y) + g + (A.T @ mu if mu.size else 0.0))
            nu = lstsq(E.T, stationarity, cond=1e-12, check_finite=False)[0]
        decrease = -float(g @ d + 0.5 * y @ y)
        return QPStep(d=d, nu=nu, mu=mu, decrease=decrease)


def solve_qp_within(U: np.ndarray, g: np.ndarray, E: np.ndarray, e: np.ndarray, A: np.ndarray, b: np.ndarray,
                    rows: np.ndarray, programme: "Programme | None" = None, keys: np.ndarray | None = None) -> QPStep:
    """``solve_qp`` over the inequality rows ``rows`` (a boolean (k,) mask) first, then with every left-out row its
    step breaks (A d > b) added, until the step breaks none: the step of ``solve_qp`` over all k rows (H is
    positive definite, so the programme's minimiser is unique; a left-out row the minimiser over the others keeps
    changes nothing; rows are only added, so it ends). The least-distance programme's cost grows with its rows,
    not its active ones, so a mask holding the active rows of a programme nearby (the last one, with the rows
    added since) makes the step cheaper. The rounds share the equality rows' elimination and the rows already
    transformed; each round after the first continues the last one's Lawson-Hanson iterations from its passive
    set (``hoc_cli.optimize.nnls``: that set's least-squares solution is still positive, only the rows added can
    enter), instead of solving the grown programme from no active row (a keyed ``programme``, the real-time steps':
    with ``nnls(..., retriangulate=True)``).
    μ (k,) is zero at the rows left out; rows that are linearly dependent may share their multipliers differently
    from ``solve_qp``'s (they are not unique there).

    Parameters as ``solve_qp``'s, with ``rows`` (k,) bool.
    """
    el = programme if programme is not None else Programme(U, g, E)
    y_p = el.particular(e)
    idx = np.flatnonzero(np.asarray(rows, bool))  # the rows in the programme, in M's column order
    if idx.size == 0:
        step = el.step(A[idx], np.zeros(0), np.zeros(0), np.ones(0), 1.0, y_p)
        M = None
    else:
        M, scale, size = el.rows(A, b, y_p, idx=idx, keys=keys)
        w = (_cold_nnls(M, repair=True) if el.keyed else _cold_nnls(M))
        step = el.step(A[idx], w, M @ w - _unit(M), scale, size, y_p)
    used = np.zeros(b.size, bool)
    used[idx] = True
    while True:
        out = np.flatnonzero(~used)
        if not out.size:
            break
        Ad = A[out] @ step.d
        broken = Ad - b[out] > 1e-12 * (np.abs(A[out]) @ np.abs(step.d) + np.abs(b[out]) + 1.0)
        if not broken.any():
            break
        new = out[broken]
        idx = np.concatenate([idx, new])
        used[new] = True
        if M is None:  # no row yet: the programme of the rows added, from no active row
            M, scale, size = el.rows(A, b, y_p, idx=new, keys=keys)
            w = (_cold_nnls(M, repair=True) if el.keyed else _cold_nnls(M))
            r = M @ w - _unit(M)
        else:
            M_new, scale_new, _ = el.rows(A, b, y_p, size, idx=new, keys=keys)
            M, scale = np.hstack([M, M_new]), np.concatenate([scale, scale_new])
            top = float(np.max(np.abs(M_new[-1])))
            if top > 1.0:  # h to a unit largest entry over the grown rows (the start repairs its passive set)
                M[-1] /= top
                size *= top
            cap = max(1, NNLS_ITER * M.shape[1])
            try:
                res = warm_nnls(M, _unit(M), passive=np.flatnonzero(w > 0.0), max_iter=cap, retriangulate=el.keyed)
            except NumericalError:
                raise NumericalError(f"the replan's quadratic programme did not converge in {cap} iterations") from None
            w, r = res.w, res.residual
        step = el.step(A[idx], w, r, scale, size, y_p)
    mu = np.zeros(A.shape[0])
    mu[idx] = step.mu
    return QPStep(d=step.d, nu=step.nu, mu=mu, decrease=step.decrease)
