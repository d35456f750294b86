"""A link goal in a fixed T within enforced limits: SQP steps from the initial trajectory (``plan_fixed_time``).

The Panda (example-robot-data) reaches a point at rest in T = 1.5 s from the ready pose, the URDF's limits
enforced, N = 16. The goal fixes three of seven joint coordinates, so the problem has many local optima; steps of a
local model (as IPOPT's) follow the one nearest the initial trajectory, where the augmented Lagrangian's first
subproblem (the goal rows at λ = 0 and a small ρ, the limits not yet imposed) ran the arm's last joint 10 rad away
and ended 1.2 % and 1.3 % dearer on these two targets. References: CasADi + IPOPT (``benchmarks/_casadi_goals``,
Radau collocation on K = 32 intervals, cold from the same inverse-kinematics guess): J and the final q.
"""
from __future__ import annotations

import numpy as np
import pytest
from _robots import ERD, ROBOTS

import hoc_cli
from hoc_cli import Fixed, JointLimits, OptimalControlProblem, RobotSystem, link_goal, load_robot
from hoc_cli.constraints.check import check_limits

PANDA = ERD / "panda_description/urdf/panda.urdf"
Q0 = [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]
IPOPT = {  # target (m): (J at K = 32, final q (rad))
    (0.4, -0.3, 0.5): (191.66998238288917, [-2.0386, 0.0053, 1.537, -2.3955, -2.6129, 0.9189, 2.233]),
    (0.5, -0.2, 0.2): (252.43007525253472, [0.0997, 0.4156, -0.5322, -2.2592, -0.9488, 2.7656, -2.0796]),
}


@pytest.mark.parametrize("target", list(IPOPT))
def test_a_panda_reach_ends_at_the_optimum_ipopt_finds_from_the_same_start(target):
    model = load_robot(PANDA, joints=[f"panda_joint{i}" for i in range(1, 8)], locked={"panda_finger_joint1": 0.02})
    arm = RobotSystem(model)
    limits = JointLimits.from_model(model)
    problem = OptimalControlProblem(arm, q0=Q0, dq0=np.zeros(7), link_goal=link_goal(arm, "panda_link8", position=target),
                                    time=Fixed(1.5), N=16, limits=limits)
    plan = hoc_cli.solve(problem)
    J_ref, q1_ref = IPOPT[target]
    assert plan.converged and plan.result.optimizer.message.startswith("SQP steps")
    assert abs(plan.J - J_ref) <= 1e-3 * J_ref  # the meshes' discretisation errors: 3e-4 measured
    # the same arm configuration at T (joint 7 turns the flange about its own axis: the goal does not see it, and the
    # cost barely, so its final angle is loosely determined and differs by up to 1.4 rad between the transcriptions)
    assert np.max(np.abs(plan.coeffs[-1, 0, :6] - q1_ref[:6])) <= 0.05
    assert check_limits(arm, limits, plan.mesh, plan.coeffs).feasible
    assert plan.result.violation <= 1e-9
    assert 0.0 <= plan.result.quadrature_change <= 1e-12


def test_a_binding_effort_limit_ends_the_steps_early_and_the_loops_plan():
    """The SQP steps impose the kinematic limits only: with an effort limit that binds, their end fails the exact
    check, and a coarse stage's early stop (``accuracy``) goes on once to the full test, then stops (not after
    ``max_steps``); ``hoc_cli.solve`` then plans by ``plan_goals``, whose loops hold the effort limit.
    """
    from hoc_cli.elements import HermiteMesh
    from hoc_cli.goals.free_time_sqp import COLD_FLOOR
    from hoc_cli.goals.replan import replan
    from hoc_cli.goals.warm import initial_plan

    model = load_robot(ROBOTS / "two_link.urdf")
    arm = RobotSystem(model)
    limits = JointLimits.from_model(model).with_overrides(effort={"shoulder": 18.0, "elbow": 18.0})
    problem = OptimalControlProblem(arm, q0=[0.0, 0.0], dq0=[0.0, 0.0], time=Fixed(1.5), N=16, limits=limits,
                                    link_goal=link_goal(arm, "tool", position=[1.0, 0.0, 1.2]))
    goals = problem.goals()
    start = initial_plan(arm, HermiteMesh("quintic", 1.5, 4), problem.q0, problem.dq0, goals)
    r = replan(arm, start, goals, limits=limits, fallback=False, max_steps=200, violation_floor=COLD_FLOOR,
               merit=True, accuracy=1e-6)
    assert not r.converged and r.steps < 50
    plan = hoc_cli.solve(problem)
    assert plan.converged and not plan.result.optimizer.message.startswith("SQP steps")
    assert any(a["kind"] == "effort" for a in plan.result.limits.active_limits())
    assert check_limits(arm, limits, plan.mesh, plan.coeffs).feasible
