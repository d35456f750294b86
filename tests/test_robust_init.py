"""``--init`` from a plan on a finer or coarser mesh keeps its optimum (issue 23).

A fixed-T plan with goals warm-started from another mesh's plan (resampled, as ``hoc plan --init`` does) starts
from that plan's goal multipliers and its limits' working set and multipliers, estimated by least squares
(``hoc_cli.goals.warm.estimate_state``), instead of zeros and an empty working set: otherwise its first inner
solve is the unconstrained one, which leaves the optimum (on the Panda of example-robot-data it ran 195
iterations instead of 45, and the issue's Panda plan landed in a dearer local optimum, 323.23 against 312.16).

Two-link arm, the tool to a point at rest in T = 1.5 s, velocity limits 1.2 rad/s binding: the warm plans equal
the cold plans of their mesh to 1e-3 of the discretisation error |J(16) − J(32)|, in at most half their iterations.
"""
from __future__ import annotations

from _robots import ROBOTS

import hoc_cli
from hoc_cli import Fixed, JointLimits, OptimalControlProblem, RobotSystem, WarmStart, link_goal, load_robot
from hoc_cli.elements import HermiteMesh
from hoc_cli.planner import resample


def test_a_warm_start_from_a_finer_or_coarser_mesh_keeps_the_optimum():
    model = load_robot(ROBOTS / "two_link.urdf")
    arm = RobotSystem(model)
    limits = JointLimits.from_model(model).with_overrides(velocity={"shoulder": 1.2, "elbow": 1.2})

    def problem(N: int) -> OptimalControlProblem:
        return OptimalControlProblem(arm, q0=[0.0, 0.0], dq0=[0.0, 0.0], time=Fixed(1.5), N=N, limits=limits,
                                     link_goal=link_goal(arm, "tool", position=[1.0, 0.0, 1.2]))

    cold = {N: hoc_cli.solve(problem(N)) for N in (16, 32)}
    assert all(p.converged and p.result.limits.working.any() for p in cold.values())  # the limits bind
    discretisation = abs(cold[16].J - cold[32].J)
    for a, b in ((32, 16), (16, 32)):
        mesh = HermiteMesh("quintic", 1.5, b)
        warm = hoc_cli.solve(problem(b), warm=WarmStart(mesh, resample(cold[a].mesh, cold[a].coeffs, mesh), cold[a].result.G))
        assert warm.converged
        assert abs(warm.J - cold[b].J) <= 1e-3 * discretisation
        assert warm.result.optimizer.iterations <= cold[b].result.optimizer.iterations / 2
