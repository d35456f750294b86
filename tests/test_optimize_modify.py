"""The Hessian modification shared by every Newton matrix (``hoc_cli.optimize.modify.gauss_newton_shift``).

Reference: the eigenvalues of the assembled matrices (numpy): the weight returned is the first of
μ0·10^k whose H + μ·GN is positive definite, so the one before is not.
"""
from __future__ import annotations

import numpy as np

from hoc_cli.errors import NumericalError
from hoc_cli.optimize.modify import TRIES, gauss_newton_shift


def _cholesky(M: np.ndarray) -> np.ndarray:
    try:
        return np.linalg.cholesky(M.sum(axis=0))
    except np.linalg.LinAlgError:
        raise NumericalError("not positive definite") from None


def test_the_first_weight_whose_matrix_factors():
    rng = np.random.default_rng(3)
    A = rng.standard_normal((6, 6))
    GN = (A @ A.T)[None]  # positive definite
    H = (np.diag([5.0, 4.0, 3.0, -0.2, -1.0, -40.0]))[None]  # indefinite
    mu, L = gauss_newton_shift(H, GN, _cholesky)
    mu0 = 1e-3 * max(abs(np.trace(H[0])), np.trace(GN[0])) / np.trace(GN[0])
    k = round(np.log10(mu / mu0))
    assert 0 < k < TRIES and np.isclose(mu, mu0 * 10.0 ** k, rtol=1e-12)
    assert np.linalg.eigvalsh(H[0] + mu * GN[0]).min() > 0 > np.linalg.eigvalsh(H[0] + mu / 10 * GN[0]).min()
    assert np.allclose(L @ L.T, H[0] + mu * GN[0])


def test_no_weight_factors_a_matrix_that_gn_cannot_fix():
    GN = np.diag([1.0, 0.0])[None]  # semi-definite: the second direction stays at H's −1
    H = np.diag([1.0, -1.0])[None]
    mu, L = gauss_newton_shift(H, GN, _cholesky)
    assert L is None and np.isclose(mu, 1e-3 * 10.0 ** TRIES, rtol=1e-12)  # mu0 = 1e-3 (tr H = 0, tr GN = 1)
