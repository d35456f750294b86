"""hoc's free-T and link-goal optima against CasADi + IPOPT direct collocation of the same continuous problems
(benchmarks/_casadi_goals.py; the full tables: benchmarks/bench_goals.py, docs/goals.md).

Skipped without casadi (a benchmark-only dependency: ``pip install -e '.[bench]'``).

The two discretisations differ (quintic Hermite elements against degree-3 Radau collocation); the
tolerances are ~10× the differences measured between hoc at N = 16 and IPOPT at K = 32 on these tasks
(free T: J and J + T 1e-9 relative, T 1e-8 s; link goal: J 1e-9 relative). hoc's free-T search stops
at |dJ*/dT + weight| ~ 6e-6 here. The link goal has two elbow solutions; hoc, started from the
inverse-kinematics guess of the dearer one, ends at the cheaper one, which IPOPT finds only from it.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

ca = pytest.importorskip("casadi")

from hoc_cli.dynamics import link_poses  # noqa: E402
from hoc_cli.elements import HermiteMesh  # noqa: E402
from hoc_cli.free_time import joint_goal_solver, minimize_time  # noqa: E402
from hoc_cli.goals import plan_goals  # noqa: E402
from hoc_cli.io.robot import load_model  # noqa: E402
from hoc_cli.io.task import load_yaml, parse_task, resolve  # noqa: E402
from hoc_cli.io.task.problem import task_goals, task_limits  # noqa: E402
from hoc_cli.system import RobotSystem  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from _casadi_goals import Goal, GoalCollocation, check_kinematics  # noqa: E402
from ipopt_limits import Limits  # noqa: E402

BASE = """
robot: ../robots/two_link.urdf
gravity: [0.0, 0.0, -9.81]
x0: {q: [0.0, 0.0], dq: [0.0, 0.0]}
order: quintic
cost: covariant
N: 16
"""


def load(extra: str):
    text = BASE + extra
    task = parse_task(load_yaml(text), path=ROOT / "configs" / "test_goals_ipopt.yaml", text=text)
    model = load_model(task)
    states = resolve(task, model.joint_names)
    return task, model, states, task_limits(model, states.limits)


def test_free_time_agrees_with_ipopt():
    task, model, st, limits = load("x1: {q: [1.2, -0.6], dq: [0.0, 0.0]}\n"
                                   "T: {free: true, min: 0.5, max: 4.0, guess: 1.5, weight: 1.0}\n")
    free = task.time.free
    solve = joint_goal_solver(RobotSystem(model), task.order, task.N, st.q0, st.dq0, st.q1, st.dq1, limits=limits,
                              cost=task.cost)
    ft = minimize_time(solve, free.min, free.max, guess=free.guess, weight=free.weight)
    c = GoalCollocation(model, st.q0, st.dq0, Goal(q1=st.q1, dq1=st.dq1), (free.min, free.max), 32,
                        weight=free.weight, limits=Limits.from_model(model))
    r = c.solve(c.guess(free.guess, st.q1, st.dq1))
    assert r.success and ft.bound is None and free.min < r.T < free.max
    assert abs(ft.T - r.T) <= 1e-7
    assert abs(ft.J - r.J) <= 1e-8 * r.J
    assert abs(ft.objective - r.objective) <= 1e-8 * r.objective
    assert abs(ft.dJ_dT + free.weight) <= 1e-5  # an interior optimum: dJ*/dT = −weight (to hoc's stopping test)


def test_link_goal_agrees_with_ipopt():
    task, model, _, _ = load("x1: {q: [0.0, 0.0]}\nT: 1.0\n")
    assert check_kinematics(model, "tool") <= 1e-12
    target = link_poses(model, np.array([1.2, -0.6]))["tool"][:3, 3]
    text = "x1: {link: tool, position: [%r, %r, %r], dq: zero}\nT: 1.0\n" % tuple(float(v) for v in target)
    task, model, st, limits = load(text)
    goals = task_goals(task, model, st)
    h = plan_goals(RobotSystem(model), HermiteMesh(task.order, task.T, task.N), st.q0, st.dq0, goals, limits=limits,
                   cost=task.cost)
    c = GoalCollocation(model, st.q0, st.dq0, Goal(link="tool", position=target), task.T, 32,
                        limits=Limits.from_model(model))
    # the planar arm reaches the point with two elbows: IPOPT from each, hoc must find the cheaper
    sols = [c.solve(c.guess(task.T, q)) for q in (np.array([1.2, -0.6]), np.array([0.6, 0.6]))]
    assert all(s.success for s in sols) and np.abs(sols[0].q1 - sols[1].q1).max() > 0.1
    r = min(sols, key=lambda s: s.J)
    q1 = h.coeffs[-1, 0]
    for q in (q1, r.q1):
        assert np.linalg.norm(link_poses(model, q)["tool"][:3, 3] - target) <= 1e-9
    assert np.abs(h.coeffs[-1, 1]).max() <= 1e-12 and np.abs(r.dq1).max() <= 1e-12
    assert np.abs(q1 - r.q1).max() <= 1e-6
    assert abs(h.J - r.J) <= 1e-8 * r.J
