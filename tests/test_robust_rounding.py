"""Rounding does not decide a plan (issue 23): the BLAS thread count and the model's units leave the answer alone.

- A free-T moving-target task on a third-party robot (UR5 of example-robot-data, ``tool0`` to a target moving
  at (0.2, −0.1, 0) m/s, weight 20) planned in subprocesses with OPENBLAS_NUM_THREADS = 1, 2, 4 and with hoc
  imported after numpy (hoc's one-thread default cannot apply): T and J agree to 1e-8 relative, every run
  converged at a stationary point (dJ*/dT = −weight).
- The replan's quadratic programme (``hoc_cli.goals.qp_step.solve_qp``) gives the same step whatever the units
  of its model: H scaled by 1e34 (a Levenberg-Marquardt shift far out) is still feasible and solved.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from _robots import ERD, ROBOTS

from hoc_cli.goals.qp_step import solve_qp, upper_factor

URDF = ERD / "ur_description/urdf/ur5_robot.urdf"
WEIGHT = 20.0
CLI = "import sys; from hoc_cli.cli import app; sys.exit(app())"


def _plan(task, env: dict, numpy_first: bool = False) -> dict:
    code = ("import numpy; " if numpy_first else "") + CLI
    out = subprocess.run([sys.executable, "-c", code, "plan", str(task), "-o", "none", "--json"], capture_output=True,
                         text=True, timeout=120, env=env, cwd=task.parent)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


@pytest.mark.skipif(not URDF.is_file(), reason="example-robot-data is not installed")
def test_the_same_free_time_plan_with_1_2_4_blas_threads_and_after_numpy(tmp_path):
    task = tmp_path / "ur5_moving.yaml"
    task.write_text(f"""robot: {URDF}
x0: {{q: [0, -1.57, 1.57, -1.57, -1.57, 0]}}
x1:
  link: tool0
  target: {{position: [-0.3, 0.5, 0.5], velocity: [0.2, -0.1, 0.0], acceleration: [0.0, 0.0, 0.0]}}
T: {{free: true, min: 0.5, max: 3.0, guess: 1.5, weight: {WEIGHT}}}
N: 4
""")
    base = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    runs = [_plan(task, base | {"OPENBLAS_NUM_THREADS": str(t)}) for t in (1, 2, 4)]
    runs.append(_plan(task, base, numpy_first=True))
    T0, J0 = runs[0]["T"], runs[0]["cost"]
    for s in runs:
        assert s["status"] == "converged" and s["T_converged"] and s["T_bound"] is None
        assert abs(s["dJ_dT"] + WEIGHT) <= 1e-6 * (s["cost"] / s["T"] + WEIGHT)  # stationary
        assert abs(s["T"] - T0) <= 1e-8 * T0 and abs(s["cost"] - J0) <= 1e-8 * J0


def test_the_replan_programme_is_solved_in_any_units():
    rng = np.random.default_rng(3)
    P, r, k = 40, 4, 12
    B = rng.standard_normal((P, P))
    H = B @ B.T + P * np.eye(P)
    g = rng.standard_normal(P)
    E, e = rng.standard_normal((r, P)), 1e-3 * rng.standard_normal(r)
    A, b = rng.standard_normal((k, P)), rng.uniform(0.0, 0.1, k) - 0.05  # some rows bind at d = 0
    ref = solve_qp(upper_factor(H), g, E, e, A, b)
    assert np.abs(E @ ref.d - e).max() < 1e-12 and (A @ ref.d - b).max() < 1e-12 and ref.mu.max() > 0
    for s in (1e-12, 1e17, 1e34):  # H and g in other units: the same step, multipliers scaled
        out = solve_qp(upper_factor(s * H), s * g, E, e, A, b)
        assert np.abs(out.d - ref.d).max() <= 1e-8 * np.abs(ref.d).max()
        assert np.abs(out.mu - s * ref.mu).max() <= 1e-8 * s * ref.mu.max()


def test_hoc_solves_on_one_blas_thread_when_numpy_loaded_its_blas_first(tmp_path):
    """numpy imported first with two OpenBLAS threads: a goal plan's iterations run on one, and the count is
    restored after (``hoc_cli.optimize.blas.one_thread``)."""
    code = """
import numpy, scipy.linalg
import hoc_cli
from hoc_cli import Fixed, OptimalControlProblem, RobotSystem, SolveOptions, link_goal, load_robot
from hoc_cli.optimize.blas import thread_counts
before = thread_counts()
arm = RobotSystem(load_robot(%r))
seen = []
problem = OptimalControlProblem(arm, q0=[0.0, 0.0], dq0=[0.0, 0.0], time=Fixed(1.5), N=8,
                                link_goal=link_goal(arm, "tool", position=[1.0, 0.0, 1.2]))
plan = hoc_cli.solve(problem, SolveOptions(callback=lambda log: seen.append(thread_counts())))
import json; print(json.dumps([before, sorted(set(map(tuple, seen))), thread_counts(), plan.converged]))
""" % str(ROBOTS / "two_link.urdf")
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         env=env | {"OPENBLAS_NUM_THREADS": "2"})
    assert out.returncode == 0, out.stderr
    before, seen, after, converged = json.loads(out.stdout)
    assert converged and before and all(n == 2 for n in before)  # numpy's and scipy's OpenBLAS read the variable
    assert seen == [[1] * len(before)] and after == before
