"""The work of the free-T goal plans on the UR5 (issue 23's last bar: no slower than IPOPT): what each plan evaluates.

The UR5's fast catch (``_ur5_catch``) and the moving target of ``benchmarks/bench_robust.py`` (``tool0`` to a target at
(−0.3, 0.5, 0.5) m moving at (0.2, −0.1, 0) m/s, T free in [0.5, 3] s, weight 20, N = 8), both through ``hoc_cli.solve``.
Their answers are those of ``tests/test_robust_catch.py`` (the catch, against IPOPT) and of IPOPT at K = 32 (the moving
target: T 0.70512 s, J 189.699; ``bench_robust.py --ipopt --K 32``).
"""
from __future__ import annotations

import numpy as np
import pytest
from _ur5_catch import URDF, ur5_catch

pytestmark = pytest.mark.skipif(not URDF.is_file(), reason="example-robot-data is not installed")

CATCH_T, CATCH_J = 0.5893713573, 99.05157140535  # hoc's plan (T to 1e-9, J to 1e-10 relative)
MOVING_T, MOVING_J = 0.7051224316, 189.6991062976  # the same


def ur5_moving():
    """The moving target of ``bench_robust.py`` as an ``OptimalControlProblem``."""
    from hoc_cli import Free, JointLimits, OptimalControlProblem, RobotSystem, link_goal
    from hoc_cli.model import load_robot

    model = load_robot(URDF)
    arm = RobotSystem(model)
    goal = link_goal(arm, "tool0", position=[-0.3, 0.5, 0.5], velocity=[0.2, -0.1, 0.0], acceleration=[0, 0, 0])
    return OptimalControlProblem(arm, q0=[0.0, -1.57, 1.57, -1.57, -1.57, 0.0], dq0=np.zeros(6), link_goal=goal,
                                 time=Free(0.5, 3.0, weight=20.0, guess=1.5), N=8, limits=JointLimits.from_model(model))


def _moving_plan_counting(monkeypatch, owner, name: str, record) -> None:
    """Solve the moving target with ``owner.name`` wrapped: ``record(args, options)`` sees each call's arguments, and
    the plan must be the known one (converged, T to 1e-9, J to 1e-10 relative)."""
    import hoc_cli

    original = getattr(owner, name)

    def spy(*args, **options):
        record(args, options)
        return original(*args, **options)

    monkeypatch.setattr(owner, name, spy)
    plan = hoc_cli.solve(ur5_moving())
    assert plan.converged
    assert plan.T == pytest.approx(MOVING_T, rel=1e-9) and plan.J == pytest.approx(MOVING_J, rel=1e-10)


def _spy_on_replans(monkeypatch) -> list:
    """A list that ``free_time_sqp.replan`` appends (elements, Gauss points per element) of its start to at each call."""
    import hoc_cli.goals.free_time_sqp as fts

    starts: list = []
    replan = fts.replan

    def spy(system, previous, *args, **options):
        starts.append((previous.mesh.N, previous.G))
        return replan(system, previous, *args, **options)

    monkeypatch.setattr(fts, "replan", spy)
    return starts


@pytest.mark.parametrize("task", ["catch", "moving"])
def test_the_coarse_stage_on_fewer_gauss_points_reaches_the_same_plan(monkeypatch, task):
    """The coarse stage (4 elements) evaluates the cost, its gradient and its Hessian on ``COARSE_G`` = 5 Gauss points
    per element, the mesh's steps on its own 8: 5/8 of the coarse samples' dynamics, the same steps, and the plan the
    steps on 8 points everywhere reach (T to 1e-9, J to 1e-10 relative; measured: 2e-15)."""
    import hoc_cli
    from hoc_cli.goals.free_time_sqp import COARSE_G

    problem = ur5_catch()[3] if task == "catch" else ur5_moving()
    starts = _spy_on_replans(monkeypatch)
    plan = hoc_cli.solve(problem)
    assert plan.converged and plan.details["T_converged"]
    assert COARSE_G == 5
    assert {G for N, G in starts if N == 4} == {COARSE_G} and {G for N, G in starts if N == 8} == {8}
    assert plan.result.G == 8
    T, J = (CATCH_T, CATCH_J) if task == "catch" else (MOVING_T, MOVING_J)
    assert plan.T == pytest.approx(T, rel=1e-9) and plan.J == pytest.approx(J, rel=1e-10)


def test_a_step_whose_goal_rows_break_the_floor_is_corrected_without_its_dynamics(monkeypatch):
    """``replan_qp._corrected_step`` reads the full step's goal rows alone first: the dynamics at its end are evaluated
    only when they pass the violation floor (the merit test then needs its J). The moving target's steps evaluate the
    dynamics (``evaluate_point`` with derivatives) 30 times (32 when every full step's end was evaluated)."""
    import hoc_cli.goals.replan_qp as rq

    calls: list = []
    _moving_plan_counting(monkeypatch, rq, "evaluate_point", lambda a, o: calls.append(o.get("derivatives", True)))
    assert sum(calls) <= 30


def test_the_steps_in_x_and_T_start_from_the_last_point_of_the_steps_at_the_guess(monkeypatch):
    """The coarse runs share their points' problems (``replan``'s ``cache``): the moving target's steps in x and T start
    at the last point of the steps at the guess T, whose dynamics, goal rows and Hessian samples they reuse (25 Hessian
    sweeps, 26 when each run evaluated its first point afresh), and the plan is the same to the last bit."""
    from hoc_cli.problem import ControlProblem

    sweeps: list = []
    _moving_plan_counting(monkeypatch, ControlProblem, "hessian_samples", lambda a, o: sweeps.append(a[0].mesh.N))
    assert len(sweeps) <= 25


def test_the_goal_rows_checked_before_a_step_are_those_of_its_evaluation(monkeypatch):
    """``replan_point.goal_values`` (a step's goal rows read before its dynamics) makes the rows' pass of the point's
    evaluation (with the samples of their curvature) and keeps it: the evaluation that follows reuses it. The moving
    target's plan makes 55 passes of the tool's forward kinematics (83 when each evaluation made its own)."""
    from hoc_cli.goals.residuals import FrameResidual

    passes: list = []
    _moving_plan_counting(monkeypatch, FrameResidual, "batch", lambda a, o: passes.append(len(a[1])))
    assert len(passes) <= 55


def test_the_T_columns_points_come_from_the_evaluations_kinematics_pass(monkeypatch):
    """With a free T, ``GoalTerms.residuals_with_samples(C, V1)`` also holds the goal rows at (q, q̇, T) ± ε·δ that
    ``GoalTerms.time_column`` differences: its column, c' and Λ'' from them are its own pass's numbers to the last bit
    (the catch's goal at a point of its initial trajectory), and the moving target's steps make that pass once, in
    their points' evaluations (``terms._plus_minus`` once instead of 16 times)."""
    import hoc_cli.goals.terms as terms_module
    from hoc_cli.elements import HermiteMesh
    from hoc_cli.free_time import fixed_coefficient_motion
    from hoc_cli.goals.terms import GoalTerms
    from hoc_cli.goals.warm import initial_plan

    _, arm, _, problem = ur5_catch()
    start = initial_plan(arm, HermiteMesh("quintic", 0.55, 8), problem.q0, problem.dq0, problem.goals())
    C, T = start.coeffs, start.mesh.T
    V1, V2 = fixed_coefficient_motion(start.problem.layout.free, C, T)
    terms = GoalTerms(start.mesh, start.problem.points, [np.array([0.3, -0.2, 0.1, 0.5, 0.4, -0.6])], 0.0)
    res, samples = terms.residuals_with_samples(C, V1)
    alone = terms.time_column(C, T, V1, V2, terms.residuals(C))
    shared = terms.time_column(C, T, V1, V2, res, samples=samples)
    assert np.array_equal(alone[0], shared[0]) and np.array_equal(alone[1], shared[1]) and alone[2] == shared[2]

    calls: list = []
    _moving_plan_counting(monkeypatch, terms_module, "_plus_minus", lambda a, o: calls.append(1))
    assert len(calls) <= 1


@pytest.mark.parametrize("task", ["catch", "moving"])
def test_the_multipliers_confirmation_makes_no_hessian_sweep(monkeypatch, task):
    """``free_time_sqp._canonical_multipliers`` confirms the least-squares multipliers by steps whose Newton matrix is
    made of the sample Hessians that confirmed the plan (``GoalResult.newton_hessians``): no sweep of its own, and the
    plan the same (T to 1e-9, J to 1e-10 relative)."""
    import hoc_cli
    import hoc_cli.goals.free_time_sqp as fts
    from hoc_cli.problem import ControlProblem

    inside, sweeps = [False], []
    hessian_samples, canonical = ControlProblem.hessian_samples, fts._canonical_multipliers

    def spy(self, *args, **options):
        sweeps.append(inside[0])
        return hessian_samples(self, *args, **options)

    def confirming(*args, **options):
        inside[0] = True
        try:
            return canonical(*args, **options)
        finally:
            inside[0] = False

    monkeypatch.setattr(ControlProblem, "hessian_samples", spy)
    monkeypatch.setattr(fts, "_canonical_multipliers", confirming)
    plan = hoc_cli.solve(ur5_catch()[3] if task == "catch" else ur5_moving())
    assert plan.converged
    T, J = (CATCH_T, CATCH_J) if task == "catch" else (MOVING_T, MOVING_J)
    assert plan.T == pytest.approx(T, rel=1e-9) and plan.J == pytest.approx(J, rel=1e-10)
    assert sweeps and not any(sweeps)
