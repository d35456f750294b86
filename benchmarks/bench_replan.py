"""Replanning latency of the lbr7 catch (configs/catch_ball.yaml, N = 8): the cold free-T solve, then warm
replans (``hoc_cli.goals.replan``) after the ball's initial position moves by a few millimetres to centimetres.

    python benchmarks/bench_replan.py [--task configs/catch_ball.yaml] [--moves 0.001 0.003 0.01 0.03] [--repeat 3] [--ipopt]
                                      [--breakdown]

Times the Python call alone (no process start-up, no task loading): the cold solve is ``hoc plan``'s
free T (``minimize_time_sqp``: a plan at the guess, then Newton steps in x and T); each replan
starts from the cold optimum, its multipliers and T. Prints one row per move: the wall time (best of ``--repeat``), Newton steps and whether it
converged (within 40 steps; no fallback to the full solver is timed) of a replan with T fixed at the previous
optimum's and of one with the free T, and the free-T replan's T, J and goal rows' violation; with ``--cold-moved``
beside the cold solve from scratch with the moved target. ``--breakdown`` splits each fixed-T replan's time into
its parts (wrapped with timers, so the total runs a little slower): the Lagrangian's evaluations (dynamics sweep
with the gradient, goal rows, limit rows), the Newton matrices (Hessian sweep, banded assembly, dense factor), the
dense QPs, and the rest; this is the per-step floor that sets how many steps fit in a latency budget.
"""
from __future__ import annotations

# isort: off
import _blas_threads  # noqa: F401  (before numpy: one BLAS thread, as hoc_cli sets)
# isort: on
import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np

from hoc_cli.goals.free_time_sqp import minimize_time_sqp
from hoc_cli.goals.replan import TimeRange, replan
from hoc_cli.goals.time_solver import goal_solver
from hoc_cli.io.robot import load_model
from hoc_cli.io.task import load_task, resolve
from hoc_cli.io.task.problem import task_goals, task_limits
from hoc_cli.system import RobotSystem

ROOT = Path(__file__).resolve().parents[1]


def moved(goals, dx: float):
    """The goals with the target's initial position moved by dx [m] along x."""
    final = dataclasses.replace(goals.final, position=goals.final.position + np.array([dx, 0.0, 0.0]))
    return dataclasses.replace(goals, final=final)


def cold(system, task, states, goals, limits):
    free = task.time.free
    solver = goal_solver(system, task.order, task.N, states.q0, states.dq0, goals, limits=limits, cost=task.cost)
    start = time.perf_counter()
    ft = minimize_time_sqp(solver, system, goals, free.min, free.max, guess=free.guess, weight=free.weight,
                           limits=limits)
    return ft, time.perf_counter() - start


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--task", default=str(ROOT / "configs" / "catch_ball.yaml"))
    ap.add_argument("--moves", type=float, nargs="+", default=[0.001, 0.003, 0.01, 0.03])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--cold-moved", action="store_true", help="also solve each moved task cold (minutes each)")
    ap.add_argument("--breakdown", action="store_true", help="time the parts of each fixed-T replan step")
    ap.add_argument("--ipopt", action="store_true", help="also CasADi + IPOPT cold and warm-started on the same changes")
    args = ap.parse_args()
    task = load_task(Path(args.task), purpose="plan")
    model = load_model(task)
    states = resolve(task, model.joint_names)
    goals = task_goals(task, model, states)
    limits = task_limits(model, states.limits)
    system = RobotSystem(model)
    free = task.time.free
    ft, wall = cold(system, task, states, goals, limits)
    print(f"cold free-T solve (N = {task.N}, {task.order}): {wall:.2f} s, {len(ft.history)} solves (the guess, the Newton steps' plan), "
          f"T = {ft.T:.6f} s, J = {ft.J:.9f}")
    span = TimeRange(free.min, free.max, free.weight)
    print(f"{'move [m]':>9} {'fixed T [ms]':>12} {'steps':>5} {'conv':>5} {'free T [ms]':>11} {'steps':>5} {'conv':>5} "
          f"{'T [s]':>10} {'J':>14} {'violation':>9}"
          + (f" {'cold [s]':>9} {'J cold':>14}" if args.cold_moved else ""))
    for dx in args.moves:
        g = moved(goals, dx)
        fixed = None
        for _ in range(args.repeat):
            start = time.perf_counter()
            rf = replan(system, ft, g, limits=limits, fallback=False)
            wall = time.perf_counter() - start
            fixed = wall if fixed is None else min(fixed, wall)
        best = None
        for _ in range(args.repeat):
            start = time.perf_counter()
            r = replan(system, ft, g, free=span, limits=limits, fallback=False)
            wall = time.perf_counter() - start
            best = wall if best is None else min(best, wall)
        row = (f"{dx:9.3f} {1e3 * fixed:12.1f} {rf.steps:5d} {str(rf.converged):>5} {1e3 * best:11.1f} {r.steps:5d} "
               f"{str(r.converged):>5} {r.T:10.6f} {r.plan.J:14.9f} "
               f"{r.plan.violation:9.1e}")
        if args.cold_moved:
            fc, wc = cold(system, task, states, g, limits)
            row += f" {wc:9.2f} {fc.J:14.9f}"
        print(row, flush=True)
    if args.breakdown:
        breakdown(system, ft, goals, limits, args.moves, args.repeat)
    if args.ipopt:
        ipopt_rows(Path(args.task), args.moves, args.repeat)


def breakdown(system, ft, goals, limits, moves, repeat: int) -> None:
    """Print, per move, a fixed-T replan's time split into evaluations, Newton matrices (the Hessian sweep and the
    banded assembly: ``ControlProblem.newton``), their dense factors, QPs and the rest [ms]
    (best of ``repeat``), with their counts: the parts are wrapped with ``time.perf_counter`` timers.
    """
    import hoc_cli.goals.replan_qp as rq
    from hoc_cli.problem import ControlProblem

    spent: dict[str, list] = {}

    def timed(name, fn):
        def wrapper(*a, **k):
            start = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                entry = spent.setdefault(name, [0.0, 0])
                entry[0] += time.perf_counter() - start
                entry[1] += 1
        return wrapper

    saved = (rq.evaluate_point, rq.solve_qp, rq.dense_factor, ControlProblem.newton)
    rq.evaluate_point, rq.solve_qp = timed("evaluation", saved[0]), timed("QP", saved[1])
    rq.dense_factor, ControlProblem.newton = timed("factor", saved[2]), timed("Newton", saved[3])
    parts = ("evaluation", "Newton", "factor", "QP")
    print(f"{'move [m]':>9} {'total [ms]':>10} {'steps':>5} "
          + " ".join(f"{p + ' [ms] (n)':>19}" for p in parts) + f" {'rest [ms]':>9}")
    try:
        for dx in moves:
            best = None
            for _ in range(repeat):
                spent.clear()
                start = time.perf_counter()
                r = replan(system, ft, moved(goals, dx), limits=limits, fallback=False)
                wall = time.perf_counter() - start
                if best is None or wall < best[0]:
                    best = (wall, r.steps, {k: tuple(v) for k, v in spent.items()})
            wall, steps, got = best
            cells = [f"{1e3 * got.get(p, (0.0, 0))[0]:13.1f} ({got.get(p, (0.0, 0))[1]:2d})" for p in parts]
            rest = wall - sum(v[0] for v in got.values())
            print(f"{dx:9.3f} {1e3 * wall:10.1f} {steps:5d} " + " ".join(f"{c:>19}" for c in cells) + f" {1e3 * rest:9.1f}",
                  flush=True)
    finally:
        rq.evaluate_point, rq.solve_qp, rq.dense_factor, ControlProblem.newton = saved


def ipopt_rows(path: Path, moves, repeat: int) -> None:
    """Print IPOPT's cold solve and, per move, its warm-started and cold re-solves (``bench_goals.catch``)."""
    import sys
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_goals import catch

    cold, rows = catch(path, moves, repeat)
    print(f"IPOPT cold (K = N, Radau d = 3): {1e3 * cold.wall:.1f} ms, {cold.iterations} iterations, T = {cold.T:.6f} s, "
          f"J = {cold.J:.9f}")
    print(f"{'move [m]':>9} {'IPOPT warm [ms]':>15} {'iter':>5} {'T [s]':>10} {'J':>14} {'cold [ms]':>9} {'iter':>5} "
          f"{'|ΔJ| warm-cold':>14}")
    for dx, warm, again in rows:
        print(f"{dx:9.3f} {1e3 * warm.wall:15.1f} {warm.iterations:5d} {warm.T:10.6f} {warm.J:14.9f} "
              f"{1e3 * again.wall:9.1f} {again.iterations:5d} {abs(warm.J - again.J):14.1e}", flush=True)


if __name__ == "__main__":
    main()
