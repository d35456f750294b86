"""Real-time replanning of a catch: the ball's ballistic estimate, the replanner (a real-time iteration of the
warm replan's SQP steps), the closed loop. Pure maths: no I/O (``hoc catch`` reads and writes the files).
"""
from hoc_cli.realtime.ballistic import BallEstimate, BallisticFit
from hoc_cli.realtime.replanner import CyclePlan, Replanner, Target

__all__ = ["BallEstimate", "BallisticFit", "CyclePlan", "Replanner", "Target"]
