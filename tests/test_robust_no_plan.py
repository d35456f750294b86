"""The UR5 fast catch (tests/test_robust_catch.py) on the paths that skip the coarse stage, and with no plan in its T range.

Two ways the free-T SQP (``hoc_cli.goals.free_time_sqp``) reached the steps at a guess T that admits no plan within the
limits (T = 0.5 s: IPOPT ``Infeasible_Problem_Detected``), whose programmes' multipliers then grew ×1e4 a step (each
enters the next Newton matrix as Σλ∇²c) until the matrix overflowed and scipy's banded Cholesky factorisation raised a
``ValueError`` (``hoc plan``: "internal error"):

- the restoration on the mesh itself (``coarse=0``, vias, a non-uniform mesh, N < 8) gave up after 60 steps where the
  catch on 10 elements needs 62 (16 elements: 97) and the steps ran from the unrestored guess;
- the T range holds no T where the catch meets the limits (max 0.5 s): the restoration stalls.

The first now converges to the coarse path's optimum; the second ends at once, not converged (``max_iter``).
"""
from __future__ import annotations

import json
import subprocess
import sys
import time

import numpy as np
import pytest
from _ur5_catch import URDF, catch_task, ur5_catch

pytestmark = pytest.mark.skipif(not URDF.is_file(), reason="example-robot-data is not installed")


def _catch(N: int, T_max: float):
    """(arm, problem, goals, limits) of the UR5 catch on N elements, T free in [0.3, T_max] from the guess 0.5 s."""
    _, arm, limits, problem = ur5_catch(N, T_max)
    return arm, problem, problem.goals(), limits


def test_the_catch_on_10_elements_restored_on_them_meets_the_optimum_by_way_of_the_coarse_elements():
    """With the coarse stage off (``coarse=0``: the path of vias, non-uniform meshes and N < 8) the restoration on the
    10 elements takes 15 steps (62 without re-solving a rejected trial with the rows it broke) to a T where the catch
    meets the limits, and the steps from there reach the optimum of the coarse path: T and J to 1e-8 relative. On main the restoration
    stopped at 60 steps and the steps at the guess ended in a ``ValueError``."""
    from hoc_cli.goals.free_time_sqp import minimize_time_sqp
    from hoc_cli.goals.time_solver import goal_solver

    arm, problem, goals, limits = _catch(10, 0.8)
    solver = goal_solver(arm, "quintic", 10, problem.q0, problem.dq0, goals, limits=limits)
    fine, coarse = (minimize_time_sqp(solver, arm, goals, 0.3, 0.8, guess=0.5, limits=limits, coarse=c) for c in (0, 4))
    assert fine.converged and coarse.converged and fine.bound is None
    assert fine.T == pytest.approx(coarse.T, rel=1e-8) and fine.J == pytest.approx(coarse.J, rel=1e-8)


def test_a_catch_with_no_T_in_its_range_ends_at_once_not_converged():
    """T in [0.3, 0.5] s: the restoration over x and T stalls (a local minimum of the violation) with no T where the catch
    meets the (tightened) limits, and the steps at the guess stop when their programmes run away (``replan_qp.RUNAWAY``): a plan not converged, ``max_iter``,
    at the guess, within seconds (no search over T: its fixed-T solves there ran for minutes)."""
    import hoc_cli
    from hoc_cli.goals.replan import TimeRange
    from hoc_cli.goals.restoration import restore
    from hoc_cli.goals.time_solver import goal_solver

    arm, problem, goals, limits = _catch(8, 0.5)
    start = goal_solver(arm, "quintic", 8, problem.q0, problem.dq0, goals, limits=limits).initial(0.5)
    found = restore(arm, start, goals, limits, span=TimeRange(0.3, 0.5))
    assert not found.feasible and found.stalled
    t0 = time.process_time()
    plan = hoc_cli.solve(problem)
    assert time.process_time() - t0 < 30.0
    assert not plan.converged and not plan.details["T_converged"] and plan.T == 0.5
    assert plan.result.optimizer.status.value == "max_iter" and np.isfinite(plan.J)
    assert "no T in [0.3, 0.5] s found" in plan.result.optimizer.message


def test_hoc_plan_reports_the_catch_with_no_T_in_its_range_on_4_elements_as_not_converged(tmp_path):
    """The same from the command line on 4 elements (no coarse stage): exit 1, ``status: max_iter``; on main
    ``hoc: error: internal error (ValueError: array must not contain infs or NaNs)``."""
    task = tmp_path / "ur5_catch.yaml"
    catch_task(task, N=4, T_max=0.5)
    out = subprocess.run([sys.executable, "-c", "import sys; from hoc_cli.cli import app; sys.exit(app())", "plan", str(task), "-o", "none", "--json"],
                         capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert out.returncode == 1, out.stderr
    assert "internal error" not in out.stderr and "no T in [0.3, 0.5] s found" in out.stderr
    s = json.loads(out.stdout)
    assert s["status"] == "max_iter" and s["T"] == 0.5 and s["T_converged"] is False


def test_a_goal_plan_whose_newton_matrix_overflows_raises_a_numerical_error(monkeypatch):
    """A goal plan (``plan_goals``: the search's fixed-T solves) whose Newton matrix leaves the floating-point range (the
    UR5 catch with a via at s = 0.3 on 6 elements: the search's plan at T = 0.68 s diverged to a cost of 3e300 in 29 s,
    too slow for this file) raises ``NumericalError`` (``hoc plan``: exit 1, one line), not scipy's ``ValueError``
    (``hoc plan``: "internal error"). Here the banded factorisation sees an infinite matrix from the first step."""
    import hoc_cli.banded
    from hoc_cli.dynamics import link_poses
    from hoc_cli.elements import HermiteMesh
    from hoc_cli.errors import NumericalError
    from hoc_cli.goals import FrameResidual, Goals, plan_goals
    from hoc_cli.model import load_robot
    from hoc_cli.system import RobotSystem
    from tests._robots import ROBOTS

    lbr = load_robot(ROBOTS / "lbr7.urdf")
    q0 = np.array([0.0, 0.6, 0.0, -1.4, 0.0, 0.9, 0.0])
    target = link_poses(lbr, q0 + 0.2)["lbr_flange"][:3, 3]
    factor = hoc_cli.banded.cholesky_banded
    monkeypatch.setattr(hoc_cli.banded, "cholesky_banded", lambda ab, lower=False: factor(np.full_like(ab, np.inf), lower=lower))
    with pytest.raises(NumericalError, match="not finite"):
        plan_goals(RobotSystem(lbr), HermiteMesh("quintic", 1.0, 4), q0, np.zeros(7),
                   Goals(final=FrameResidual(lbr, "lbr_flange", target)))
