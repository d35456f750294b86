"""The plan at a free T's guess two ways, on the lbr7 catch and variations of it (N = 8, URDF limits enforced).

    python benchmarks/bench_free_time_start.py [--N 8]

``hoc_cli.goals.free_time_sqp.minimize_time_sqp`` plans at the guess T, then moves x and T together by Newton
steps. The plan at the guess comes either from Newton steps at fixed T started from the initial trajectory
(the default: the ℓ1 merit test and a Levenberg-Marquardt shift choose the steps' lengths) or from the full
solve (``cold_steps=0``: continuation, the goal rows' and the limits' augmented-Lagrangian loops). Prints, per
task, both ways' wall time, T and J + weight·T, and their relative difference: the two must end at the same
optimum, the steps faster.
"""
from __future__ import annotations

# isort: off
import _blas_threads  # noqa: F401  (before numpy: one BLAS thread, as hoc_cli sets)
# isort: on
import argparse
import time

from bench_goals import task_from
from bench_replan import ROOT

from hoc_cli.goals.free_time_sqp import minimize_time_sqp
from hoc_cli.goals.time_solver import goal_solver
from hoc_cli.io.task.problem import task_goals
from hoc_cli.system import RobotSystem

CATCH = (ROOT / "configs" / "catch_ball.yaml").read_text()
BALL = "position: [0.6725, -0.0375, 0.1246]"
TASKS = {
    "catch (configs/catch_ball.yaml)": CATCH,
    "catch, ball 5 cm along x and y": CATCH.replace(BALL, "position: [0.7225, 0.0125, 0.1246]"),
    "catch, ball 5 cm lower": CATCH.replace(BALL, "position: [0.6725, -0.0375, 0.0746]"),
    "flange to a point at rest, weight 20": CATCH.replace(
        "target: {position: [0.6725, -0.0375, 0.1246], velocity: [-0.15, 0.25, 3.13], acceleration: [0.0, 0.0, -9.81]}"
        "\n  match_velocity: true", "position: [0.5, 0.2, 0.6]").replace(
        "T: {free: true, min: 0.3, max: 0.5, guess: 0.35}", "T: {free: true, min: 0.5, max: 3.0, guess: 1.0, weight: 20.0}"),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--N", type=int, default=8)
    args = ap.parse_args()
    print(f"{'task':>38} {'steps [s]':>9} {'full solve [s]':>14} {'T [s]':>12} {'J + w·T':>15} {'relative diff.':>14}")
    for name, text in TASKS.items():
        task, model, states, limits = task_from(text, args.N)
        system, goals, free = RobotSystem(model), task_goals(task, model, states), task.time.free
        solver = goal_solver(system, task.order, task.N, states.q0, states.dq0, goals, limits=limits, cost=task.cost)
        runs = []
        for cold_steps in (None, 0):
            options = {} if cold_steps is None else {"cold_steps": cold_steps}
            start = time.perf_counter()
            ft = minimize_time_sqp(solver, system, goals, free.min, free.max, guess=free.guess, weight=free.weight,
                                   limits=limits, **options)
            runs.append((time.perf_counter() - start, ft))
        (w_steps, a), (w_full, b) = runs
        by_steps = a.history[0].result.optimizer.message.startswith("warm replan")
        print(f"{name:>38} {w_steps:9.2f} {w_full:14.2f} {a.T:12.9f} {a.objective:15.10f} "
              f"{abs(a.objective - b.objective) / abs(b.objective):14.1e}" + ("" if by_steps else "  (steps fell back)"),
              flush=True)


if __name__ == "__main__":
    main()
