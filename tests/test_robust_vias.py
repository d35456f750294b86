"""A free T with joint vias alone (pinned on mesh nodes, no goal rows) and a binding velocity limit (issue 23).

Such a plan has no goal rows, so the free-T SQP's working set is its only multiplier block; that plan crashed
(an IndexError in the replan) before. Checked against hoc's fixed-T plans (``plan_goals``: continuation and
augmented-Lagrangian loops, another solver): at T* the same J (1e-7), at T* ± 2 % a higher J (weight 0, an
interior optimum), within the limits.
"""
from __future__ import annotations

import dataclasses

from _robots import ROBOTS

import hoc_cli
from hoc_cli import Fixed, Free, JointLimits, OptimalControlProblem, RobotSystem, joint_via, load_robot
from hoc_cli.constraints.check import check_limits


def test_a_free_time_through_a_pinned_joint_via_with_a_binding_velocity_limit():
    model = load_robot(ROBOTS / "two_link.urdf")
    arm = RobotSystem(model)
    limits = JointLimits.from_model(model).with_overrides(velocity={"shoulder": 0.9})
    problem = OptimalControlProblem(arm, q0=[0.0, 0.0], dq0=[0.0, 0.0], q1=[1.2, -0.6], N=16, limits=limits,
                                    vias=(joint_via([0.9, 0.3], s=0.65),), time=Free(1.5, 2.0, guess=2.0))
    plan = hoc_cli.solve(problem)
    assert plan.converged and plan.details["T_bound"] is None and 1.5 < plan.T < 2.0
    assert abs(plan.details["dJ_dT"]) <= 1e-6 * plan.J / plan.T
    assert check_limits(arm, limits, plan.mesh, plan.coeffs).feasible
    fixed = [hoc_cli.solve(dataclasses.replace(problem, time=Fixed(plan.T * f))) for f in (0.98, 1.0, 1.02)]
    assert all(p.converged for p in fixed)
    assert abs(fixed[1].J - plan.J) <= 1e-7 * plan.J
    assert fixed[0].J > plan.J and fixed[2].J > plan.J
