"""Layout and per-model constants of the :mod:`hoc_cli.dynamics` kernels: input checks, chunk
sizes, the sample-axis-last storage with its row permutation, the joint generators D and the
stacked constant matrices of every joint step. See the package docstring for the symbols.
"""
from __future__ import annotations

import weakref

import numpy as np

from ..model.tree import RobotModel

#: samples processed together. Bounds the temporaries: every body's arrays are allocated together,
#: and above a few MB per array the allocator hands back fresh pages on every call (page faults
#: cost more than the arithmetic). Tuned on a 7-DOF arm, 2-core x86 machine, inside the planner.
ID_CHUNK = 512      # inverse_dynamics, bias_forces, gravity_forces
DERIV_CHUNK = 512   # id_derivatives at n ≤ 7 (scratch ∝ n² K): DERIV_CHUNK · 49 / n² samples above
JAC_MIN_K = 32      # id_derivatives: below, the plain n-seed reverse sweep (fewer numpy calls)
MASS_CHUNK = 512    # mass_matrix, forward_dynamics, covariant_gradient_terms: n columns per body
VJP_CHUNK = 1024    # id_vjp, mass_quadratic_grad: one seed (the cost Hessian sweep's 15 copies of 48 samples: one chunk)


# --------------------------------------------------------------------------- input checking
def _batch(model: RobotModel, name: str, x) -> np.ndarray:
    """(K, n) float array from (K, n) or (n,) input; ValueError naming the argument otherwise."""
    arr = np.asarray(x, dtype=float)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != model.n:
        raise ValueError(f"{name}: expected shape (K, {model.n}) or ({model.n},) for joints "
                         f"{list(model.joint_names)}, got {np.shape(x)}")
    return arr


def _inputs(model: RobotModel, **arrays):
    """Check every array, require a common K; returns (list of (n, K) contiguous arrays, K, 1-D?)."""
    out = []
    K = None
    one_d = all(np.ndim(v) == 1 for v in arrays.values())
    for name, value in arrays.items():
        arr = _batch(model, name, value)
        if K is None:
            K = arr.shape[0]
        elif arr.shape[0] != K:
            first = next(iter(arrays))
            raise ValueError(f"{name}: has {arr.shape[0]} samples but {first} has {K}")
        out.append(np.ascontiguousarray(arr.T))
    return out, K, one_d


def _shape_out(x: np.ndarray, one_d: bool) -> np.ndarray:
    return x[0] if one_d else x


# A spatial motion or force of a body is 6 rows in the order (x, y, z) × (angular, linear):
# rows 0-3 are the x/y components that a joint's rotation mixes, rows 4-5 the z components. The
# constant 6 × 6 transforms and inertias are permuted to match. Per body, arrays are stored
# (rows, channels, [seeds,] K): channels are velocity/acceleration/unit-acceleration columns, K the
# samples (contiguous), so that every constant matrix applies as one BLAS product on (rows, ·).
#
# The q-dependent part of joint i acts on the x/y rows only. Into the moved frame (motions, and the
# force adjoints of the reverse sweep): m = α y + β D y; out of it (forces, motion adjoints):
# F ← α F + β Dᵀ F, with (α, β) = (cos q, sin q) for a revolute joint and (1, q) for a prismatic one,
# and D a constant 4 × 4 generator (revolute: (Dm)_x = m_y, (Dm)_y = −m_x; prismatic: the linear
# x/y rows get ±q × the angular y/x rows). ∂m/∂q = D m, and the joint-velocity term of the
# acceleration is q̇ D v. Each constant transform is stacked with its D product, so a joint step is
# one BLAS product (10 × 6 or 6 × 10) plus two or three element-wise operations.
_PERM = np.array([0, 3, 1, 4, 2, 5])


_XY = slice(0, 4)


_PI1 = np.array([1, 2, 0])  # (a × b)_x = a_π1 b_π2 − a_π2 b_π1


_PI2 = np.array([2, 0, 1])


def _perm_rows(M9: np.ndarray, perm: np.ndarray) -> np.ndarray:
    """Rows 3·x + j of a (9, ·) matrix with the xyz index x replaced by perm[x]."""
    return M9.reshape(3, 3, -1)[perm].reshape(9, -1)


def _selection(M: np.ndarray) -> np.ndarray:
    """The column of the single 1 in each row of a 0/1 matrix M (r, c) whose rows each hold one: (r,) indices."""
    assert np.all((M == 0) | (M == 1)) and np.all(M.sum(axis=1) == 1)
    return np.ascontiguousarray(np.argmax(M, axis=1))


class _Consts:
    """Per-model constants of the kernels, computed once per model (cached weakly by model)."""

    def __init__(self, model: RobotModel) -> None:
        n = model.n
        ix = np.ix_(_PERM, _PERM)
        X = [np.asarray(Xi)[ix] for Xi in model.tree_motion]
        I = [np.asarray(Ii)[ix] for Ii in model.inertia]
        self.n = n
        self.prism = [t == "prismatic" for t in model.joint_types]
        self.rev = [not p for p in self.prism]
        self.t = [1 if p else 0 for p in self.prism]  # joint axis: angular (0) or linear (1) z
        self.zrow = np.array([4 + t for t in self.t], dtype=np.intp)
        self.order = [int(i) for i in model.order]
        self.parent = [int(p) for p in model.parent]
        self.ar = np.arange(n)
        # generators D (6 × 6, acting on the x/y rows) and the (2, 2) sign patterns of their
        # (reversed-view) application, see _dview
        self.sgn = np.zeros((n, 2, 2))
        self.sgnT = np.zeros((n, 2, 2))
        D = np.zeros((n, 6, 6))
        for i in range(n):
            if self.prism[i]:
                D[i, 1, 2], D[i, 3, 0] = 1.0, -1.0
                self.sgn[i] = [[0.0, 1.0], [0.0, -1.0]]
                self.sgnT[i] = [[-1.0, 0.0], [1.0, 0.0]]
            else:
                D[i, 0, 2] = D[i, 1, 3] = 1.0
                D[i, 2, 0] = D[i, 3, 1] = -1.0
                self.sgn[i] = [[1.0, 1.0], [-1.0, -1.0]]
                self.sgnT[i] = [[-1.0, -1.0], [1.0, 1.0]]
        # gather form of D and Dᵀ on the x/y rows, for operations on all bodies at once
        self.src = np.zeros((n, 4), dtype=np.intp)
        self.srcT = np.zeros((n, 4), dtype=np.intp)
        self.sg4 = np.zeros((n, 4))
        self.sgT4 = np.zeros((n, 4))
        for i in range(n):
            for r in range(4):
                for c in range(4):
                    if D[i, r, c]:
                        self.src[i, r], self.sg4[i, r] = c, D[i, r, c]
                        self.srcT[i, c], self.sgT4[i, c] = r, D[i, r, c]
        self.ar4 = np.arange(n)[:, None]
        # joint steps: into body i, T = ZF @ m_parent, m = α T[4:8] + β T[0:4] (x/y), T[8:10] (z);
        # out of it, Xᵀ (α F + β Dᵀ F) = Zb @ (F_z, α F_xy, β F_xy)
        self.ZF = [np.ascontiguousarray(np.vstack([(D[i] @ X[i])[_XY], X[i]])) for i in range(n)]
        self.Zb = [np.ascontiguousarray(np.hstack([X[i].T[:, 4:6], X[i].T[:, _XY],
                                                   X[i].T[:, _XY] @ D[i][_XY, _XY].T])) for i in range(n)]
        base = np.zeros(6)
        base[[1, 3, 5]] = -np.asarray(model.gravity, dtype=float)
        self.zfg = [Z @ base for Z in self.ZF]  # the base's (gravity) acceleration moved into a root body
        # velocity-product force v ×* (I v) = S (A v × B v), A v = (ω, v_lin, ω) and B v = (L, p, p)
        # = rows of I v, stacked (xyz, 3); S sums (ω × L + v_lin × p, ω × p).
        A9 = np.zeros((9, 6))
        S = np.zeros((6, 9))
        for x in range(3):
            A9[3 * x, 2 * x] = A9[3 * x + 1, 2 * x + 1] = A9[3 * x + 2, 2 * x] = 1.0
            S[2 * x, 3 * x] = S[2 * x, 3 * x + 1] = S[2 * x + 1, 3 * x + 2] = 1.0
        rows = np.array([[2 * x, 2 * x + 1, 2 * x + 1] for x in range(3)]).ravel()
        St = S.T
        self.I = np.ascontiguousarray(np.stack(I)) if n else np.zeros((0, 6, 6))
        ABq, ISf, ISb, AB9T = [], [], [], []
        for i in range(n):
            B9 = I[i][rows]
            # Gq = (Bπ1, Bπ2, Aπ2, Aπ1) v: Gq[18:] * Gq[:18] = (Aπ2 Bπ1, Aπ1 Bπ2), cross = 2nd − 1st
            ABq.append(np.vstack([_perm_rows(B9, _PI1), _perm_rows(B9, _PI2),
                                  _perm_rows(A9, _PI2), _perm_rows(A9, _PI1)]))
            ISf.append(np.hstack([I[i], -S, S]))
            # adjoint: (I f̄, g_π2, g_π1, g_π1, g_π2) with g = Sᵀ f̄
            ISb.append(np.vstack([I[i], _perm_rows(St, _PI2), _perm_rows(St, _PI1),
                                  _perm_rows(St, _PI1), _perm_rows(St, _PI2)]))
            AB9T.append(np.vstack([A9, B9]).T)
        stack = (lambda L, shape: np.ascontiguousarray(np.stack(L)) if n else np.zeros((0,) + shape))
        self.ABq = stack(ABq, (36, 6))
        # A v and g = Sᵀ f̄ pick rows (each row of A9 and of Sᵀ holds a single 1): their rows of Gq and of the
        # adjoint's factors are taken by indexing, the numbers the products with those 0/1 rows give
        self.ABq18 = np.ascontiguousarray(self.ABq[:, :18])
        self.a_sel = _selection(np.vstack([_perm_rows(A9, _PI2), _perm_rows(A9, _PI1)]))  # (18,)
        self.s_sel = _selection(np.vstack([_perm_rows(St, _PI2), _perm_rows(St, _PI1),
                                           _perm_rows(St, _PI1), _perm_rows(St, _PI2)]))  # (36,)
        self.ISf = stack(ISf, (6, 24))
        self.ISb = stack(ISb, (42, 6))
        self.AB9T = stack(AB9T, (6, 18))
        # ancestors (self included); mass columns: body i carries the columns [0, hi[i]) (all its
        # ancestors), its parent's range hi_par[i]
        anc = [None] * n
        for i in self.order:
            p = self.parent[i]
            anc[i] = [i] if p < 0 else anc[p] + [i]
        self.anc = anc
        self.hi = [max(a) + 1 for a in anc]
        self.hi_par = [0 if self.parent[i] < 0 else self.hi[self.parent[i]] for i in range(n)]
        mask = np.zeros((n, n), dtype=bool)
        for i in range(n):
            mask[i, anc[i]] = True
        self.anc_mask = mask                         # [i, j]: j is i or an ancestor of i
        self.desc_mask = mask.T & ~np.eye(n, dtype=bool)  # [i, j]: j is a strict descendant of i
        self.all_rev = all(self.rev)


_CONSTS: weakref.WeakKeyDictionary[RobotModel, _Consts] = weakref.WeakKeyDictionary()


def _consts(model: RobotModel) -> _Consts:
    c = _CONSTS.get(model)
    if c is None:
        c = _CONSTS[model] = _Consts(model)
    return c


def _dview(x: np.ndarray, rev: bool) -> np.ndarray:
    """(2, 2, ...) view of the x/y rows (4, ...) reordered so that ``sgn * _dview(x)`` is D x."""
    x2 = x.reshape((2, 2) + x.shape[1:])
    return x2[::-1] if rev else x2[::-1, ::-1]


def _dall(C: _Consts, x: np.ndarray, transpose: bool = False) -> np.ndarray:
    """D x (or Dᵀ x) for the x/y rows x (n, 4, ...) of every body at once (a new array)."""
    if C.all_rev:  # D x = (x_y, −x_x); Dᵀ = −D
        y = np.empty(x.shape)
        if transpose:
            np.negative(x[:, 2:4], out=y[:, 0:2])
            y[:, 2:4] = x[:, 0:2]
        else:
            y[:, 0:2] = x[:, 2:4]
            np.negative(x[:, 0:2], out=y[:, 2:4])
        return y
    if transpose:
        src, sg = C.srcT, C.sgT4
    else:
        src, sg = C.src, C.sg4
    y = x[C.ar4, src]
    y *= sg.reshape(sg.shape + (1,) * (x.ndim - 2))
    return y


def _sx(x: np.ndarray, S: int) -> np.ndarray:
    """View the merged (seeds × samples) last axis as (S, K) when there are several seeds."""
    return x if S == 1 else x.reshape(x.shape[:-1] + (S, -1))


def _kx(g: np.ndarray, S: int) -> np.ndarray:
    """A per-sample factor (..., K) broadcast over the seeds of a _sx view."""
    return g if S == 1 else g[..., None, :]


def _cos_sin(q: np.ndarray, out: np.ndarray | None = None):
    """(cos q, sin q) from t = tan(q/2): c = (1 − t²)/(1 + t²), s = 2t/(1 + t²); within
    3e-16 of np.cos/np.sin (checked for |q| ≤ 1000 rad) and about 3× faster than calling both.
    With ``out`` (2, ...) the pair is written there.
    """
    t = np.tan(0.5 * q)
    t2 = t * t
    d = 1.0 / (1.0 + t2)
    if out is None:
        out = np.empty((2,) + q.shape)
    c, s = out[0], out[1]
    np.subtract(1.0, t2, out=c)
    c *= d
    np.multiply(t, 2.0, out=s)
    s *= d
    return c, s


def _alpha_beta(C: _Consts, q: np.ndarray) -> np.ndarray:
    """(n, 2, K): per body (α, β) = (cos q, sin q) (revolute) or (1, q) (prismatic)."""
    n, K = q.shape
    CS = np.empty((2, n, K))
    _cos_sin(q, out=CS)
    for i in range(n):
        if C.prism[i]:
            CS[0, i] = 1.0
            CS[1, i] = q[i]
    return CS.transpose(1, 0, 2)



def _chunks(K: int, size: int):
    """Consecutive slices of at most ``size`` of the K samples."""
    for start in range(0, K, size):
        yield slice(start, min(K, start + size))
