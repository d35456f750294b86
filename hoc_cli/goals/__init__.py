"""Goals beyond a joint state at T: link poses (free final q), via points, a moving target.

``residuals`` (joint and frame residuals at one instant), ``terms`` (their augmented-Lagrangian
rows on a mesh), ``plan`` (``plan_goals``: the planner with these rows, and inverse kinematics for
the initial guess), ``mesh`` (meshes with the via times as nodes), ``replan`` (warm replans) and
``warm`` (a replan's previous plan from coefficients alone). Free final time is ``hoc_cli.free_time``;
docs/goals.md describes the maths.
"""
from hoc_cli.goals.plan import GoalProblem, GoalResult, Goals, inverse_kinematics, plan_goals
from hoc_cli.goals.residuals import FrameResidual, JointResidual, quaternion_matrix, rotation_angle
from hoc_cli.goals.terms import GoalPoint, GoalTerms

__all__ = ["FrameResidual", "GoalPoint", "GoalProblem", "GoalResult", "GoalTerms", "Goals", "JointResidual",
           "inverse_kinematics", "plan_goals", "quaternion_matrix", "rotation_angle"]
