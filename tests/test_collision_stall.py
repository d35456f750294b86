"""A fixed-T link goal with collision enforcement and joint limits ends in seconds (no loop runs unbounded).

The catch of configs/catch_ball.yaml at T = 0.42 s over a table, with a 3 cm "lamp" that the plain catch passes
within 5 mm of: the goal rows' loop runs inside the limits' rounds inside the collision loop. Its inner solves
run at the collision loop's loose tolerance until the clearance is certified; a goal loop asking its rows met to
1e-12 at that tolerance grew its ρ ×10 on every inner solve that could not see the rest (to 1e20), and the limits'
rows could then no longer move the final state: the plan crawled for minutes.
"""
from __future__ import annotations

import pytest
import yaml
from _collision_tasks import ROOT, plan, task_folder

from hoc_cli.collision import enforce
from hoc_cli.goals import plan as goal_plan

LBR7 = {  # the lbr7's links as capsules (each link's own frame, m)
    "lbr_link_0": [{"capsule": {"a": [0, 0, 0.03], "b": [0, 0, 0.12], "radius": 0.08}}],
    "lbr_link_1": [{"capsule": {"a": [0, 0, 0.03], "b": [0, 0, 0.17], "radius": 0.07}}],
    "lbr_link_2": [{"capsule": {"a": [0, 0, 0.03], "b": [0, 0, 0.17], "radius": 0.065}}],
    "lbr_link_3": [{"capsule": {"a": [0, 0, 0.03], "b": [0, 0, 0.18], "radius": 0.065}}],
    "lbr_link_4": [{"capsule": {"a": [0, 0, 0.03], "b": [0, 0, 0.155], "radius": 0.06}}],
    "lbr_link_5": [{"capsule": {"a": [0, 0, 0.03], "b": [0, 0, 0.11], "radius": 0.05}}],
    "lbr_link_6": [{"sphere": {"radius": 0.065}}],
    "lbr_link_7": [{"capsule": {"a": [0, 0, 0.02], "b": [0, 0, 0.06], "radius": 0.04}}],
    "lbr_flange": [{"capsule": {"a": [0, 0, 0.0], "b": [0, 0, 0.12], "radius": 0.03}}],
}
TABLE = {"name": "table", "box": {"size": [0.6, 0.8, 0.04]}, "position": [0.65, 0.0, 0.23]}
LAMP = {"name": "lamp", "sphere": {"radius": 0.03}, "position": [0.70, 0.06, 0.54]}
ITERATIONS = 600  # inner iterations allowed in all (the fixed plan takes about 160)


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    return task_folder(tmp_path, monkeypatch, ("lbr7.urdf",))


def _catch(T: float) -> dict:
    doc = yaml.safe_load((ROOT / "configs" / "catch_ball.yaml").read_text())
    doc.pop("output", None)
    return doc | {"T": T, "N": 8, "collision": {"margin": 0.01, "robot": LBR7, "obstacles": [TABLE, LAMP]}}


def budget(monkeypatch, limit: int) -> None:
    """Every inner solve of ``plan_goals`` counted: beyond ``limit`` iterations in all the plan is stopped."""
    spent = [0]
    inner = goal_plan.minimize

    def counted(*args, callback=None, **kwargs):
        def each(log):
            spent[0] += 1
            if spent[0] > limit:
                raise RuntimeError(f"{spent[0]} inner iterations: the plan crawls")
            if callback is not None:
                callback(log)

        return inner(*args, callback=each, **kwargs)

    monkeypatch.setattr(goal_plan, "minimize", counted)


def test_the_catch_past_the_lamp_within_its_limits_ends_certified_in_a_few_hundred_iterations(workdir, monkeypatch):
    budget(monkeypatch, ITERATIONS)
    r, s = plan(workdir, _catch(0.42))
    assert r.exit_code == 0, (r.stderr, r.exception)
    assert s["converged"] and s["collision_enforce"]["status"] == "converged"
    c = s["min_clearance"]
    assert c["certified"] and c["lower_bound"] >= 0.01 - 1e-9 and c["pair"] == ["lbr_link_7", "lamp"]
    assert c["distance"] < 0.015  # the lamp binds
    assert s["reached"]["position_error"] <= 1e-9 and s["reached"]["velocity_error"] <= 1e-9
    assert s["limit_violations"] == [] and s["active_limits"]  # within the URDF's limits, some of them active



ARM = {"upper_arm": [{"capsule": {"a": [0, 0, 0], "b": [1, 0, 0], "radius": 0.05}}],
       "forearm": [{"capsule": {"a": [0, 0, 0], "b": [1, 0, 0], "radius": 0.05}}]}
BALL = {"name": "ball", "sphere": {"radius": 0.1}, "position": [1.75, 0, 0.55]}  # on the free plan's path


def test_a_collision_loop_that_spends_its_iterations_ends_with_a_status_and_says_why(tmp_path, monkeypatch):
    """The two-link arm round a ball takes 5 outer iterations; with a budget of 1 inner iteration the loop stops
    after its first: not converged (exit 1), the message naming the budget."""
    d = task_folder(tmp_path, monkeypatch, ("two_link.urdf",))
    doc = {"robot": "../robots/two_link.urdf", "x0": {"q": [0.0, 0.0]}, "x1": {"q": [1.2, -0.6]}, "T": 1.5, "N": 8,
           "collision": {"margin": 0.01, "robot": ARM, "obstacles": [BALL]}}
    monkeypatch.setattr(enforce, "MAX_ITERATIONS", 1)
    r, s = plan(d, doc)
    assert r.exit_code == 1 and "not converged: stopped when its inner solves had spent 1 iterations" in r.stderr
    assert not s["converged"] and s["collision_enforce"]["status"] == "not_converged"
    assert s["collision_enforce"]["outer_iterations"] == 1 and s["collision_enforce"]["start"] == "start"  # no via
    assert "forearm and ball come within" in s["message"]


def test_a_goal_plan_whose_collision_loop_spends_its_iterations_ends_not_converged(workdir, monkeypatch):
    """The lamp catch with a budget of 20 inner iterations per collision solve ends at once, not converged (exit 1)."""
    monkeypatch.setattr(enforce, "MAX_ITERATIONS", 20)
    r, s = plan(workdir, _catch(0.42))
    assert r.exit_code == 1 and "not converged" in r.stderr, r.stderr
    assert not s["converged"] and s["collision_enforce"]["status"] == "not_converged"
    assert s["collision_enforce"]["outer_iterations"] <= 2


def test_the_goal_rows_penalty_grows_at_most_rho_range_times_its_start(workdir, monkeypatch):
    """The lamp catch's goal loop takes ρ to 1e6 times its start; capped at 100 times, it stays there and the plan
    still ends with a status."""
    import hoc_cli.goals as goals

    monkeypatch.setattr(goal_plan, "RHO_RANGE", 100.0)
    started, results = [], []
    start, plan_goals = goal_plan.GoalTerms.start.__func__, goals.plan_goals

    def recorded_start(cls, mesh, points, rho=1.0):
        started.append(rho)
        return start(cls, mesh, points, rho)

    def recorded(*args, **kwargs):
        results.append(plan_goals(*args, **kwargs))
        return results[-1]

    monkeypatch.setattr(goal_plan.GoalTerms, "start", classmethod(recorded_start))
    monkeypatch.setattr(goals, "plan_goals", recorded)
    budget(monkeypatch, ITERATIONS)
    r, s = plan(workdir, _catch(0.42))
    assert r.exit_code in (0, 1) and s is not None, r.stderr
    assert len(started) == 1 and results
    assert results[-1].terms.rho <= 100.0 * started[0] * (1 + 1e-12)
    assert results[-1].terms.rho > 10.0 * started[0]  # the loop does grow it: the cap binds


def test_the_limits_rounds_penalty_grows_at_most_rho_max_times_its_start(workdir, monkeypatch):
    """The lamp catch's limits' rounds take ρ to 1e3·ρ0; capped at 100·ρ0, they stay there and the plan ends."""
    from hoc_cli.collision import limit_rounds

    monkeypatch.setattr(limit_rounds, "RHO_MAX", 100.0)
    ratios = []
    rounds = limit_rounds.LimitState.rounds

    def recorded(self, *args, **kwargs):
        got = rounds(self, *args, **kwargs)
        if self.rho is not None:
            ratios.append(self.rho / self.term.rho0)
        return got

    monkeypatch.setattr(limit_rounds.LimitState, "rounds", recorded)
    budget(monkeypatch, 3 * ITERATIONS)
    r, s = plan(workdir, _catch(0.42))
    assert r.exit_code in (0, 1) and s is not None, r.stderr
    assert ratios and max(ratios) <= 100.0 * (1 + 1e-12) and max(ratios) > 10.0
