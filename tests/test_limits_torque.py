"""The torque cost with limits enforced on a light-wristed arm (benchmarks/tasks/panda_torque.yaml):
the levels of the continuation end on the SQP, started from the coarser level's multipliers."""
from __future__ import annotations

import numpy as np
import pytest

from hoc_cli.constraints import JointLimits
from hoc_cli.elements import HermiteMesh
from hoc_cli.model import load_robot
from hoc_cli.planner import plan
from hoc_cli.system import RobotSystem
from tests._robots import ERD

PANDA = ERD / "panda_description" / "urdf" / "panda.urdf"


@pytest.mark.skipif(not PANDA.exists(), reason="example-robot-data not installed")
def test_the_panda_torque_move_ends_on_the_sqp_within_its_limits():
    """N = 32 (levels 4, 16, 32). Measured: 391 iterations with numpy 2.4.6 / SciPy 1.17.1, the last level's SQP
    converged (with earlier versions 424, the SQP stalled at its QP's accuracy and the augmented Lagrangian started
    from its multipliers finished in a few rounds: rounding decides which); with every level's augmented Lagrangian
    restarted from λ = 0 (and the wrist's idle effort rows kept) 870 iterations.
    """
    model = load_robot(PANDA, joints=[f"panda_joint{i}" for i in range(1, 8)], locked={"panda_finger_joint1": 0.02})
    q0 = np.array([0, -0.785398, 0, -2.35619, 0, 1.5707, 0.785398])
    q1 = np.array([1.0, 0.3, -0.6, -1.6, 0.5, 2.2, -0.3])
    zero = np.zeros(7)
    r = plan(RobotSystem(model), HermiteMesh("quintic", 2.0, 32), q0, zero, q1, zero, cost="torque",
             limits=JointLimits.from_model(model))
    assert r.converged and r.limits.check.violations() == []
    assert r.limits.sqp in ("converged", "stalled") and r.limits.outer_iterations <= 10
    assert not r.limits.working[3].any()  # the wrist's effort rows left the working set
    assert r.optimizer.iterations <= 500, r.optimizer.iterations
