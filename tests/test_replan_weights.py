"""The goal rows' part of the dense SQP's model (``hoc_cli.goals.replan_qp``) away from the rows, on the offline
steps and on the real-time ones (``quick``).

Each step's programme is the quadratic model of ℒ = I + λ·c (+ the limit rows') plus ρEᵀE over the goal rows E (which
changes the step's multipliers, not the step). Two things hold where the point is off the rows (c ≠ 0, as after a long
step in T), each checked against an independent reference:

- the Newton matrix's goal part is Σλ∇²c + ρDᵀD, with the multipliers λ themselves as the curvature's weights (those
  of the programme's T column): central differences of x ↦ D(x)ᵀλ;
- the multipliers a second-order correction reports are those of its programme without ρEᵀE: the programme's own
  stationarity, g + (H − ρEᵀE)d + Eᵀλ + Aᵀμ = 0 with the correction's rows E d = E d₀ − c(x + d₀).
"""
from __future__ import annotations

import inspect

import numpy as np
import pytest

import hoc_cli.goals.replan as replan_module
import hoc_cli.goals.replan_qp as replan_qp
from hoc_cli.elements import HermiteMesh
from hoc_cli.free_time import rescale
from hoc_cli.goals.active_limits import ActiveRows
from hoc_cli.goals.free_time_sqp import COLD_FLOOR, COLD_STEPS
from hoc_cli.goals.replan import replan
from hoc_cli.goals.replan_point import evaluate_point
from hoc_cli.goals.warm import previous_plan
from tests._robots import lbr7_catch_start


@pytest.fixture(scope="module")
def catch():
    """(system, limits, goals, the initial trajectory at T = 0.35 s on 4 elements) of configs/catch_ball.yaml."""
    return lbr7_catch_start(N=4, T=0.35)


def _dense(blocks: np.ndarray, stride: int, free: np.ndarray) -> np.ndarray:
    """The element blocks (N, 2s, 2s) summed into the (N+1)s-square matrix, restricted to the free coefficients."""
    N, size = blocks.shape[0], (blocks.shape[0] + 1) * stride
    out = np.zeros((size, size))
    for e in range(N):
        out[e * stride:(e + 2) * stride, e * stride:(e + 2) * stride] += blocks[e]
    return out[np.ix_(free, free)]


@pytest.mark.parametrize("quick", [False, True])
def test_the_goal_rows_curvature_is_weighed_by_their_multipliers_off_the_rows(catch, monkeypatch, quick):
    """The initial trajectory rescaled from 0.35 s to 0.37 s (the ball has moved on: the rows are off by centimetres),
    multipliers λ = 1: the goal part of the first Newton matrix times a few directions v equals the central difference
    of D(x)ᵀλ along v plus ρDᵀDv, to 1e-5 of the curvature's part (the augmented Lagrangian's weights λ + ρc, which
    the step's model had, are off by ρc ≈ 5 here); on both paths."""
    arm, limits, goals, start = catch
    q0, dq0 = start.problem.boundary[:2]
    T = 0.37
    plan = previous_plan(arm, HermiteMesh("quintic", T, 4), rescale(start.coeffs, 0.35, T), q0, dq0, goals,
                         cost=start.problem.cost, G=start.G, multipliers="zeros")
    assert plan.violation > 1e-2
    rho = 100.0
    lam = [np.ones(p.residual.size) for p in plan.problem.points]
    seen = []
    newton = replan_qp._newton

    def spy(problem, ev, extra_of, *args, **kwargs):
        seen.append((problem, extra_of(True)))
        return newton(problem, ev, extra_of, *args, **kwargs)

    monkeypatch.setattr(replan_qp, "_newton", spy)
    replan_qp.qp_steps(arm, plan, goals, lam + [np.zeros(0)], ActiveRows.empty(), free=None, limits=limits, tol=1e-12,
                       max_steps=0, rho_aug=rho, quick=quick)
    problem, blocks = seen[0]
    layout = problem.layout
    H = _dense(blocks, problem.mesh.m * problem.n, layout.free)

    def rows_at(x):  # (c, D) of the goal rows at the free coefficients x
        pt = evaluate_point(arm, "quintic", 4, T, problem.coefficients(x), q0, dq0, goals, problem.cost, plan.G,
                            lam + [np.zeros(0)], limits, None, 0.0, False, {})
        r = sum(v.size for v in lam)
        return pt.c[:r], pt.D[:r]

    x = layout.pack(plan.coeffs)
    c, D = rows_at(x)
    assert np.max(np.abs(c)) > 1e-2
    w = np.concatenate(lam)
    rng = np.random.default_rng(3)
    for _ in range(3):
        v = rng.standard_normal(x.size)
        eps = 1e-4 / np.max(np.abs(v))
        curvature = ((rows_at(x + eps * v)[1] - rows_at(x - eps * v)[1]).T @ w) / (2 * eps)
        model = H @ v - rho * D.T @ (D @ v)
        assert np.max(np.abs(model - curvature)) <= 1e-5 * np.max(np.abs(curvature))


@pytest.mark.parametrize("quick", [False, True])
def test_a_corrected_step_reports_its_programme_s_multipliers(catch, monkeypatch, quick):
    """The lbr7 catch's steps from scratch (4 elements, the merit test: corrected steps among them), offline and
    real-time (``quick``: the programmes solved over the last active rows first): for every step the second-order
    correction made, its goal multipliers λ and limit multipliers μ meet the correction programme's stationarity
    without ρEᵀE, g + (UᵀU − ρEᵀE)d + Eᵀλ + Aᵀμ = 0, to 1e-9 of |g|."""
    arm, limits, goals, start = catch
    calls: list = []
    solve, within, correct = replan_qp.solve_qp, replan_qp.solve_qp_within, replan_qp._corrected_step

    def solving(U, g, E, e, A, b, **kwargs):
        s = solve(U, g, E, e, A, b, **kwargs)
        calls.append((U, g, E, e, A, s))
        return s

    def solving_within(U, g, E, e, A, b, rows, **kwargs):
        s = within(U, g, E, e, A, b, rows, **kwargs)
        calls.append((U, g, E, e, A, s))
        return s

    checked = []

    signature = inspect.signature(correct)

    def correcting(*args, **kwargs):
        calls.clear()
        out = correct(*args, **kwargs)
        if out is not None and calls:  # the correction's programme was solved and its step taken
            rho = signature.bind(*args, **kwargs).arguments["rho_aug"]
            U, g, E, e, A, s = calls[-1]
            assert np.array_equal(out[6], s.d[:out[6].size])
            r = E.shape[0]
            lam = np.concatenate(out[4][:-1])[:r] if r else np.zeros(0)
            d = s.d
            residual = g + U.T @ (U @ d) - rho * E.T @ (E @ d) + E.T @ lam + A.T @ s.mu
            checked.append(float(np.max(np.abs(residual))) / float(np.max(np.abs(g))))
        return out

    monkeypatch.setattr(replan_qp, "solve_qp", solving)
    monkeypatch.setattr(replan_qp, "solve_qp_within", solving_within)
    monkeypatch.setattr(replan_qp, "_corrected_step", correcting)
    if quick:
        steps = replan_qp.qp_steps
        monkeypatch.setattr(replan_module, "qp_steps", lambda *a, **k: steps(*a, **k, quick=True))
    r = replan(arm, start, goals, limits=limits, fallback=False, max_steps=COLD_STEPS, violation_floor=COLD_FLOOR,
               merit=True)
    assert r.converged and checked
    assert max(checked) <= 1e-9


def test_the_first_step_in_x_and_t_after_the_fixed_t_steps_moves_t(catch):
    """The lbr7 catch's coarse steps at the guess T (``minimize_time_sqp``'s first stage on 4 elements, to its loose
    accuracy), then one step in x and T from their plan, which carries their last Newton matrix: that step makes its
    own (the T column exact) and moves T towards the optimum, 0.419 s, by more than 0.01 s (0.04 measured; with the
    fixed-T steps' matrix and a differenced T column, 7e-7)."""
    from hoc_cli.goals.free_time_sqp import COARSE_START_ACCURACY, FREE_COLD_FLOOR
    from hoc_cli.goals.replan import TimeRange

    arm, limits, goals, start = catch
    at_guess = replan(arm, start, goals, limits=limits, fallback=False, max_steps=COLD_STEPS,
                      violation_floor=FREE_COLD_FLOOR, merit=True, accuracy=COARSE_START_ACCURACY)
    assert at_guess.plan.optimizer.status.name == "CONVERGED" and at_guess.plan.newton_factor is not None
    one = replan(arm, at_guess.plan, goals, free=TimeRange(0.3, 0.5), limits=limits, fallback=False, max_steps=1,
                 violation_floor=FREE_COLD_FLOOR)
    assert one.steps == 1 and 0.36 < one.T < 0.42
