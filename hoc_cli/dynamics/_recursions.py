"""Internals of :mod:`hoc_cli.dynamics`: input checks, the sample-axis-last layout, per-model
constants and the Newton-Euler recursions (forward, backward, adjoint). See the package docstring
for the symbols and the layout."""
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
VJP_CHUNK = 512     # id_vjp, mass_quadratic_grad: one seed


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


_CONSTS: "weakref.WeakKeyDictionary[RobotModel, _Consts]" = weakref.WeakKeyDictionary()


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
    With ``out`` (2, ...) the pair is written there."""
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


class _Pass:
    """One batch's forward (Newton-Euler) quantities, kept for the reverse sweep.

    TT (n, 10, ch, K): rows 4-9 the motion of each body (channels: [velocity], [acceleration],
    [unit-acceleration columns]), rows 0-3 scratch. FF (n, 14, fch, K): rows 0-5 the force
    transmitted through each joint (subtree sum; channels: [acceleration], [columns]), rows 6-13
    scratch. Gq (n, 36, K): the velocity-product factors.
    """

    __slots__ = ("q", "dq", "CS", "TT", "FF", "Gq", "U", "hv", "ha", "nb", "cols", "K")


def _forward(C: _Consts, q, dq, acc, gravity: bool, cols: bool) -> _Pass:
    """Motions of every body, root to leaves. ``dq`` None: no velocity channel; ``acc`` None and
    no gravity: no acceleration channel; ``cols``: carry the n unit joint accelerations too."""
    n, K = q.shape
    P = _Pass()
    P.q, P.dq, P.K = q, dq, K
    P.CS = CS = _alpha_beta(C, q)
    hv = dq is not None
    ha = acc is not None or gravity or hv
    nb = int(hv) + int(ha)
    ch = nb + (n if cols else 0)
    P.hv, P.ha, P.nb, P.cols = hv, ha, nb, cols
    ac = nb - 1  # acceleration channel
    TT = np.empty((n, 10, ch, K))
    SCin = CS[:, ::-1, None, None, :]  # (β, α) for (D y, y)
    if hv:
        WS = C.sgn[:, :, :, None] * dq[:, None, None, :]  # (n, 2, 2, K): q̇ D, as a view's signs
    for i in C.order:
        p = C.parent[i]
        Ti = TT[i]
        t = C.t[i]
        if cols:
            cp, ci = nb + C.hi_par[i], nb + C.hi[i]
        else:
            cp = ci = ch
        if p < 0:
            Ti[4:10] = 0.0
            if gravity:
                Ta = Ti[:, ac]
                Ta[...] = C.zfg[i][:, None]
                V = Ta[0:8].reshape(2, 4, K)
                V *= CS[i, ::-1, None, :]
                Ta[4:8] += Ta[0:4]
        else:
            dst = Ti[:, :cp]
            np.matmul(C.ZF[i], TT[p, 4:10, :cp].reshape(6, cp * K), out=dst.reshape(10, cp * K))
            V = dst[0:8].reshape(2, 4, cp, K)
            V *= SCin[i]
            dst[4:8] += dst[0:4]
            if cols:
                Ti[4:10, cp:] = 0.0
            if hv:
                m = Ti[4:8]
                a = m[:, 1].reshape(2, 2, K)
                a += _dview(m[:, 0], C.rev[i]) * WS[i]
        if cols:
            Ti[8 + t, nb + i] = 1.0
        if hv:
            Ti[8 + t, 0] += dq[i]
        if acc is not None:
            Ti[8 + t, ac] += acc[i]
    P.TT = TT
    return P


def _forces(C: _Consts, P: _Pass, only_acc: bool = False) -> None:
    """Body forces f = I a + v ×* (I v) of every body at once (into P.FF rows 0-5)."""
    n, K = P.q.shape
    TT = P.TT
    ch = TT.shape[2]
    hv = P.hv
    fch = 1 if only_acc else ch - hv
    FF = np.empty((n, 14, fch, K))
    if hv:
        if only_acc:
            Gq = P.Gq
        else:
            P.Gq = Gq = np.matmul(C.ABq, TT[:, 4:10, 0])
        U = np.empty((n, 24, K))
        U[:, :6] = TT[:, 4:10, 1]
        np.multiply(Gq[:, 18:], Gq[:, :18], out=U[:, 6:])
        np.matmul(C.ISf, U, out=FF[:, 0:6, 0])
        if fch > 1:
            np.matmul(C.I, TT[:, 4:10, 2:].reshape(n, 6, (ch - 2) * K),
                      out=FF[:, 0:6, 1:].reshape(n, 6, (fch - 1) * K))
    else:
        np.matmul(C.I, TT[:, 4:10].reshape(n, 6, ch * K), out=FF[:, 0:6].reshape(n, 6, fch * K))
    P.FF = FF


def _backward(C: _Consts, P: _Pass) -> None:
    """Subtree sums F_parent += Xᵀ (joint out) F_child, leaves to root, in place in P.FF."""
    FF = P.FF
    n, _, fch, K = FF.shape
    CSo = P.CS[:, :, None, None, :]
    tmp = np.empty(6 * fch * K)
    na = fch if not P.cols or fch == 1 else int(P.ha)  # force channels besides the columns
    for i in reversed(C.order):
        p = C.parent[i]
        if p < 0:
            continue
        fc = na + C.hi_par[i] if (P.cols and fch > 1) else fch
        Fi = FF[i]
        np.multiply(Fi[0:4, :fc], CSo[i], out=Fi[6:14, :fc].reshape(2, 4, fc, K))
        t6 = tmp[:6 * fc * K].reshape(6, fc * K)
        np.matmul(C.Zb[i], Fi[4:14, :fc].reshape(10, fc * K), out=t6)
        FF[p, 0:6, :fc] += t6.reshape(6, fc, K)


def _mass_from(C: _Consts, P: _Pass, out: np.ndarray) -> None:
    """M (K, n, n) into ``out`` from the column channels of a finished pass: row i of the force
    at joint i holds M[i, j] for the ancestors j of i, the rest follows by symmetry (0 off-branch)."""
    off = int(P.ha)
    R = P.FF[C.ar, C.zrow, off:off + C.n].transpose(2, 0, 1)  # (K, i, j)
    np.copyto(out, np.where(C.desc_mask, R.transpose(0, 2, 1), 0.0))
    np.copyto(out, R, where=C.anc_mask)


def _keep(C: _Consts, P: _Pass) -> tuple:
    """D applied to what the reverse sweep needs: (Dv (n, 4, K) or None, D mc (n, 4, ch, K), Dᵀ F)."""
    TT = P.TT
    hv = P.hv
    ac = P.nb - 1
    n, K = P.q.shape
    DMC = np.empty((n, 4, 2 if hv else 1, K))
    DMC[:, :, -1] = _dall(C, TT[:, 4:8, ac])
    if hv:
        Dv = _dall(C, TT[:, 4:8, 0])
        DMC[:, :, 0] = Dv
        # mc (before the joint-velocity term) = a − q̇ D v, so D mc = D a − q̇ D D v
        if C.all_rev:  # D D = −1
            DDv = TT[:, 4:8, 0] * P.dq[:, None, :]
            DMC[:, :, 1] += DDv
        else:
            DDv = _dall(C, Dv)
            DDv *= P.dq[:, None, :]
            DMC[:, :, 1] -= DDv
    else:
        Dv = None
    DtF = _dall(C, P.FF[:, 0:4, 0], transpose=True)
    return Dv, DMC, DtF


def _vjp(C: _Consts, P: _Pass, lam: np.ndarray):
    """Reverse-mode sweep of the Newton-Euler pass P (acceleration channel) for S seeds at once.

    Args:
        lam: (n, S, K) weights λ (may be a broadcast view).
    Returns:
        (gq, gdq, gddq), each (n, S, K): ``gq[j, s] = λ_sᵀ ∂τ/∂q_j``; likewise ∂/∂q̇ (None without
        velocity) and ∂/∂q̈ (= (M λ_s)_j).

    Sweep 1 (root to leaves) carries the force adjoints f̄_i = λ_i e_z + (the parent's moved into
    body i), motion-like; they give every body's local motion adjoints at once (through
    f = I a + v ×* I v); sweep 2 (leaves to root) sums those over subtrees. The q, q̇, q̈ gradients
    are then read off for all joints at once: ∂/∂q_i from D (the joint generator) applied to the
    kept motions and forces, ∂/∂q̇_i, ∂/∂q̈_i where they enter. Seeds and samples share the last
    axis (S·K) so that most operations are 3-D.
    """
    n, S, K = lam.shape
    SK = S * K
    hv = P.hv
    Dv, DMC, DtF = _keep(C, P)
    B = np.empty((n, 10, SK))
    SCin = P.CS[:, ::-1, None, :]  # (n, 2, 1, K)
    for i in C.order:
        p = C.parent[i]
        Bi = B[i]
        if p < 0:
            Bi[4:10] = 0.0
        else:
            np.matmul(C.ZF[i], B[p, 4:10], out=Bi)
            V = _sx(Bi[0:8].reshape(2, 4, SK), S)
            V *= _kx(SCin[i], S)
            Bi[4:8] += Bi[0:4]
        zr = _sx(Bi[8 + C.t[i]], S)
        zr += lam[i] if S > 1 else lam[i, 0]
    b = B[:, 4:10]
    ch = 2 if hv else 1
    MB = np.empty((n, 14, ch, SK))
    if hv:
        Y = np.matmul(C.ISb, b)  # (I f̄, g_π2, g_π1, g_π1, g_π2)
        MB[:, 0:6, 1] = Y[:, :6]
        Pm = Y[:, 6:]
        _sx(Pm, S)[...] *= _kx(P.Gq, S)
        ZZ = np.empty((n, 18, SK))  # (Bv × g, g × Av)
        np.subtract(Pm[:, 0:9], Pm[:, 9:18], out=ZZ[:, 0:9])
        np.subtract(Pm[:, 18:27], Pm[:, 27:36], out=ZZ[:, 9:18])
        np.matmul(C.AB9T, ZZ, out=MB[:, 0:6, 0])
        WT = C.sgnT[:, :, :, None] * P.dq[:, None, None, :]  # (n, 2, 2, K)
    else:
        np.matmul(C.I, b, out=MB[:, 0:6, 0])
    gq = _sx(b[:, 0:4], S) * _kx(DtF, S)
    gq = gq.sum(axis=1)
    CSo = P.CS[:, :, None, :]
    tmp = np.empty((6, ch * SK))
    for i in reversed(C.order):
        Mi = MB[i]
        if hv:
            vb = _sx(Mi[0:4, 0].reshape(2, 2, SK), S)
            vb += _sx(_dview(Mi[0:4, 1], C.rev[i]), S) * _kx(WT[i], S)
        p = C.parent[i]
        if p < 0:
            continue
        out8 = Mi[6:14].reshape(2, 4 * ch, SK)
        np.multiply(_sx(Mi[0:4].reshape(1, 4 * ch, SK), S), _kx(CSo[i], S), out=_sx(out8, S))
        np.matmul(C.Zb[i], Mi[4:14].reshape(10, ch * SK), out=tmp)
        MB[p, 0:6] += tmp.reshape(6, ch, SK)
    g2 = _sx(MB[:, 0:4].reshape(n, 4 * ch, SK), S) * _kx(DMC.reshape(n, 4 * ch, K), S)
    gq += g2.sum(axis=1)
    gddq = MB[C.ar, C.zrow, ch - 1]
    if hv:
        g3 = _sx(MB[:, 0:4, 1], S) * _kx(Dv, S)
        gdq = g3.sum(axis=1)
        gdq += _sx(MB[C.ar, C.zrow, 0], S)
        gdq = gdq.reshape(n, S, K)
    else:
        gdq = None
    return gq.reshape(n, S, K), gdq, gddq.reshape(n, S, K)


def _chunks(K: int, size: int):
    for start in range(0, K, size):
        yield slice(start, min(K, start + size))


def _tau_of(C: _Consts, P: _Pass) -> np.ndarray:
    """(n, K) joint torques of a finished pass (acceleration channel)."""
    return P.FF[C.ar, C.zrow, 0]


def _tau(model: RobotModel, q, dq, ddq, gravity: bool) -> np.ndarray:
    """RNEA torques (K, n) from (n, K) inputs (dq, ddq may be None), in cache-sized chunks."""
    C = _consts(model)
    n, K = q.shape
    out = np.empty((K, n))
    for sl in _chunks(K, ID_CHUNK):
        P = _forward(C, q[:, sl], None if dq is None else dq[:, sl],
                     None if ddq is None else ddq[:, sl], gravity, cols=False)
        if not P.ha:  # no velocity, acceleration or gravity: zero torques
            out[sl] = 0.0
            continue
        _forces(C, P)
        _backward(C, P)
        out[sl] = _tau_of(C, P).T
    return out


def _h_and_mass(C: _Consts, q, dq, acc, out_u, out_M) -> _Pass:
    """One pass for ID(q, q̇, acc) (K, n) and M (K, n, n) (into out_u, out_M)."""
    P = _forward(C, q, dq, acc, True, cols=True)
    _forces(C, P)
    _backward(C, P)
    out_u[...] = _tau_of(C, P).T
    _mass_from(C, P, out_M)
    return P


def _jac(C: _Consts, P: _Pass, gq, gdq, gddq, work: np.ndarray) -> None:
    """Full Jacobians of a finished Newton-Euler pass P (with velocity): the reverse sweep of
    :func:`_vjp` seeded with the n unit vectors λ = e_s, into gq, gdq, gddq (n, n, K) with
    ``gq[j, s] = ∂u_s/∂q_j`` (likewise q̇, q̈).

    Seed s's force adjoint is nonzero only in the subtree of joint s, so in sweep 1 (and in the
    local motion adjoints, the expensive part) body i carries only the seeds [0, hi[i]) (its
    ancestors, as the mass-matrix columns); sweep 2 carries all n. The local steps go one body at
    a time (ragged seed counts); every temporary is carved out of ``work``.
    """
    n, K = P.q.shape
    nK = n * K
    Dv, DMC, DtF = _keep(C, P)
    hi, hp_ = C.hi, C.hi_par
    # work layout: B (per body (10, hi, K)), MB (n, 14, 2, n, K), Y (36, n K), ZZ (18, n K)
    offs = [0]
    for h in hi:
        offs.append(offs[-1] + 10 * h * K)
    nb = offs[-1]
    MB = work[nb:nb + n * 28 * nK].reshape(n, 14, 2, n, K)
    o = nb + n * 28 * nK
    Yb = work[o:o + 36 * nK]
    ZZb = work[o + 36 * nK:o + 54 * nK]
    Bs = [work[offs[i]:offs[i + 1]].reshape(10, hi[i], K) for i in range(n)]
    SCin = P.CS[:, ::-1, None, None, :]  # (n, 2, 1, 1, K): (β, α) for (D y, y)
    g1 = gddq  # scratch until the end: the force term of ∂/∂q
    g1[...] = 0.0
    for i in C.order:
        p = C.parent[i]
        h, hp = hi[i], hp_[i]
        Bi = Bs[i]
        if p < 0:
            Bi[4:10] = 0.0
        else:
            dst = Bi[:, :hp]
            np.matmul(C.ZF[i], Bs[p][4:10].reshape(6, hp * K), out=dst.reshape(10, hp * K))
            V = dst[0:8].reshape(2, 4, hp, K)
            V *= SCin[i]
            dst[4:8] += dst[0:4]
            Bi[4:10, hp:] = 0.0
        Bi[8 + C.t[i], i] += 1.0
        # local motion adjoints of body i (seeds [0, h)): ā = I f̄, v̄ from the velocity product
        b = Bi[4:10].reshape(6, h * K)
        Mi = MB[i]
        np.matmul(C.I[i], b, out=Mi[0:6, 1, :h].reshape(6, h * K))
        Pm = Yb[:36 * h * K].reshape(36, h * K)
        np.matmul(C.ISb[i, 6:], b, out=Pm)
        Pm3 = Pm.reshape(36, h, K)
        Pm3 *= P.Gq[i][:, None, :]
        ZZ = ZZb[:18 * h * K].reshape(18, h * K)
        np.subtract(Pm[0:9], Pm[9:18], out=ZZ[0:9])
        np.subtract(Pm[18:27], Pm[27:36], out=ZZ[9:18])
        np.matmul(C.AB9T[i], ZZ, out=Mi[0:6, 0, :h].reshape(6, h * K))
        Mi[0:6, :, h:] = 0.0
        # ∂/∂q_i through the joint's motion transform (forces): f̄_xy · Dᵀ F
        t4 = Yb[:4 * h * K].reshape(4, h, K)
        np.multiply(Bi[4:8], DtF[i][:, None, :], out=t4)
        t4.sum(axis=0, out=g1[i, :h])
    WT = C.sgnT[:, :, :, None, None] * P.dq[:, None, None, None, :]  # (n, 2, 2, 1, K)
    CSo = P.CS[:, :, None, None, :]  # (n, 2, 1, 1, K)
    tmp = Yb[:12 * nK].reshape(6, 2 * nK)
    for i in reversed(C.order):
        Mi = MB[i]
        vb = Mi[0:4, 0].reshape(2, 2, n, K)
        vb += _dview(Mi[0:4, 1], C.rev[i]) * WT[i]
        p = C.parent[i]
        if p < 0:
            continue
        np.multiply(Mi[0:4].reshape(1, 8, n, K), CSo[i], out=Mi[6:14].reshape(2, 8, n, K))
        np.matmul(C.Zb[i], Mi[4:14].reshape(10, 2 * nK), out=tmp)
        MB[p, 0:6] += tmp.reshape(6, 2, n, K)
    # ∂/∂q_i through the joint's force transform (motions): (v̄, ā)_xy · D (v, a − q̇ D v)
    np.einsum("ircsk,irck->isk", MB[:, 0:4], DMC, out=gq)
    gq += g1
    gddq[...] = MB[C.ar, C.zrow, 1]
    np.einsum("irsk,irk->isk", MB[:, 0:4, 1], Dv, out=gdq)
    gdq += MB[C.ar, C.zrow, 0]


def _jac_work(C: _Consts, K: int) -> np.ndarray:
    """Scratch for :func:`_jac` at K samples (one buffer, shared by all chunks of a call)."""
    return np.empty(10 * sum(C.hi) * K + (28 * C.n + 54) * C.n * K)

