"""The Newton-Euler passes of :mod:`hoc_cli.dynamics`: motions root to leaves (``_forward``),
body forces of all bodies at once (``_forces``), subtree force sums leaves to root
(``_backward``), and what is read off a finished pass (torques, mass matrix). See
:mod:`._layout` for the storage of a pass.
"""
from __future__ import annotations

import numpy as np

from ..model.tree import RobotModel
from ._layout import ID_CHUNK, _alpha_beta, _chunks, _Consts, _consts, _dview


class _Pass:
    """One batch's forward (Newton-Euler) quantities, kept for the reverse sweep.

    TT (n, 10, ch, K): rows 4-9 the motion of each body (channels: [velocity], [acceleration],
    [unit-acceleration columns]), rows 0-3 scratch. FF (n, 14, fch, K): rows 0-5 the force
    transmitted through each joint (subtree sum; channels: [acceleration], [columns]), rows 6-13
    scratch. Gq (n, 36, K): the velocity-product factors.
    """

    __slots__ = ("CS", "FF", "Gq", "K", "TT", "U", "cols", "dq", "ha", "hv", "nb", "q")


def _forward(C: _Consts, q, dq, acc, gravity: bool, cols: bool) -> _Pass:
    """Motions of every body, root to leaves. ``dq`` None: no velocity channel; ``acc`` None and
    no gravity: no acceleration channel; ``cols``: carry the n unit joint accelerations too.
    """
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
        cp = nb + C.hi_par[i] if cols else ch  # channels carried over from the parent
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
            v = TT[:, 4:10, 0]
            P.Gq = Gq = np.empty((n, 36, K))
            np.matmul(C.ABq18, v, out=Gq[:, :18])  # (Bπ1, Bπ2) v
            Gq[:, 18:] = v[:, C.a_sel]  # (Aπ2, Aπ1) v: rows of v
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
    _, _, fch, K = FF.shape
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
    at joint i holds M[i, j] for the ancestors j of i, the rest follows by symmetry (0 off-branch).
    """
    off = int(P.ha)
    R = P.FF[C.ar, C.zrow, off:off + C.n].transpose(2, 0, 1)  # (K, i, j)
    np.copyto(out, np.where(C.desc_mask, R.transpose(0, 2, 1), 0.0))
    np.copyto(out, R, where=C.anc_mask)


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
    P = _newton_euler(C, q, dq, acc, True, cols=True)
    out_u[...] = _tau_of(C, P).T
    _mass_from(C, P, out_M)
    return P



def _newton_euler(C: _Consts, q, dq, acc, gravity: bool, cols: bool) -> _Pass:
    """A finished pass (motions, forces, subtree sums); arguments as :func:`_forward`."""
    P = _forward(C, q, dq, acc, gravity, cols)
    _forces(C, P)
    _backward(C, P)
    return P


def _shift_acceleration(C: _Consts, P: _Pass, w: np.ndarray) -> None:
    """Turn a finished pass of :func:`_h_and_mass` (velocity, acceleration and the unit-acceleration
    columns) into the pass at acceleration q̈ − ½ w, w (n, K), in place: a ← a − ½ Σ_j w_j
    (column j), then the forces (velocity products reused) and subtree sums again, columns dropped.
    """
    TT = P.TT
    da = TT[:, 4:10, 2:] * w
    TT[:, 4:10, 1] -= 0.5 * da.sum(axis=2)
    _forces(C, P, only_acc=True)
    P.cols = False
    _backward(C, P)
