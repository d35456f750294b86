"""A fast catch on a third-party robot whose guess T admits no plan within the limits (issue 23).

UR5 (example-robot-data), ``tool0`` catches a ball tossed from (0.9, 0.6, 0.2) m at (−0.86, −0.3, 2.8) m/s
under gravity, ``match_velocity``, T free in [0.3, 0.8] s from the guess 0.5 s, N = 8, the URDF's limits
enforced. At T = 0.5 s the catch is infeasible within the limits (IPOPT: ``Infeasible_Problem_Detected``
at K = 8 and 32); the free-T SQP must move T (``hoc_cli.goals.restoration``) instead of pushing the
trajectory at the guess.

The reference is CasADi + IPOPT on the same continuous problem (benchmarks/_casadi_goals.py, degree-3
Radau collocation, the URDF's position, velocity and effort limits), cold from the quintic to hoc's
inverse-kinematics guess at T = 0.5 s, measured 2026-12-01 by
``python benchmarks/bench_robust.py --ipopt --K 8 32`` (casadi 3.8.2):

    K =  8: T* = 0.5893717504 s, J* = 99.0494090733
    K = 32: T* = 0.5893715205 s, J* = 99.0495892335

hoc (N = 8) must meet both within 1 % (the issue's bar; measured: T to 1e-6, J to 2e-5), end converged,
meet the goal by Pinocchio's forward kinematics and break no limit by hoc's exact check.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from _robots import PinocchioOracle, steps_on_mesh
from _ur5_catch import A0, P0, URDF, V0, catch_task, ur5_catch

from hoc_cli.elements import HermiteMesh
from hoc_cli.model import load_robot

pytestmark = pytest.mark.skipif(not URDF.is_file(), reason="example-robot-data is not installed")

T_IPOPT, J_IPOPT = 0.5893715205, 99.0495892335  # K = 32 (module docstring)


def _plan(task, threads: int, numpy_first: bool = False) -> dict:
    """``hoc plan TASK --json`` in a subprocess with OPENBLAS_NUM_THREADS = ``threads``, numpy imported first or not."""
    code = ("import numpy, scipy.linalg; " if numpy_first else "") + "import sys; from hoc_cli.cli import app; sys.exit(app())"
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", code, "plan", str(task), "-o", "none", "--json"], capture_output=True,
                         text=True, timeout=120, cwd=task.parent, env=env | {"OPENBLAS_NUM_THREADS": str(threads)})
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


@pytest.fixture(scope="module")
def one_thread_plan(tmp_path_factory) -> dict:
    task = tmp_path_factory.mktemp("catch") / "ur5_catch.yaml"
    catch_task(task)
    return _plan(task, 1)


def test_a_catch_infeasible_at_its_guess_moves_T_and_meets_ipopt(one_thread_plan):
    s = one_thread_plan
    assert s["status"] == "converged" and s["T_converged"] and s["T_bound"] is None
    assert abs(s["T"] - T_IPOPT) <= 1e-2 * T_IPOPT and abs(s["cost"] - J_IPOPT) <= 1e-2 * J_IPOPT
    assert abs(s["dJ_dT"]) <= 1e-4 * s["cost"] / s["T"]  # stationary in T (weight 0)
    assert s["limit_violations"] == []
    model = load_robot(URDF)
    q1 = np.array([s["final_q"][j] for j in model.joint_names])
    T = s["T"]
    reached = PinocchioOracle(model).link_pose(q1, "tool0")[:3, 3]
    assert np.abs(reached - (P0 + V0 * T + 0.5 * A0 * T * T)).max() < 1e-9


@pytest.mark.parametrize("threads, numpy_first", [(2, False), (2, True)], ids=["2 threads", "2 threads, numpy first"])
def test_the_same_catch_with_two_blas_threads_and_after_numpy(one_thread_plan, tmp_path, threads, numpy_first):
    """Rounding does not decide the catch (issue 23): with two OpenBLAS threads, and with numpy and scipy loaded
    (with two threads) before hoc, T and J agree with the one-thread plan to 1e-8 relative, by the same steps: hoc
    solves on one BLAS thread whatever was loaded (``hoc_cli.optimize.blas``). Measured without that control, numpy
    first with two threads: J and T still agree to 1e-12, but after 78 steps instead of 51 and in 62 s instead of 6."""
    task = tmp_path / "ur5_catch.yaml"
    catch_task(task)
    s, s1 = _plan(task, threads, numpy_first), one_thread_plan
    assert s["status"] == "converged" and s["T_converged"]
    assert abs(s["T"] - s1["T"]) <= 1e-8 * s1["T"] and abs(s["cost"] - s1["cost"]) <= 1e-8 * s1["cost"]
    assert s["iterations"] == s1["iterations"]


def test_the_restoration_finds_a_T_where_the_catch_meets_its_goal_within_the_kinematic_limits():
    """``restore`` from the initial trajectory at the guess: over x alone it cannot meet the rows at T = 0.5 s
    (infeasible there, by IPOPT); over x and T it ends at a T in (0.5, T*] where the returned trajectory meets the
    goal (Pinocchio's forward kinematics, 1e-8 m) and the kinematic limits by hoc's exact extrema check (the
    restoration leaves effort to the steps that follow)."""
    from hoc_cli.constraints.bounds import KINEMATIC
    from hoc_cli.constraints.check import check_limits
    from hoc_cli.goals.replan import TimeRange
    from hoc_cli.goals.restoration import restore
    from hoc_cli.goals.time_solver import goal_solver

    model, arm, limits, problem = ur5_catch()
    goals = problem.goals()
    start = goal_solver(arm, "quintic", 8, problem.q0, problem.dq0, goals, limits=limits).initial(0.5)
    assert not restore(arm, start, goals, limits, max_steps=20).feasible
    found = restore(arm, start, goals, limits, span=TimeRange(0.3, 0.8))
    assert found.feasible and 0.5 < found.T <= T_IPOPT
    mesh = HermiteMesh("quintic", found.T, 8)
    check = check_limits(arm, limits, mesh, found.coeffs)
    assert np.all(check.hi_excess[:KINEMATIC] <= 0) and np.all(check.lo_excess[:KINEMATIC] <= 0)
    reached = PinocchioOracle(model).link_pose(found.coeffs[-1, 0], "tool0")[:3, 3]
    assert np.abs(reached - (P0 + V0 * found.T + 0.5 * A0 * found.T ** 2)).max() < 1e-8


def test_the_restoration_on_the_coarse_elements_reaches_the_optimum_of_the_steps_on_the_mesh(monkeypatch):
    """Where the coarse stage applies (``free_time_sqp._coarse_first``: 8 equal elements, no vias) the restoration runs
    on its 4 elements, and the coarse optimum then takes a few steps in x and T on the mesh (one plan there): the
    optimum of the restoration and the steps on the 8 elements alone (``coarse=0``, two plans: at the restored T and
    the steps in x and T), T to 1e-9 and J to 1e-10 relative. Restored on the mesh, the trajectory resampled to the
    coarse elements broke a limit and the coarse stage never ran."""
    from hoc_cli.goals.free_time_sqp import minimize_time_sqp
    from hoc_cli.goals.time_solver import goal_solver

    model, arm, limits, problem = ur5_catch()
    goals = problem.goals()
    solver = goal_solver(arm, "quintic", 8, problem.q0, problem.dq0, goals, limits=limits)
    fine = minimize_time_sqp(solver, arm, goals, 0.3, 0.8, guess=0.5, limits=limits, coarse=0)
    on_mesh = steps_on_mesh(monkeypatch, 8)
    coarse = minimize_time_sqp(solver, arm, goals, 0.3, 0.8, guess=0.5, limits=limits, coarse=4)
    assert fine.converged and coarse.converged and coarse.bound is None
    assert len(fine.history) == 2 and len(coarse.history) == 1
    assert sum(on_mesh) <= 6 < fine.result.optimizer.iterations
    assert coarse.T == pytest.approx(fine.T, rel=1e-9)
    assert coarse.J == pytest.approx(fine.J, rel=1e-10)


def _spy_on_runs(monkeypatch) -> list:
    """A list that ``free_time_sqp._run`` appends (elements, free T?, steps) to at each of its runs from now on."""
    import hoc_cli.goals.free_time_sqp as fts

    runs: list = []
    run = fts._run

    def spy(record, *args, **options):
        r = run(record, *args, **options)
        runs.append((r.plan.mesh.N, options.get("free") is not None, r.steps))
        return r

    monkeypatch.setattr(fts, "_run", spy)
    return runs


def test_after_the_restoration_the_coarse_stage_steps_in_x_and_T_at_once(monkeypatch):
    """The restoration has moved T from the guess to where the catch meets its goal within the limits: the coarse stage
    takes its steps in x and T from the restored trajectory, none at the restored T first (those took 11 steps from the
    restored J = 609 to 129 at T = 0.553 s, then 10 in x and T; in x and T at once: 15 with the goal rows restored to 1e-9
    and the violation floor 2 cm, 10 with them restored to ``free_time_sqp.RESTORE_TOL`` and ``RESTORED_FLOOR``; then 3
    on the mesh), and the plan is the optimum reached by way of the steps at the guess on the 8 elements alone
    (``coarse=0``): T to 1e-9, J to 1e-10 relative."""
    from hoc_cli.goals.free_time_sqp import minimize_time_sqp
    from hoc_cli.goals.time_solver import goal_solver

    model, arm, limits, problem = ur5_catch()
    goals = problem.goals()
    solver = goal_solver(arm, "quintic", 8, problem.q0, problem.dq0, goals, limits=limits)
    fine = minimize_time_sqp(solver, arm, goals, 0.3, 0.8, guess=0.5, limits=limits, coarse=0)
    runs = _spy_on_runs(monkeypatch)
    coarse = minimize_time_sqp(solver, arm, goals, 0.3, 0.8, guess=0.5, limits=limits, coarse=4)
    assert coarse.converged and coarse.bound is None
    assert [free for N, free, _ in runs if N == 4] == [True]
    assert sum(steps for _, _, steps in runs) <= 15 < fine.result.optimizer.iterations
    assert coarse.T == pytest.approx(fine.T, rel=1e-9)
    assert coarse.J == pytest.approx(fine.J, rel=1e-10)


def test_from_the_guess_0_6_s_the_coarse_steps_from_the_restored_trajectory_converge(monkeypatch):
    """From the guess 0.6 s (``hoc_cli.solve``) the coarse restoration ends at T ≈ 0.583 s; the coarse steps in x and T
    from there, whose goal rows may rise to ``free_time_sqp.RESTORED_FLOOR`` (5 cm) undamped, converge in 8 steps and the
    mesh's in 3 (with the 2 cm of the steps from the initial trajectory they ran to their limit of 120 steps, and the
    mesh's took 7 at the restored T and 5 in x and T): the optimum reached from 0.5 s, T to 1e-9 and J to 1e-10
    relative."""
    import dataclasses

    import hoc_cli
    from hoc_cli import Free

    model, arm, limits, problem = ur5_catch()
    ref = hoc_cli.solve(problem)
    runs = _spy_on_runs(monkeypatch)
    late = hoc_cli.solve(dataclasses.replace(problem, time=Free(0.3, 0.8, guess=0.6)))
    assert late.converged and late.details["T_bound"] is None
    assert [free for N, free, _ in runs if N == 4] == [True]
    assert sum(steps for _, _, steps in runs) <= 15
    assert late.T == pytest.approx(ref.T, rel=1e-9) and late.J == pytest.approx(ref.J, rel=1e-10)


def test_from_the_guess_0_7_s_the_catch_reaches_the_optimum_from_0_5_s():
    """From the guess 0.7 s the minimum-norm final velocity of the inverse-kinematics guess needs 9 rad/s of a 3.15 rad/s
    joint. Restored on the coarse stage's 4 elements (18 steps, to T ≈ 0.598 s; on the 8 elements alone it takes
    19) the catch converges to the optimum reached from 0.5 s: T to 1e-9 and J to 1e-10 relative,
    within 1 % of IPOPT's, meeting the ball by Pinocchio's forward kinematics."""
    import dataclasses

    import hoc_cli
    from hoc_cli import Free

    model, arm, limits, problem = ur5_catch()
    ref, late = (hoc_cli.solve(dataclasses.replace(problem, time=Free(0.3, 0.8, guess=g))) for g in (0.5, 0.7))
    assert ref.converged and late.converged and late.details["T_bound"] is None
    assert late.T == pytest.approx(ref.T, rel=1e-9) and late.J == pytest.approx(ref.J, rel=1e-10)
    assert abs(late.T - T_IPOPT) <= 1e-2 * T_IPOPT and abs(late.J - J_IPOPT) <= 1e-2 * J_IPOPT
    reached = PinocchioOracle(model).link_pose(late.coeffs[-1, 0], "tool0")[:3, 3]
    assert np.abs(reached - (P0 + V0 * late.T + 0.5 * A0 * late.T ** 2)).max() < 1e-9


@pytest.mark.parametrize("N", [10, 16])
def test_the_catch_on_finer_meshes_converges_by_way_of_the_coarse_elements(N):
    """On 10 and 16 elements the steps on the mesh from its restored trajectory run off (a Newton matrix with
    entries beyond the floating-point range: a ``ValueError`` of the banded factorisation); restored on the coarse
    stage's 4 elements the catch converges in a few steps on the mesh: within 1 % of IPOPT's T and J (K = 32), the
    ball met by Pinocchio's forward kinematics, within the limits by the exact check."""
    import hoc_cli
    from hoc_cli.constraints.check import check_limits

    model, arm, limits, problem = ur5_catch(N)
    plan = hoc_cli.solve(problem)
    assert plan.converged and plan.details["T_solves"] == 1 and plan.details["T_bound"] is None
    assert abs(plan.T - T_IPOPT) <= 1e-2 * T_IPOPT and abs(plan.J - J_IPOPT) <= 1e-2 * J_IPOPT
    assert check_limits(arm, limits, plan.mesh, plan.coeffs).feasible
    reached = PinocchioOracle(model).link_pose(plan.coeffs[-1, 0], "tool0")[:3, 3]
    assert np.abs(reached - (P0 + V0 * plan.T + 0.5 * A0 * plan.T ** 2)).max() < 1e-9


@pytest.mark.parametrize("guess", [0.4, 0.8])
def test_from_a_guess_whose_restoration_stalls_a_restart_at_the_middle_of_the_range_finds_the_catch(guess):
    """From the guesses 0.4 s and 0.8 s the restoration from the initial trajectory stalls at a local minimum of the
    violation (at 0.31 s with the goal rows 7 cm off, at 0.47 s and 53 cm), and the search over T that followed ran for
    minutes (428 s unconverged from 0.4 s). Restarted from the initial trajectory at the middle of T's range
    (``free_time_sqp._restore_either_end``) it finds a T where the catch meets the limits, and the plan is the optimum
    reached from 0.5 s: T to 1e-9 and J to 1e-10 relative, within 1 % of IPOPT's."""
    import dataclasses

    import hoc_cli
    from hoc_cli import Free
    from hoc_cli.goals.free_time_sqp import _restore_either_end
    from hoc_cli.goals.replan import TimeRange
    from hoc_cli.goals.restoration import restore
    from hoc_cli.goals.time_solver import goal_solver

    model, arm, limits, problem = ur5_catch()
    ref = hoc_cli.solve(problem)
    problem = dataclasses.replace(problem, time=Free(0.3, 0.8, guess=guess))
    goals = problem.goals()
    solver = goal_solver(arm, "quintic", 8, problem.q0, problem.dq0, goals, limits=limits)
    span = TimeRange(0.3, 0.8)
    start = solver.initial(guess)
    first = restore(arm, start, goals, limits, span=span)
    assert first.stalled and not first.feasible and first.violation > 0.05
    found, _ = _restore_either_end(arm, start, goals, limits, span, lambda plan: plan, solver.initial)
    assert found.feasible and 0.5 < found.T < 0.7
    plan = hoc_cli.solve(problem)
    assert plan.converged and plan.details["T_bound"] is None
    assert plan.T == pytest.approx(ref.T, rel=1e-9) and plan.J == pytest.approx(ref.J, rel=1e-10)
    assert abs(plan.T - T_IPOPT) <= 1e-2 * T_IPOPT and abs(plan.J - J_IPOPT) <= 1e-2 * J_IPOPT
