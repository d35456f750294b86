"""The SQP steps of ``hoc_cli.goals.replan_qp`` keep the last Newton matrix only after a step that barely moved.

A step whose programme predicted a negative decrease (the goal or limit rows forced a rise of the model, far from
the optimum) is not small: reusing its matrix at the next point, with another working set, left the next
programme's T row inconsistent (‖U⁻ᵀb‖² of 1e17 against h ≈ 3e8: T frozen for a step) and its x step too long.
On the lbr7 catch under the torque cost this made the free-T steps zigzag 62 times, past their cap of 60, and the
search over fixed-T solves then ran for minutes (``hoc plan configs/catch_ball.yaml --cost torque``).

The check here spies on the steps of the (covariant) lbr7 catch, whose cold steps from the initial trajectory
have negative decreases: after each, the next programme of the same replan is solved with a new factor (the first
programme of the next replan takes its plan's last factor, at that very point, by design).
"""
from __future__ import annotations

import numpy as np

import hoc_cli
import hoc_cli.goals.replan as replan_module
import hoc_cli.goals.replan_qp as replan_qp
from hoc_cli import Free, JointLimits, OptimalControlProblem, RobotSystem, link_goal, load_robot
from hoc_cli.goals.replan_qp import LAG_RTOL, keeps_factor
from tests._robots import ROBOTS


def test_a_negative_decrease_is_not_a_small_step():
    J = 440.0
    assert keeps_factor(0.0, J) and keeps_factor(0.5 * LAG_RTOL * J, J) and keeps_factor(-0.5 * LAG_RTOL * J, J)
    assert not keeps_factor(-0.15, J)  # a forced rise of the model (the torque catch's step 22)
    assert not keeps_factor(2.0 * LAG_RTOL * J, J)


def test_after_a_step_with_a_negative_decrease_the_next_programme_has_a_new_factor(monkeypatch):
    events: list = []
    solve_qp, dense_factor = replan_qp.solve_qp, replan_qp.dense_factor

    def spy_qp(U, *args, **kwargs):
        step = solve_qp(U, *args, **kwargs)
        events.append(("qp", step.decrease))
        return step

    def spy_factor(W):
        events.append(("factor", None))
        return dense_factor(W)

    monkeypatch.setattr(replan_qp, "solve_qp", spy_qp)
    monkeypatch.setattr(replan_qp, "dense_factor", spy_factor)
    steps = replan_module.qp_steps

    def spy_steps(*args, **kwargs):
        events.append(("replan", None))
        return steps(*args, **kwargs)

    monkeypatch.setattr(replan_module, "qp_steps", spy_steps)
    within, correct, keeps = replan_qp.solve_qp_within, replan_qp._corrected_step, replan_qp.keeps_factor

    def spy_within(U, *args, **kwargs):
        step = within(U, *args, **kwargs)
        events.append(("qp", step.decrease))
        return step

    def spy_correct(*args, **kwargs):  # its programme shares the step's factor: not the next step's programme
        events.append(("correction", None))
        out = correct(*args, **kwargs)
        events.append(("corrected", None))
        return out

    def spy_keeps(*args):  # asked at the start of every step after a replan's first
        events.append(("step", None))
        return keeps(*args)

    monkeypatch.setattr(replan_qp, "solve_qp_within", spy_within)
    monkeypatch.setattr(replan_qp, "_corrected_step", spy_correct)
    monkeypatch.setattr(replan_qp, "keeps_factor", spy_keeps)
    lbr = load_robot(ROBOTS / "lbr7.urdf")
    arm = RobotSystem(lbr)
    ball = link_goal(arm, "lbr_flange", position=[0.6725, -0.0375, 0.1246], velocity=[-0.15, 0.25, 3.13],
                     acceleration=[0.0, 0.0, -9.81], match_velocity=True)
    problem = OptimalControlProblem(arm, q0=[0.0, 0.6, 0.0, -1.4, 0.0, 0.9, 0.0], dq0=np.zeros(7), link_goal=ball,
                                    time=Free(0.3, 0.5, guess=0.35), N=8, limits=JointLimits.from_model(lbr))
    plan = hoc_cli.solve(problem)
    assert plan.converged
    inside, kept = False, []
    for event in events:  # the corrections' programmes left out: they share their step's factor
        inside = (inside or event[0] == "correction") and event[0] != "corrected"
        if not inside and event[0] not in ("correction", "corrected"):
            kept.append(event)
    rises = 0
    for i, (kind, _) in enumerate(kept):
        if kind != "step":
            continue
        before = [e for e in kept[:i] if e[0] in ("qp", "step", "replan")]
        if len(before) < 1 or before[-1][0] != "qp" or not before[-1][1] < -1e-6:
            continue  # the last step's last programme (its expansions' last) did not predict a rise
        following = kept[i + 1:]
        nxt = next((j for j, e in enumerate(following) if e[0] == "qp"), None)
        if nxt is None:
            continue
        rises += 1
        assert ("factor", None) in following[:nxt], f"step {i}: the last factor reused after a rise {before[-1][1]}"
    assert rises >= 2  # the cold steps of this catch have such steps (else the check above checks nothing)
