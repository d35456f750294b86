"""Constraints on the plan: joint limits as data, their check on a plan, and their enforcement.

``JointLimits`` (bounds.py) holds the limits; ``check_limits`` (check.py) checks a plan exactly;
``enforce`` (augmented_lagrangian.py) solves the limited problem: the unconstrained solve first,
then an SQP on the linear kinematic rows (sqp.py), and where effort binds or the SQP fails the
augmented Lagrangian (auglag.py: one loop, its constraints as terms) with the limits' term
(``LimitTerm`` over ``LimitTerms``, penalty.py; effort at a ``PointSet``, points.py).
"""
from hoc_cli.constraints.augmented_lagrangian import EnforceResult, enforce, shortest_duration
from hoc_cli.constraints.bounds import KINDS, JointLimits
from hoc_cli.constraints.check import LimitCheck, check_limits

__all__ = ["JointLimits", "KINDS", "LimitCheck", "check_limits", "EnforceResult", "enforce", "shortest_duration"]
