"""Free-T and goal tasks on third-party robots (example-robot-data), hoc timed beside CasADi + IPOPT.

    python benchmarks/bench_robust.py [--ipopt] [--K 8 32] [--tasks "panda reach" ...] [--repeat 5]

The tasks of issue 23's independent check, the URDF's limits enforced:

1. ``ur5 catch``: the UR5's ``tool0`` catches a ball tossed from (0.9, 0.6, 0.2) m at (−0.86, −0.3, 2.8) m/s
   under gravity, ``match_velocity``, T free in [0.3, 0.8] s from the guess 0.5 s (infeasible there), N = 8.
2. ``ur5 moving``: ``tool0`` to a target at (−0.3, 0.5, 0.5) m moving at (0.2, −0.1, 0) m/s, T free in
   [0.5, 3] s, weight 20, N = 8.
3. ``panda reach``: the Panda's ``panda_link8`` to (0.5, 0.3, 0.4) m at rest in T = 1.5 s, N = 16.

hoc: ``hoc_cli.solve`` (its ``wall_time_s``, and the process's CPU time over the call). IPOPT (``--ipopt``; casadi
needed): ``_casadi_goals.GoalCollocation`` on K intervals (``--K``), cold from the quintic to hoc's inverse-kinematics
guess of the final state at the guess T; its wall time is the solver call's (the NLP is built before), its CPU time
the process's over that call. The modules hoc imports on first use (``scipy.optimize``, and hoc's own solver modules:
``hoc_cli.goals``, ``optimize``, ``constraints``, ``strategy``, ``free_time``) are imported before the timings, as
CasADi's are, so both times are the solves' (the start-up of ``hoc plan`` is ``bench_startup.py``'s; with
``PYTHONDONTWRITEBYTECODE`` set each first import compiles its source: 50-80 ms of the first UR5 catch measured
otherwise). ``--repeat R`` solves each task R times with each solver, from the same start, and keeps the least wall and
the least CPU time (the machine is shared: single times are noisy).
Each IPOPT row ends with the ratios hoc/IPOPT of the task's wall and CPU times, measured in the same run (the
machine's load beside them in the first line). The discretisations differ (quintic Hermite elements, Radau
collocation), so J and T agree to the meshes' discretisation errors.
"""
from __future__ import annotations

# isort: off
import _blas_threads  # noqa: F401  (before numpy: one BLAS thread, as hoc_cli sets)
# isort: on
import argparse
import math
import os
import sys
import sysconfig
import time
from pathlib import Path

import numpy as np

import hoc_cli
from hoc_cli import Fixed, Free, JointLimits, OptimalControlProblem, RobotSystem, link_goal, load_robot

ERD = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix" / "share" / "example-robot-data" / "robots"
UR5 = ERD / "ur_description/urdf/ur5_robot.urdf"
PANDA = ERD / "panda_description/urdf/panda.urdf"
UR5_Q0 = [0.0, -1.57, 1.57, -1.57, -1.57, 0.0]
PANDA_Q0 = [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]


def tasks() -> dict:
    """name -> (model, problem, target (position, velocity, acceleration, match_velocity), T for IPOPT)."""
    ur5 = load_robot(UR5)
    panda = load_robot(PANDA, joints=[f"panda_joint{i}" for i in range(1, 8)], locked={"panda_finger_joint1": 0.02})
    out = {}
    for name, model, q0, link, target, span, N in (
            ("ur5 catch", ur5, UR5_Q0, "tool0", ([0.9, 0.6, 0.2], [-0.86, -0.3, 2.8], [0, 0, -9.81], True),
             Free(0.3, 0.8, guess=0.5), 8),
            ("ur5 moving", ur5, UR5_Q0, "tool0", ([-0.3, 0.5, 0.5], [0.2, -0.1, 0.0], [0, 0, 0], False),
             Free(0.5, 3.0, weight=20.0, guess=1.5), 8),
            ("panda reach", panda, PANDA_Q0, "panda_link8", ([0.5, 0.3, 0.4], None, None, False), Fixed(1.5), 16)):
        arm = RobotSystem(model)
        p, v, a, match = target
        goal = link_goal(arm, link, position=p, velocity=v, acceleration=a, match_velocity=match)
        problem = OptimalControlProblem(arm, q0=q0, dq0=np.zeros(model.n), link_goal=goal, time=span, N=N,
                                        limits=JointLimits.from_model(model))
        out[name] = (model, problem, target)
    return out


def ipopt(model, problem, target, K: int):
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _casadi_goals import Goal, GoalCollocation
    from ipopt_limits import Limits

    p, v, a, match = target
    goal = Goal(link=problem.link_goal.link, position=np.array(p, float),
                velocity=None if v is None else np.array(v, float),
                acceleration=None if a is None else np.array(a, float), match_velocity=match)
    free = problem.free_time
    T = (free.min, free.max) if free is not None else problem.T
    T_guess = free.guess if free is not None else problem.T
    goals = problem.goals()
    nlp = GoalCollocation(model, problem.q0, problem.dq0, goal, T, K, limits=Limits.from_model(model),
                          weight=free.weight if free is not None else 0.0)
    x0 = nlp.guess(T_guess, goals.q1_guess, goals.dq1_guess if match else None)
    cpu = time.process_time()
    s = nlp.solve(x0)
    return s, time.process_time() - cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ipopt", action="store_true", help="also solve each task with CasADi + IPOPT")
    ap.add_argument("--K", type=int, nargs="+", default=[8, 32], help="IPOPT's collocation intervals")
    ap.add_argument("--tasks", nargs="+", default=None, choices=["ur5 catch", "ur5 moving", "panda reach"],
                    help="run only these tasks (default all)")
    ap.add_argument("--repeat", type=int, default=1, help="solves per task and solver; the least times are shown")
    args = ap.parse_args()
    _first_use_imports()

    load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    print(f"load average (1, 5, 15 min) at the start: {load}; ratio = hoc / IPOPT, wall and CPU, in this run")
    print(f"{'task':>12} {'solver':>6} {'mesh':>5} {'status':>24} {'T [s]':>12} {'J':>16} {'wall [s]':>9} "
          f"{'CPU [s]':>8} {'ratio wall':>10} {'ratio CPU':>9}")
    for name, (model, problem, target) in tasks().items():
        if args.tasks is not None and name not in args.tasks:
            continue
        wall, cpu = math.inf, math.inf
        for _ in range(args.repeat):
            t = time.process_time()
            plan = hoc_cli.solve(problem)
            cpu, wall = min(cpu, time.process_time() - t), min(wall, plan.wall_time_s)
        status = "converged" if plan.converged else "not converged"
        print(f"{name:>12} {'hoc':>6} {problem.N:5d} {status:>24} {plan.T:12.8f} {plan.J:16.10f} {wall:9.2f} "
              f"{cpu:8.2f}", flush=True)
        if args.ipopt:
            for K in args.K:
                s_wall, s_cpu = math.inf, math.inf
                for _ in range(args.repeat):
                    s, c = ipopt(model, problem, target, K)
                    s_wall, s_cpu = min(s_wall, s.wall), min(s_cpu, c)
                print(f"{name:>12} {'IPOPT':>6} {K:5d} {s.status:>24} {s.T:12.8f} {s.J:16.10f} {s_wall:9.2f} "
                      f"{s_cpu:8.2f} {wall / s_wall:10.2f} {cpu / max(s_cpu, 1e-9):9.2f}", flush=True)


def _first_use_imports() -> None:
    """Import what a solve imports on first use (module docstring): ``scipy.optimize`` and hoc's solver modules."""
    import importlib
    import pkgutil

    import scipy.optimize  # noqa: F401

    for package in ("hoc_cli.goals", "hoc_cli.optimize", "hoc_cli.constraints"):
        for info in pkgutil.iter_modules(importlib.import_module(package).__path__, package + "."):
            importlib.import_module(info.name)
    importlib.import_module("hoc_cli.strategy")
    importlib.import_module("hoc_cli.free_time")


if __name__ == "__main__":
    main()
