"""``qp_step.solve_qp`` without equality rows (the restoration's programmes, ``hoc_cli.goals.restoration``): the null
space basis Z is the identity, whose products the programme skips (``Programme.Z`` None), and the step still meets the
programme's KKT conditions (an independent check: H d + g + Aᵀμ = 0, A d ≤ b, μ ≥ 0, μ·(A d − b) = 0) and gives the
step of the same programme with one redundant equality row 0·d = 0 added, the general path.
"""
from __future__ import annotations

import numpy as np
import pytest


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_programme_without_equality_rows_skips_the_identity_basis_and_meets_its_kkt_conditions(seed):
    from hoc_cli.goals.qp_step import Programme, solve_qp, upper_factor

    rng = np.random.default_rng(seed)
    P, k = 40, 30
    X = rng.standard_normal((P, P))
    H = X @ X.T + P * np.eye(P)
    g = 10.0 * rng.standard_normal(P)
    A, b = rng.standard_normal((k, P)), rng.random(k) - 0.5
    U = upper_factor(H)
    E, e = np.zeros((0, P)), np.zeros(0)
    assert Programme(U, g, E).Z is None
    step = solve_qp(U, g, E, e, A, b)
    d, mu = step.d, step.mu
    assert np.max(A @ d - b) <= 1e-10 and np.min(mu) >= 0.0 and np.sum(mu > 0) >= 2
    assert np.max(np.abs(H @ d + g + A.T @ mu)) <= 1e-9 * np.max(np.abs(g))
    assert np.max(np.abs(mu * (A @ d - b))) <= 1e-10
    general = solve_qp(U, g, np.zeros((1, P)), np.zeros(1), A, b)
    assert np.allclose(general.d, d, rtol=0, atol=1e-12) and np.allclose(general.mu, mu, rtol=0, atol=1e-12)
    assert np.isclose(general.decrease, step.decrease, rtol=1e-13)


def test_the_programmes_triangular_solves_are_scipys_numbers_without_its_wrapper(monkeypatch):
    """``qp_step._solve_upper`` calls LAPACK's dtrtrs as ``scipy.linalg.solve_triangular`` does (the transposed system
    for a C-ordered factor): bit for bit its numbers, for C- and Fortran-ordered U, X (P,) and (P, k), U⁻¹ and U⁻ᵀ,
    without going through it (it is kept for other dtypes and empty X)."""
    import scipy.linalg

    import hoc_cli.goals.qp_step as qp_step

    rng = np.random.default_rng(3)
    P = 23
    U = np.triu(rng.standard_normal((P, P))) + 5.0 * np.eye(P)
    cases = [(V, X, trans) for V in (U, np.asfortranarray(U)) for X in (rng.standard_normal(P), rng.standard_normal((P, 4)),
             rng.standard_normal((4, P)).T) for trans in ("N", "T")]
    refs = [scipy.linalg.solve_triangular(V, X, trans=trans, check_finite=False) for V, X, trans in cases]

    def forbidden(*args, **kwargs):
        raise AssertionError("scipy.linalg.solve_triangular called")

    monkeypatch.setattr(qp_step, "solve_triangular", forbidden)
    for (V, X, trans), ref in zip(cases, refs):
        got = qp_step._solve_upper(V, X, trans)
        assert got.shape == ref.shape and np.array_equal(got, ref)


def test_the_models_factor_is_scipys_numbers_without_its_wrapper(monkeypatch):
    """``qp_step.upper_factor`` calls LAPACK's dpotrf as ``scipy.linalg.cho_factor`` does: bit for bit
    ``np.triu(cho_factor(H)[0])``, C-ordered as that is (the triangular solves after it take the same path), without
    going through ``cho_factor``; ``NumericalError`` for an indefinite H."""
    import scipy.linalg

    import hoc_cli.goals.qp_step as qp_step
    from hoc_cli.errors import NumericalError

    rng = np.random.default_rng(4)
    X = rng.standard_normal((31, 31))
    H = X @ X.T + np.eye(31)
    ref = np.triu(scipy.linalg.cho_factor(H, lower=False, check_finite=False)[0])

    def forbidden(*args, **kwargs):
        raise AssertionError("scipy.linalg.cho_factor called")

    monkeypatch.setattr(qp_step, "cho_factor", forbidden)
    got = qp_step.upper_factor(H)
    assert np.array_equal(got, ref) and got.flags.c_contiguous == ref.flags.c_contiguous
    with pytest.raises(NumericalError):
        qp_step.upper_factor(H - 100.0 * np.eye(31))


def test_a_keyed_programme_without_equality_rows_on_its_touched_columns_gives_the_same_step():
    """A keyed programme (the real-time steps') without equality rows whose rows touch few columns solves its NNLS in
    the touched columns' basis (``Programme._touched_basis``, its shifted origin U⁻¹ z0 with Z = I): the same step and
    multipliers as the unkeyed programme, to rounding."""
    from hoc_cli.goals.qp_step import Programme, solve_qp, upper_factor

    rng = np.random.default_rng(5)
    P, k = 40, 12
    X = rng.standard_normal((P, P))
    U = upper_factor(X @ X.T + P * np.eye(P))
    g = 10.0 * rng.standard_normal(P)
    A = np.zeros((k, P))
    A[:, :8] = rng.standard_normal((k, 8))  # 8 of 40 columns touched
    b = 0.1 * rng.random(k)  # d = 0 meets them
    E, e = np.zeros((0, P)), np.zeros(0)
    ref = solve_qp(U, g, E, e, A, b)
    prog = Programme(U, g, E, keyed=True)
    got = solve_qp(U, g, E, e, A, b, programme=prog, keys=np.arange(k))
    assert prog._compressed and np.sum(ref.mu > 0) >= 2
    assert np.allclose(got.d, ref.d, rtol=0, atol=1e-11) and np.allclose(got.mu, ref.mu, rtol=0, atol=1e-11)
