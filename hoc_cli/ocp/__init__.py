"""The optimal-control problem (``OptimalControlProblem``), its time (``Fixed``, ``Free``) and goals built
from Python (``link_goal``, ``joint_via``, ``link_via``); ``hoc_cli.solve`` plans it.
"""
from hoc_cli.ocp.goals import joint_via, link_goal, link_via
from hoc_cli.ocp.problem import Fixed, Free, OptimalControlProblem

__all__ = ["Fixed", "Free", "OptimalControlProblem", "joint_via", "link_goal", "link_via"]
