"""A keyed programme's least-distance matrix in the basis of the columns its rows touch (``Programme._touched_basis``).

The real-time steps' limit rows touch a third of the coefficients (the elements and joints near a bound); their
least-distance columns Gᵀ_j = −Zᵀ U⁻ᵀ A_jᵀ all lie in the range of B = Zᵀ U⁻ᵀ I_T (T the touched columns), so the
NNLS runs on t + 1 rows [R_B A[:, T]ᵀ; hᵀ] (B = W R_B) instead of P − rank + 1: the same objective for every w,
the same minimiser. The reference: the unkeyed programme over the full null space, nothing shared.
"""
from __future__ import annotations

import numpy as np
import pytest
from _robots import CATCH_G, CATCH_P0, CATCH_V0, lbr7_catch_problem

import hoc_cli.goals.qp_step as qp_step
from hoc_cli.goals.qp_step import Programme, solve_qp, solve_qp_within, upper_factor
from hoc_cli.realtime import Replanner, Target


def _sparse_programme(seed: int, P: int = 40, r: int = 4, k: int = 80, t: int = 12):
    """A strictly convex programme whose k rows touch only t of the P coefficients (every tenth row twice), its
    unconstrained minimiser breaking many of them; the equality rows dense.
    """
    rng = np.random.default_rng(seed)
    M = rng.standard_normal((P, P))
    U = upper_factor(M.T @ M + P * np.eye(P))
    g = 5.0 * rng.standard_normal(P)
    d0 = rng.standard_normal(P)
    E = rng.standard_normal((r, P))
    cols = np.sort(rng.choice(P, t, replace=False))
    A = np.zeros((k, P))
    A[:, cols] = rng.standard_normal((k, t)) * (rng.random((k, t)) < 0.5)
    A[np.arange(k), cols[np.arange(k) % t]] += 1.0  # every touched column in some row, no zero row
    A[::10] = A[1::10]
    e, b = E @ d0, A @ d0 + np.abs(rng.standard_normal(k))
    return U, g, E, e, A, b, t


def _shapes(monkeypatch) -> list:
    seen = []
    monkeypatch.setattr(qp_step, "_cold_nnls", lambda M, repair=False, f=qp_step._cold_nnls:
                        seen.append(M.shape) or f(M, repair=repair))
    return seen


@pytest.mark.parametrize("seed", range(5))
def test_a_keyed_programmes_matrix_has_the_touched_columns_rows_and_the_full_minimiser(seed, monkeypatch):
    U, g, E, e, A, b, t = _sparse_programme(seed)
    full = solve_qp(U, g, E, e, A, b)  # (P − rank + 1)-row NNLS
    seen = _shapes(monkeypatch)
    keys = np.arange(b.size)
    keyed = solve_qp(U, g, E, e, A, b, programme=Programme(U, g, E, keyed=True), keys=keys)
    assert seen == [(t + 1, b.size)]  # 13 rows, not 37
    scale = np.max(np.abs(full.d))
    assert np.min(np.abs(A @ full.d - b)) < 1e-9 and np.sum(full.mu > 0.0) >= 2  # rows active
    assert np.allclose(keyed.d, full.d, rtol=0.0, atol=1e-10 * scale)
    assert abs(keyed.decrease - full.decrease) <= 1e-10 * abs(full.decrease)
    H = U.T @ U
    assert np.allclose(H @ keyed.d + g + A.T @ keyed.mu + E.T @ keyed.nu, 0.0, atol=1e-8 * np.abs(g).max())
    assert np.all(keyed.mu >= 0.0) and np.all(keyed.mu[np.abs(A @ keyed.d - b) > 1e-8] == 0.0)
    # the rounds from no row (the real-time steps' first programme), continued in the same basis
    seen.clear()
    within = solve_qp_within(U, g, E, e, A, b, np.zeros(b.size, bool), programme=Programme(U, g, E, keyed=True),
                             keys=keys)
    assert seen and all(m == t + 1 for m, _ in seen)
    assert np.allclose(within.d, full.d, rtol=0.0, atol=1e-10 * scale)


def test_a_programme_grows_its_basis_with_rows_that_touch_more_columns():
    """A second A of the same programme (the real-time steps' rounds with more candidate rows) whose rows touch
    columns outside the first basis: the basis is the union, the step the full programme's.
    """
    U, g, E, e, A, b, t = _sparse_programme(0)
    prog = Programme(U, g, E, keyed=True)
    first = solve_qp(U, g, E, e, A, b, programme=prog, keys=np.arange(b.size))
    assert np.allclose(first.d, solve_qp(U, g, E, e, A, b).d, rtol=0.0, atol=1e-10 * np.max(np.abs(first.d)))
    extra = np.zeros((3, A.shape[1]))
    new_cols = np.setdiff1d(np.arange(A.shape[1]), prog._basis[0])[:3]
    extra[np.arange(3), new_cols] = 1.0
    A2 = np.vstack([A, extra])
    b2 = np.concatenate([b, extra @ first.d - 0.1])  # the new rows break the first step
    second = solve_qp(U, g, E, e, A2, b2, programme=prog, keys=np.arange(b2.size))
    assert prog._basis[0].size == t + 3
    ref = solve_qp(U, g, E, e, A2, b2)
    assert np.allclose(second.d, ref.d, rtol=0.0, atol=1e-10 * np.max(np.abs(ref.d)))


def test_the_real_time_steps_programmes_are_solved_on_the_touched_columns(monkeypatch):
    """The lbr7 catch on 8 elements (P = 177 with T), its target moved: each step's least-distance matrix has at
    most 1 + the columns its rows touch rows (51-65 on these updates), not P − rank + 1 = 171.
    """
    from hoc_cli import solve

    problem = lbr7_catch_problem()
    cold = solve(problem)
    rp = Replanner(problem, cold, max_steps=1)
    touched, seen = [], _shapes(monkeypatch)
    real = qp_step.Programme._touched_basis

    def spy(self, A):
        touched.append(int(np.any(A != 0.0, axis=0).sum()))
        return real(self, A)

    monkeypatch.setattr(qp_step.Programme, "_touched_basis", spy)
    p1, v1 = CATCH_P0 + np.array([0.04, 0.0, 0.0]), CATCH_V0 + np.array([0.05, 0.05, 0.0])
    for k in range(3):
        tk = 0.05 + 0.01 * k
        cur = rp.current
        rp.update(tk, (cur.state(tk)[0], cur.state(tk, 1)[0]),
                  Target(p1 + v1 * tk + 0.5 * CATCH_G * tk**2, v1 + CATCH_G * tk, CATCH_G), budget_s=10.0)
    assert touched and max(touched) < 100
    assert seen and max(m for m, _ in seen) <= max(touched) + 1
