"""The UR5 fast catch of issue 23, shared by the tests of the free-T goal solver on a third-party robot.

UR5 (example-robot-data), ``tool0`` catches a ball tossed from (0.9, 0.6, 0.2) m at (−0.86, −0.3, 2.8) m/s under
gravity, ``match_velocity``, T free in [0.3, T_max] s from the guess 0.5 s, the URDF's limits enforced.
"""
from __future__ import annotations

import numpy as np
from _robots import ERD

URDF = ERD / "ur_description/urdf/ur5_robot.urdf"
P0, V0, A0 = np.array([0.9, 0.6, 0.2]), np.array([-0.86, -0.3, 2.8]), np.array([0.0, 0.0, -9.81])
Q0 = [0, -1.57, 1.57, -1.57, -1.57, 0]


def ur5_catch(N: int = 8, T_max: float = 0.8):
    """(model, arm, limits, problem) of the catch on N elements, T free in [0.3, T_max] s from 0.5 s."""
    from hoc_cli import Free, JointLimits, OptimalControlProblem, RobotSystem, link_goal
    from hoc_cli.model import load_robot

    model = load_robot(URDF)
    arm = RobotSystem(model)
    limits = JointLimits.from_model(model)
    ball = link_goal(arm, "tool0", position=P0, velocity=V0, acceleration=A0, match_velocity=True)
    return model, arm, limits, OptimalControlProblem(arm, q0=Q0, dq0=np.zeros(6), link_goal=ball,
                                                     time=Free(0.3, T_max, guess=0.5), N=N, limits=limits)


def catch_task(path, N: int = 8, T_max: float = 0.8) -> None:
    """The same catch as a task file at ``path``."""
    path.write_text(f"""robot: {URDF}
x0: {{q: {Q0}}}
x1:
  link: tool0
  target: {{position: {P0.tolist()}, velocity: {V0.tolist()}, acceleration: {A0.tolist()}}}
  match_velocity: true
T: {{free: true, min: 0.3, max: {T_max}, guess: 0.5}}
N: {N}
""")
