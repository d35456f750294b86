"""The feedback correction near the catch (``hoc_cli.realtime.feedback``) and the closed loop that uses it."""
from __future__ import annotations

import numpy as np
import pytest
from _robots import CATCH_G, CATCH_P0, CATCH_V0, lbr7_catch_problem
from scipy.optimize import minimize

import hoc_cli
from hoc_cli.constraints.check import check_limits
from hoc_cli.realtime.feedback import correct
from hoc_cli.realtime.loop import flange_states
from hoc_cli.realtime.replanner import CyclePlan

G, P0, V0 = CATCH_G, CATCH_P0, CATCH_V0


@pytest.fixture(scope="module")
def catch():
    problem = lbr7_catch_problem()
    plan = hoc_cli.solve(problem)
    res = plan.result
    return problem, CyclePlan(t0=0.0, mesh=res.mesh, coeffs=np.array(res.coeffs), cost=float(res.J))


def _end(problem, plan):
    p, v = flange_states(problem.system.model, "lbr_flange", plan.state(plan.t_end), plan.state(plan.t_end, 1))
    return p[0], v[0]


def test_the_correction_meets_the_moved_target_from_the_same_state_within_the_limits(catch):
    problem, plan = catch
    t_s = plan.t_end - 0.08
    p, v = _end(problem, plan)
    dp, dv = np.array([0.002, -0.001, 0.0015]), np.array([0.004, 0.0, -0.006])
    new = correct(problem.system, problem.limits, "lbr_flange", plan, t_s, p + dp, v + dv)
    assert new is not None and new.status == "feedback" and new.t0 == t_s and new.t_end == pytest.approx(plan.t_end)
    pn, vn = _end(problem, new)
    assert np.abs(pn - (p + dp)).max() < 1e-7 and np.abs(vn - (v + dv)).max() < 1e-6
    assert new.violation == pytest.approx(max(np.abs(pn - p - dp).max(), np.abs(vn - v - dv).max()), abs=1e-9)
    for d in (0, 1):  # the robot's state at t_s is kept
        assert np.abs(new.state(t_s, d) - plan.state(t_s, d)).max() < 1e-12
    assert check_limits(problem.system, problem.limits, new.mesh, new.coeffs).feasible
    # the plan is unchanged by a correction to where it already goes
    same = correct(problem.system, problem.limits, "lbr_flange", plan, t_s, p, v)
    ts = np.linspace(t_s, plan.t_end, 50)
    assert np.abs(same.state(ts) - plan.state(ts)).max() < 1e-10


def test_the_correction_is_the_least_acceleration_one(catch):
    """Against SLSQP on the same problem: ∫‖δq̈‖² by quadrature of the correction sampled from the plans, the flange's
    end position and velocity by forward kinematics (no limit row is near here: the plan's last 80 ms).
    """
    problem, plan = catch
    t_s = plan.t_end - 0.08
    p, v = _end(problem, plan)
    goal = np.concatenate([p + [0.001, 0.0, -0.001], v + [0.0, 0.003, 0.0]])
    new = correct(problem.system, None, "lbr_flange", plan, t_s, goal[:3], goal[3:])
    L = plan.t_end - t_s
    tau = np.linspace(0.0, L, 2001)
    n = 7

    def delta(x, d):  # the cubic with δ = δ̇ = 0 at 0, (a, b) at L, by its own Hermite formula in τ
        a, b = x[:n], x[n:]
        s = tau / L
        h = [(3 * s**2 - 2 * s**3, (6 * s - 6 * s**2) / L, (6 - 12 * s) / L**2),
             (L * (s**3 - s**2), 3 * s**2 - 2 * s, (6 * s - 2) / L)]
        return np.outer(h[0][d], a) + np.outer(h[1][d], b)

    def cost(x):
        return np.trapezoid(np.sum(delta(x, 2) ** 2, axis=1), tau) * 1e3

    def rows(x):
        q = plan.state(plan.t_end)[0] + x[:n]
        dq = plan.state(plan.t_end, 1)[0] + x[n:]
        pe, ve = flange_states(problem.system.model, "lbr_flange", q, dq)
        return np.concatenate([pe[0], ve[0]]) - goal

    ref = minimize(cost, np.zeros(2 * n), constraints={"type": "eq", "fun": rows}, method="SLSQP",
                   options={"ftol": 1e-14, "maxiter": 500})
    assert ref.success
    x_new = np.concatenate([(new.state(plan.t_end) - plan.state(plan.t_end))[0],
                            (new.state(plan.t_end, 1) - plan.state(plan.t_end, 1))[0]])
    assert np.abs(x_new - ref.x).max() < 1e-4 * np.abs(ref.x).max()
    assert cost(x_new) == pytest.approx(cost(ref.x), rel=1e-5)


def test_a_correction_beyond_the_limits_is_refused(catch):
    problem, plan = catch
    t_s = plan.t_end - 0.02
    p, v = _end(problem, plan)
    assert correct(problem.system, problem.limits, "lbr_flange", plan, t_s, p + [0.05, 0.0, 0.0], v) is None
    assert correct(problem.system, problem.limits, "lbr_flange", plan, plan.t_end, p, v) is None
