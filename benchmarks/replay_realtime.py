"""The real-time catch's SQP updates replayed one by one: the work of each update, apart from the machine's load.

    python benchmarks/replay_realtime.py [--scenario configs/catch_throw.yaml] [--N 8] [--repeat 7]
    valgrind --tool=cachegrind --cache-sim=no python benchmarks/replay_realtime.py --only 1 --passes P

The scenario's loop runs once untimed (every update applied, the same updates on every machine) and each SQP
update's input is kept (the replanner's state before it, its start time, state and target); then each update is
run again from that state ``--repeat`` times and the least thread CPU time (``time.thread_time``) is printed per
update [ms] with its plan's start, steps, status and J. The least of several runs is the update's cost when the
machine let it run; on a machine shared with other jobs even that varies by several ms, so ``--only K --passes P``
runs update K (or a comma-separated list) after one warm call P times and nothing else: the difference of the instruction counts of
``--passes 1`` and ``--passes 0`` under valgrind's cachegrind is the update's work (it varies by about 1 % from
run to run with Python's hash seed), which does not depend on the load. With ``--marks`` each timed update is
bracketed by ``os.getppid()`` calls, so that one run of
``valgrind --tool=callgrind --dump-before=getppid ... --only 0,1,2 --marks`` writes each update's count to a file of
its own (the first file: everything before; then one per update in order). ``--inputs FILE`` keeps the captured updates
in FILE (pickle) and, when FILE exists, replays those instead of running the loop: two versions of the code then
replay the same updates (the loop's plans, hence its later updates' inputs, differ between them).
"""
from __future__ import annotations

# isort: off
import _blas_threads  # noqa: F401  (before numpy: one BLAS thread, as hoc_cli sets)
# isort: on
import argparse
import dataclasses
import math
import os
import pickle
import time
from pathlib import Path

from hoc_cli.io.robot import load_model
from hoc_cli.io.scenario import load_scenario
from hoc_cli.io.task import apply_overrides, resolve
from hoc_cli.io.task.problem import problem_from_task, task_limits
from hoc_cli.realtime.loop import run_catch
from hoc_cli.realtime.replanner import Replanner
from hoc_cli.strategy import solve

UNTIMED = 1e9  # [s] the budget of every update: the replanner's own skip and abandon rules (measured step times
# against the budget) never act, even under valgrind on a loaded machine (updates of seconds), so each update does
# the same work in every run
ROOT = Path(__file__).resolve().parents[1]


def captured_updates(scenario: str, N: int) -> tuple[Replanner, list]:
    """The replanner of the scenario's untimed loop and every SQP update's input (state, t, x, target, free_time)."""
    sc = load_scenario(scenario)
    task = apply_overrides(sc.task, N=N)
    model = load_model(task)
    states = resolve(task, model.joint_names)
    problem = problem_from_task(task, model, states, task_limits(model, states.limits))
    plan = solve(problem)
    rp = Replanner(problem, plan, max_steps=sc.cycle.steps)
    inputs: list = []
    update = rp.update

    def keep(t, x, target, budget_s, *, free_time=True):
        inputs.append((rp.state(), t, x, target, free_time))
        return update(t, x, target, UNTIMED, free_time=free_time)

    rp.update = keep
    run_catch(problem, plan, sc.throw, sc.observer, dataclasses.replace(sc.cycle, budget=UNTIMED), replanner=rp, timed=False)
    rp.update = update
    return rp, inputs


def kept_updates(scenario: str, N: int, path: str | None) -> tuple[Replanner, list]:
    """``captured_updates``, or with ``path``: the updates kept in that file when it exists (the replanner built from the
    scenario's cold plan, without the loop), else the captured ones, kept there (the plans' costs not kept: NaN).
    """
    if path is None or not os.path.exists(path):
        rp, inputs = captured_updates(scenario, N)
        if path is not None:
            bare = []
            for (cur, lam, active, mu), t, x, target, free_time in inputs:  # a Deferred cost is not kept
                cur = dataclasses.replace(cur, cost=math.nan, steps_cost=math.nan, kkt=math.nan)
                bare.append(((cur, lam, active, mu), t, x, target, free_time))
            with open(path, "wb") as fh:
                pickle.dump(bare, fh)
        return rp, inputs
    sc = load_scenario(scenario)
    task = apply_overrides(sc.task, N=N)
    model = load_model(task)
    states = resolve(task, model.joint_names)
    problem = problem_from_task(task, model, states, task_limits(model, states.limits))
    with open(path, "rb") as fh:
        inputs = pickle.load(fh)
    return Replanner(problem, solve(problem), max_steps=sc.cycle.steps), inputs


def replay(rp: Replanner, inp: tuple):
    """The update of ``inp`` from its state again; its plan."""
    state, t, x, target, free_time = inp
    rp.restore(state)
    return rp.update(t, x, target, UNTIMED, free_time=free_time)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default=str(ROOT / "configs" / "catch_throw.yaml"))
    ap.add_argument("--N", type=int, default=8)
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--only", default=None, help="run these updates (comma-separated indices) alone, after one warm call")
    ap.add_argument("--passes", type=int, default=1, help="with --only: its runs after the warm call")
    ap.add_argument("--marks", action="store_true",
                    help="with --only: os.getppid() before each timed update and after the last (valgrind --tool=callgrind "
                         "--dump-before=getppid then writes one count per update)")
    ap.add_argument("--inputs", default=None, help="keep the captured updates in this file, or replay them from it")
    args = ap.parse_args()
    rp, inputs = kept_updates(args.scenario, args.N, args.inputs)
    if args.only is not None:
        chosen = [inputs[int(k)] for k in args.only.split(",")]
        for p in range(1 + args.passes):
            for inp in chosen:
                if args.marks and p:
                    os.getppid()
                replay(rp, inp)
        if args.marks:
            os.getppid()
        return
    for k, inp in enumerate(inputs):
        best = float("inf")
        for _ in range(args.repeat):
            c0 = time.thread_time()
            out = replay(rp, inp)
            best = min(best, time.thread_time() - c0)
        print(f"update {k}: plan from t = {inp[1]:.3f} s, {out.steps} step(s), {out.status:9s} J {out.J:.12g}, "
              f"least CPU of {args.repeat}: {1e3 * best:6.2f} ms")


if __name__ == "__main__":
    main()
