"""Steps, evaluations and CPU time of the cold free-T goal plans (issue 23), one line per task.

    python benchmarks/bench_free_steps.py [--tasks "catch 8" "ur5 catch" ...] [--repeat 1]

Tasks: ``catch N`` is configs/catch_ball.yaml on N elements (N = 8, 16, 32), solved as ``bench_goals.py
--hoc-catch`` times it (``bench_replan.cold``: ``minimize_time_sqp`` from the task's guess); ``ur5 catch`` and
``ur5 moving`` are ``bench_robust.py``'s (``hoc_cli.solve``). Each line: the Newton steps and evaluations of every
replan that made the plan (the plan's ``optimizer.iterations`` and ``n_evals``: the restoration's are not among
them), the process's CPU time over the solve (best of ``--repeat``), T, J and J + weight·T. Counts do not depend on
the machine's load; compare CPU times old vs new interleaved (docs/design.md).
"""
from __future__ import annotations

# isort: off
import _blas_threads  # noqa: F401  (before numpy: one BLAS thread, as hoc_cli sets)
# isort: on
import argparse
import os
import time
from pathlib import Path

from bench_goals import task_from
from bench_replan import cold
from bench_robust import tasks as robust_tasks

import hoc_cli
from hoc_cli.io.task.problem import task_goals
from hoc_cli.system import RobotSystem

ROOT = Path(__file__).resolve().parents[1]
TASKS = ("catch 8", "catch 16", "catch 32", "ur5 catch", "ur5 moving")


def solve(name: str) -> tuple[float, object, float, float, float]:
    """(CPU [s], the plan's optimizer result, T [s], J, weight) of one cold solve of the task ``name``."""
    if name.startswith("catch"):
        N = int(name.split()[1])
        task, model, states, limits = task_from((ROOT / "configs" / "catch_ball.yaml").read_text(), N)
        goals = task_goals(task, model, states)
        system = RobotSystem(model)
        cpu = time.process_time()
        ft, _ = cold(system, task, states, goals, limits)
        cpu = time.process_time() - cpu
        return cpu, ft.point.result.optimizer, ft.T, ft.J, task.time.free.weight
    model, problem, _ = robust_tasks()[name]
    cpu = time.process_time()
    plan = hoc_cli.solve(problem)
    cpu = time.process_time() - cpu
    return cpu, plan.result.optimizer, plan.T, plan.J, problem.free_time.weight


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", nargs="+", default=list(TASKS), choices=TASKS)
    ap.add_argument("--repeat", type=int, default=1, help="solves per task (the CPU time is the best)")
    args = ap.parse_args()
    import scipy.optimize  # noqa: F401  (hoc's first-use import, before the timings)

    load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    print(f"load average (1, 5, 15 min) at the start: {load}")
    print(f"{'task':>10} {'steps':>5} {'evals':>5} {'CPU [s]':>8} {'T [s]':>16} {'J':>18} {'J + weight T':>18}")
    for name in args.tasks:
        runs = [solve(name) for _ in range(max(args.repeat, 1))]
        cpu = min(r[0] for r in runs)
        _, opt, T, J, weight = runs[0]
        print(f"{name:>10} {opt.iterations:5d} {opt.n_evals:5d} {cpu:8.2f} {T:16.12f} {J:18.12f} {J + weight * T:18.12f}",
              flush=True)


if __name__ == "__main__":
    main()
