"""The step's programme re-solved over a subset of its limit rows (``solve_qp_within``): the step of the full one.

A real-time update re-solves a programme whose step broke limit rows outside its candidates over the last
programme's active rows and the rows added (``hoc_cli.goals.replan_qp``); the rows it leaves out are checked and
added back while the step breaks one, so the step is ``solve_qp``'s over every row. The rounds after the first
continue the least-distance programme's Lawson-Hanson iterations from the last round's passive set.
"""
from __future__ import annotations

import inspect

import numpy as np
import pytest
from _robots import CATCH_G, CATCH_P0, CATCH_V0, lbr7_catch_problem

import hoc_cli.goals.qp_step as qp_step
import hoc_cli.goals.replan_qp as replan_qp
from hoc_cli.goals.qp_step import solve_qp, solve_qp_within, upper_factor
from hoc_cli.realtime import Replanner, Target

G, P0, V0 = CATCH_G, CATCH_P0, CATCH_V0  # configs/catch_ball.yaml's target


def _programme(seed: int, P: int = 30, r: int = 4, k: int = 120):
    """A strictly convex programme whose unconstrained minimiser breaks many of k rows (every tenth row twice)."""
    rng = np.random.default_rng(seed)
    M = rng.standard_normal((P, P))
    U = upper_factor(M.T @ M + P * np.eye(P))
    g = 5.0 * rng.standard_normal(P)
    d0 = rng.standard_normal(P)  # a feasible step
    E = rng.standard_normal((r, P))
    A = rng.standard_normal((k, P))
    A[::10] = A[1::10]  # linearly dependent rows: multipliers that are not unique
    e, b = E @ d0, A @ d0 + np.abs(rng.standard_normal(k))
    return U, g, E, e, A, b


@pytest.mark.parametrize("seed", range(5))
def test_the_step_over_a_subset_of_the_rows_is_the_full_programmes(seed):
    U, g, E, e, A, b = _programme(seed)
    full = solve_qp(U, g, E, e, A, b)
    rows = np.zeros(b.size, bool)
    rows[:10] = True
    alone = solve_qp(U, g, E, e, A[rows], b[rows])
    assert np.max(A[~rows] @ alone.d - b[~rows]) > 1e-3  # the subset's own step breaks rows left out
    within = solve_qp_within(U, g, E, e, A, b, rows)
    assert np.allclose(within.d, full.d, rtol=0.0, atol=1e-10 * np.max(np.abs(full.d)))
    assert abs(within.decrease - full.decrease) <= 1e-10 * abs(full.decrease)
    assert within.mu.shape == full.mu.shape and np.all(within.mu >= 0.0)
    assert np.max(A @ within.d - b) <= 1e-9 and np.allclose(E @ within.d, e, atol=1e-9)
    H = U.T @ U  # stationarity with its own multipliers (those of dependent rows may differ from solve_qp's)
    assert np.allclose(H @ within.d + g + A.T @ within.mu + E.T @ within.nu, 0.0, atol=1e-8 * np.abs(g).max())
    assert np.all(within.mu[np.abs(A @ within.d - b) > 1e-8] == 0.0)  # complementarity


def test_only_the_first_round_solves_its_least_distance_programme_from_no_active_row(monkeypatch):
    """The rounds that add the rows a step broke continue from the last round's passive set (few iterations), and
    the step is still the full programme's.
    """
    U, g, E, e, A, b = _programme(0)
    full = solve_qp(U, g, E, e, A, b)
    rows = np.zeros(b.size, bool)
    rows[:10] = True
    cold, warm = [], []
    monkeypatch.setattr(qp_step, "_cold_nnls", lambda M, f=qp_step._cold_nnls: cold.append(M.shape) or f(M))
    monkeypatch.setattr(qp_step, "warm_nnls", lambda *a, f=qp_step.warm_nnls, **k: warm.append(f(*a, **k)) or warm[-1])
    within = solve_qp_within(U, g, E, e, A, b, rows)
    assert len(cold) == 1 and cold[0][1] == 10  # the first round's programme (its 10 rows) alone from scratch
    assert len(warm) >= 1 and all(res.iterations < res.w.size for res in warm)
    assert np.allclose(within.d, full.d, rtol=0.0, atol=1e-10 * np.max(np.abs(full.d)))


def test_a_real_time_updates_reduced_programmes_take_the_full_programmes_steps(monkeypatch):
    """The catch on 8 elements, its target moved 4 cm and its velocity 0.07 m/s: the updates' steps break rows outside their candidates and
    one is corrected (the second-order correction's programme over the step's active rows first).
    """
    from hoc_cli import solve

    problem = lbr7_catch_problem()
    seen = []

    def spy(U, g, E, e, A, b, rows, programme=None, keys=None):
        step = solve_qp_within(U, g, E, e, A, b, rows, programme=programme, keys=keys)
        full = solve_qp(U, g, E, e, A, b)  # from scratch, nothing shared
        caller = inspect.currentframe().f_back.f_code.co_name
        seen.append((caller, int(rows.sum()) < rows.size, float(np.max(np.abs(step.d - full.d)) / np.max(np.abs(full.d)))))
        return step

    cold = solve(problem)  # (its steps' programmes, near convergence steps of rounding size, are not the real-time ones)
    monkeypatch.setattr(replan_qp, "solve_qp_within", spy)
    rp = Replanner(problem, cold, max_steps=1)
    p1, v1 = P0 + np.array([0.04, 0.0, 0.0]), V0 + np.array([0.05, 0.05, 0.0])
    for k in range(3):
        tk = 0.05 + 0.01 * k
        cur = rp.current
        rp.update(tk, (cur.state(tk)[0], cur.state(tk, 1)[0]), Target(p1 + v1 * tk + 0.5 * G * tk**2, v1 + G * tk, G),
                  budget_s=10.0)
    assert {c for c, reduced, _ in seen if reduced} == {"qp_steps", "_corrected_step"}  # 2 and 1 measured
    assert max(err for *_, err in seen) <= 1e-9  # 2e-14 measured
