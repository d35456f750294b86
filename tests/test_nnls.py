"""Lawson-Hanson NNLS from a given passive set (``hoc_cli.optimize.nnls``) against scipy.optimize.nnls.

scipy's ``nnls`` (Lawson & Hanson's algorithm, compiled) is the independent reference: the residual M w − f of
the minimiser is unique, and so is w where the columns are linearly independent.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import nnls as scipy_nnls

from hoc_cli.errors import NumericalError
from hoc_cli.optimize.nnls import nnls


def _problem(seed: int, m: int, k: int, duplicates: bool = False):
    rng = np.random.default_rng(seed)
    M = rng.standard_normal((m, k))
    if duplicates:  # every fifth column equal to the next one, one a multiple of another: dependent columns
        M[:, 0:k - 1:5] = M[:, 1::5][:, :len(range(0, k - 1, 5))]
        M[:, 2] = 3.0 * M[:, 3]
    return M, rng.standard_normal(m)


def _kkt(M, f, res) -> float:
    """The largest dual value Mᵀ(f − M w) off the passive set (≤ 0 at the minimiser) relative to ‖M‖‖f‖."""
    v = M.T @ (f - M @ res.w)
    return float(np.max(v) / (np.linalg.norm(M) * np.linalg.norm(f)))


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("m, k", [(30, 12), (25, 60), (40, 40)])
def test_from_no_passive_set_it_is_scipys_minimiser(seed, m, k):
    M, f = _problem(seed, m, k)
    ref, _ = scipy_nnls(M, f, maxiter=50 * k)
    res = nnls(M, f)
    assert np.all(res.w >= 0.0)
    assert np.linalg.norm(res.residual - (M @ ref - f)) <= 1e-11 * np.linalg.norm(f)
    assert _kkt(M, f, res) <= 1e-12
    if m >= k:  # independent columns: w itself is unique
        assert np.allclose(res.w, ref, rtol=0.0, atol=1e-10 * max(np.max(ref), 1.0))


@pytest.mark.parametrize("seed", range(8))
def test_dependent_columns_give_scipys_residual_and_never_enter_together(seed):
    M, f = _problem(seed, 30, 50, duplicates=True)
    ref, _ = scipy_nnls(M, f, maxiter=2500)
    for passive in (None, np.flatnonzero(ref > 0.0), np.arange(0, 50, 2)):
        res = nnls(M, f, passive=passive)
        assert np.linalg.norm(res.residual - (M @ ref - f)) <= 1e-11 * np.linalg.norm(f)
        assert _kkt(M, f, res) <= 1e-12
        S = res.passive
        assert np.linalg.matrix_rank(M[:, S]) == S.size  # the passive columns stay independent


@pytest.mark.parametrize("seed", range(6))
def test_a_start_from_any_passive_set_ends_at_the_minimiser(seed):
    """Passive sets whose least-squares solution has negative entries (a guess) are repaired first."""
    M, f = _problem(seed, 30, 45)
    ref, _ = scipy_nnls(M, f, maxiter=2500)
    rng = np.random.default_rng(100 + seed)
    for _ in range(4):
        res = nnls(M, f, passive=np.flatnonzero(rng.random(45) < 0.4))
        assert np.linalg.norm(res.residual - (M @ ref - f)) <= 1e-11 * np.linalg.norm(f)


@pytest.mark.parametrize("seed", range(6))
def test_a_column_added_to_a_solved_problem_takes_few_iterations_from_its_passive_set(seed):
    """The warm start's point: the minimiser over 60 columns, then one column more; from the first passive set only
    the changes are made (counted: 0-3 here), far fewer than from no passive set (28-41).
    """
    M, f = _problem(seed, 40, 61)
    first = nnls(M[:, :60], f)
    cold = nnls(M, f)
    warm = nnls(M, f, passive=first.passive)
    ref, _ = scipy_nnls(M, f, maxiter=3050)
    assert np.linalg.norm(warm.residual - (M @ ref - f)) <= 1e-11 * np.linalg.norm(f)
    assert nnls(M, f, passive=cold.passive).iterations == 0  # started at the minimiser: nothing to do
    assert warm.iterations <= 4 and cold.iterations >= 25


def test_the_iteration_cap_raises_a_numerical_error():
    M, f = _problem(0, 30, 40)
    with pytest.raises(NumericalError):
        nnls(M, f, max_iter=2)


@pytest.mark.parametrize("seed", range(6))
def test_a_drop_retriangulated_is_the_factor_of_the_kept_columns(seed):
    """``_ThinQR.keep`` with ``retriangulate`` (one small QR of the later columns' rows of R): Q orthonormal, Q R the
    kept columns of M in their order, Qᵀf the stored right-hand side, R upper triangular; several drops in a row,
    the first column among them.
    """
    from hoc_cli.optimize.nnls import _ThinQR

    M, f = _problem(seed, 40, 25)
    MT = np.ascontiguousarray(M.T)
    rng = np.random.default_rng(seed)
    cols = list(rng.permutation(25)[:18])
    qrf = _ThinQR(MT, f, cols, retriangulate=True)
    for drop in (7, 0, 11, 4):
        mask = np.ones(len(qrf.cols), bool)
        mask[min(drop, mask.size - 1)] = False
        kept = [c for c, k in zip(qrf.cols, mask) if k]
        qrf.keep(mask)
        assert qrf.cols == kept
        p = len(kept)
        Q, R = qrf.Q[:, :p], np.triu(qrf.R[:p, :p])
        assert np.abs(Q.T @ Q - np.eye(p)).max() <= 1e-14
        assert np.abs(Q @ R - M[:, kept]).max() <= 1e-13 * np.abs(M).max()
        assert np.abs(qrf.qf[:p] - Q.T @ f).max() <= 1e-13 * np.linalg.norm(f)
        z = qrf.solve()
        ref = np.linalg.lstsq(M[:, kept], f, rcond=None)[0]
        assert np.abs(z - ref).max() <= 1e-11 * max(np.abs(ref).max(), 1.0)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("duplicates", [False, True])
def test_retriangulated_drops_take_the_same_iterations_to_scipys_minimiser(seed, duplicates):
    """``nnls(..., retriangulate=True)``: the same iterations and passive set as appending again, the residual of
    scipy's minimiser, from no passive set and from a guess that must lose columns first.
    """
    M, f = _problem(seed, 30, 50, duplicates=duplicates)
    ref, _ = scipy_nnls(M, f, maxiter=2500)
    guess = np.random.default_rng(200 + seed).permutation(50)[:20]
    for passive in (None, guess):
        a = nnls(M, f, passive=passive)
        b = nnls(M, f, passive=passive, retriangulate=True)
        assert b.iterations == a.iterations and sorted(b.passive) == sorted(a.passive)
        assert np.linalg.norm(b.residual - (M @ ref - f)) <= 1e-11 * np.linalg.norm(f)
        assert _kkt(M, f, b) <= 1e-12
