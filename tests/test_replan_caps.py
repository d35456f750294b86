"""Every loop of the dense SQP ends in a status: the quadratic programme's own iteration cap included.

``hoc_cli.goals.qp_step.solve_qp`` solves its least-distance programme by scipy's Lawson-Hanson NNLS, which raises
``RuntimeError`` at its iteration cap; that is the callers' failed step (``NumericalError``: the replan's steps
end there, not converged), never an internal error of ``hoc plan``.
"""
from __future__ import annotations

import numpy as np
import pytest

import hoc_cli.goals.qp_step as qp_step
from hoc_cli.errors import NumericalError
from hoc_cli.goals.qp_step import solve_qp


def _box_qp():
    """min −10·Σd + ½|d|² subject to d ≤ 1: the three rows active, d = 1, μ = 9 (by hand)."""
    P = 3
    return np.eye(P), -10.0 * np.ones(P), np.zeros((0, P)), np.zeros(0), np.eye(P), np.ones(P)


def test_the_programme_is_solved_within_its_cap():
    step = solve_qp(*_box_qp())
    assert np.allclose(step.d, 1.0, atol=1e-12) and np.allclose(step.mu, 9.0, atol=1e-10)


def test_the_nnls_cap_is_a_failed_step_not_a_crash(monkeypatch):
    monkeypatch.setattr(qp_step, "NNLS_ITER", 0)  # one Lawson-Hanson iteration: three active rows need three
    with pytest.raises(NumericalError, match="did not converge in 1 iterations"):
        solve_qp(*_box_qp())


def test_a_replan_whose_programme_hits_its_cap_ends_not_converged(monkeypatch):
    """The lbr7 catch's steps at its guess T from the initial trajectory (``minimize_time_sqp``'s first phase,
    URDF limits binding): with the cap at one iteration the first programme needing more fails, and ``replan``
    returns its last point, not converged, instead of raising."""
    from hoc_cli.goals.free_time_sqp import COLD_FLOOR, COLD_STEPS
    from hoc_cli.goals.replan import replan
    from hoc_cli.goals.time_solver import goal_solver
    from tests._robots import lbr7_catch_problem

    problem = lbr7_catch_problem(N=8)
    arm, limits = problem.system, problem.limits
    goals = problem.goals()
    start = goal_solver(arm, "quintic", 8, problem.q0, problem.dq0, goals, limits=limits).initial(0.35)
    monkeypatch.setattr(qp_step, "NNLS_ITER", 0)
    r = replan(arm, start, goals, limits=limits, fallback=False, max_steps=COLD_STEPS, violation_floor=COLD_FLOOR,
               merit=True)
    assert not r.converged and 0 < r.steps < COLD_STEPS and np.isfinite(r.plan.J)
