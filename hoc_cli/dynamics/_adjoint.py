"""The reverse (adjoint) sweep of a finished Newton-Euler pass: vector-Jacobian products
(``_vjp``, any number of seeds) and full Jacobians (``_jac``, the n unit seeds carried only where
they are nonzero). See the package docstring for the symbols, :mod:`._layout` for the storage.
"""
from __future__ import annotations

import numpy as np

from ._layout import JAC_MIN_K, _Consts, _dall, _dview, _kx, _sx
from ._passes import _Pass


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

    Parameters
    ----------
    lam
        (n, S, K) weights λ (may be a broadcast view).

    Returns
    -------
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
        np.matmul(C.I, b, out=MB[:, 0:6, 1])  # I f̄
        Pm = b[:, C.s_sel]  # (g_π2, g_π1, g_π1, g_π2), g = Sᵀ f̄: rows of f̄
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
        np.take(b, C.s_sel, axis=0, out=Pm, mode="clip")  # ISb[i, 6:] b: rows of b
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



def _vjp_rows(C: _Consts, P: _Pass, lam: np.ndarray) -> tuple:
    """:func:`_vjp` for one seed λ (n, K): (gq, gdq, gddq), each (K, n) (gdq None without velocity)."""
    gq, gdq, gddq = _vjp(C, P, lam[:, None])
    return gq[:, 0].T, None if gdq is None else gdq[:, 0].T, gddq[:, 0].T


def _jacobians_into(C: _Consts, P: _Pass, work, du_dq, du_ddq, M) -> None:
    """∂u/∂q, ∂u/∂q̇ and ∂u/∂q̈ = M of a finished pass with velocity into du_dq, du_ddq, M, each
    (K, n, n) with ``[k, i, j] = ∂u_i/∂x_j``. From ``JAC_MIN_K`` samples on, by :func:`_jac` in
    ``work`` (:func:`_jac_work`); below, fewer numpy calls with all seeds on all bodies.
    """
    n, K = P.q.shape
    if work is None or K < JAC_MIN_K:
        Gs = _vjp(C, P, np.broadcast_to(np.eye(n)[:, :, None], (n, n, K)))
    else:
        Gs = np.empty((3, n, n, K))
        _jac(C, P, Gs[0], Gs[1], Gs[2], work)
    # Gs[:, j, i, k] = ∂u_i/∂(q_j, q̇_j, q̈_j) at sample k
    for out, G in zip((du_dq, du_ddq, M), Gs):
        out[...] = np.transpose(G, (2, 1, 0))
