"""Per-cycle compute of the real-time catch (``hoc catch``): the replanner's updates against full re-convergence.

    python benchmarks/bench_realtime.py [--scenario configs/catch_throw.yaml] [--N 8 16] [--repeat 1] [--family 0] [--ipopt]

For each N: the closed loop of the scenario (its throw, noise, seed, cycle rate, budget, steps), then the same loop
with every update converged (up to 40 SQP steps, no budget: hoc's own full re-convergence per cycle), and, with
``--ipopt`` and casadi importable, IPOPT (benchmarks/_casadi_goals.py, K = N Radau intervals) on the problem of every
``--ipopt-every``-th cycle (its start state, the estimate, the remaining time free), warm-started from the previous
such cycle's IPOPT solution. Prints per-update wall time and thread CPU time (``time.thread_time``) distributions
[ms] and the ratios of the medians. The machine may be shared: wall times then exceed CPU times (and CPU times
grow too), so the load average is printed before and after the runs.
``--repeat R`` runs the real-time loop R times and pools their updates in the distributions (a run has few SQP
updates: none while the estimate is uncertain, corrections in the last 0.1 s). The step rows count the updates that
ran SQP work, whether their plan was applied, held (the limits' check) or abandoned at a checkpoint (a skipped update
costs nothing); the feedback rows the corrections.
``--family K`` also runs the fixed family of K seeded throws (hoc_cli/realtime/throws.py) at the scenario's noise
(seed = k) and prints how many were caught (the issue's 20 at σ = 5 mm: ``--family 20``, about a minute per 10);
with the scenario's time budget the steps per update depend on the machine's speed, ``--steps S`` takes exactly S
per update instead (reproducible).
"""
from __future__ import annotations

# isort: off
import _blas_threads  # noqa: F401  (before numpy: one BLAS thread, as hoc_cli sets)
# isort: on
import argparse
import dataclasses
import os
import time
from pathlib import Path

import numpy as np

from hoc_cli.io.robot import load_model
from hoc_cli.io.scenario import load_scenario
from hoc_cli.io.task import apply_overrides, resolve
from hoc_cli.io.task.problem import problem_from_task, task_limits
from hoc_cli.realtime.loop import run_catch
from hoc_cli.realtime.throws import family
from hoc_cli.strategy import solve

ROOT = Path(__file__).resolve().parents[1]


def dist(values) -> str:
    v = np.asarray(values, float)
    return (f"median {np.median(v):7.1f}  p95 {np.percentile(v, 95):7.1f}  p99 {np.percentile(v, 99):7.1f}  "
            f"max {v.max():7.1f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default=str(ROOT / "configs" / "catch_throw.yaml"))
    ap.add_argument("--N", type=int, nargs="*", default=[8, 16])
    ap.add_argument("--family", type=int, default=0)
    ap.add_argument("--steps", type=int, default=None,
                    help="the family with exactly this many SQP steps per update (no time budget: reproducible on any "
                         "machine) instead of the scenario's budget")
    ap.add_argument("--repeat", type=int, default=1,
                    help="runs of the real-time loop, their updates pooled")
    ap.add_argument("--ipopt", action="store_true")
    ap.add_argument("--ipopt-every", type=int, default=8)
    args = ap.parse_args()
    sc = load_scenario(args.scenario)
    print(f"load average {' '.join(f'{v:.2f}' for v in os.getloadavg())} (1, 5, 15 min)")
    print(f"scenario {args.scenario}: cycle {sc.cycle.rate:g} Hz, budget {1e3 * sc.cycle.budget:g} ms, at most "
          f"{sc.cycle.steps} steps; observations {sc.observer.rate:g} Hz, sigma {1e3 * sc.observer.noise:g} mm")
    for N in args.N:
        task = apply_overrides(sc.task, N=N)
        model = load_model(task)
        states = resolve(task, model.joint_names)
        problem = problem_from_task(task, model, states, task_limits(model, states.limits))
        start = time.perf_counter()
        plan = solve(problem)
        print(f"\nN = {N}: nominal cold plan {time.perf_counter() - start:.2f} s, T = {plan.T:.6f} s")
        rt = run_catch(problem, plan, sc.throw, sc.observer, sc.cycle)
        more = [run_catch(problem, plan, sc.throw, sc.observer, sc.cycle) for _ in range(args.repeat - 1)]
        full_cycle = dataclasses.replace(sc.cycle, budget=1e9, steps=40)
        full = run_catch(problem, plan, sc.throw, sc.observer, full_cycle, timed=False)
        rows = [("real-time updates", rt), ("full re-convergence", full)]
        for name, run in rows:
            runs = [run, *more] if run is rt else [run]
            recs_all = [r for m in runs for r in m.records]
            print(f"  {name:20s} {run.status:8s} error {1e3 * run.position_error:5.2f} mm, {run.relative_speed:.4f} m/s; "
                  f"{len(runs)} run(s), {len(recs_all)} updates, overruns (discarded) {sum(m.overruns for m in runs)}, "
                  f"skipped {sum(m.skipped for m in runs)}, abandoned {sum(m.abandoned for m in runs)}")
            for kind in ("step", "feedback"):
                recs = [r for r in recs_all if r.kind == kind and (kind == "feedback" or r.plan.worked)]
                if not recs:
                    continue
                budget = 1e3 * recs[0].budget
                what = "updates that ran SQP work" if kind == "step" else "corrections"
                print(f"    {kind:8s} {len(recs)} {what}, steps/update {np.mean([r.plan.steps for r in recs]):.1f}, "
                      f"budget {budget:g} ms, over it {sum(r.late for r in recs)}")
                print(f"      wall ms {dist([1e3 * r.plan.wall_time_s for r in recs])}")
                print(f"      CPU ms  {dist([1e3 * r.cpu_s for r in recs])}")
        med = {name: np.median([r.cpu_s for r in run.records if r.kind == "step" and r.plan.worked])
               for name, run in rows}
        medw = {name: np.median([r.plan.wall_time_s for r in run.records if r.kind == "step" and r.plan.worked])
                for name, run in rows}
        print(f"  full re-convergence / real-time update, median: CPU {med['full re-convergence'] / med['real-time updates']:.1f}x, "
              f"wall {medw['full re-convergence'] / medw['real-time updates']:.1f}x")
        if args.ipopt:
            ipopt(model, problem, rt, args.ipopt_every, medw["real-time updates"], med["real-time updates"])
    if args.family:
        task = sc.task
        model = load_model(task)
        states = resolve(task, model.joint_names)
        problem = problem_from_task(task, model, states, task_limits(model, states.limits))
        plan = solve(problem)
        goal = problem.link_goal
        caught, errors, est_errors = 0, [], []
        overruns = skipped = abandoned = updates = 0
        cycle = sc.cycle if args.steps is None else dataclasses.replace(sc.cycle, steps=args.steps, budget=1e9)
        for k, throw in enumerate(family(goal.position, goal.velocity, args.family, goal.acceleration)):
            run = run_catch(problem, plan, throw, dataclasses.replace(sc.observer, seed=k), cycle, timed=args.steps is None)
            caught += run.caught
            errors.append(run.position_error)
            applied = run.applied()
            if applied:  # the estimate of the plan the arm finished, at the catch time
                last = applied[-1]
                tau = run.T - last.t_start
                est = last.position + last.velocity * tau + 0.5 * last.acceleration * tau**2
                est_errors.append(float(np.linalg.norm(est - throw.states(run.T)[0][0])))
                what = (f"its estimate at the catch off by {1e3 * est_errors[-1]:5.2f} mm (from observations up to "
                        f"{1e3 * (run.T - last.t):.0f} ms before)")
            else:
                what = "no update applied: the nominal plan"
            print(f"  throw {k:2d}: {run.status:11s} {1e3 * run.position_error:5.2f} mm {run.relative_speed:.4f} m/s; "
                  f"{what}; {run.overruns} overruns, {run.skipped} skipped, {run.abandoned} abandoned of {run.cycles} updates", flush=True)
            overruns += run.overruns
            skipped += run.skipped
            abandoned += run.abandoned
            updates += run.cycles
        how = "the scenario's budget" if args.steps is None else f"{args.steps} steps per update"
        print(f"family of {args.family} (N = {task.N}, sigma {1e3 * sc.observer.noise:g} mm, {how}): {caught} caught; "
              f"position error median {1e3 * np.median(errors):.2f} mm, p90 {1e3 * np.percentile(errors, 90):.2f} mm, "
              f"max {1e3 * np.max(errors):.2f} mm; under 4 mm: {sum(e < 4e-3 for e in errors)}; the estimates at the catch "
              f"off by median {1e3 * np.median(est_errors):.2f} mm, max {1e3 * np.max(est_errors):.2f} mm; "
              f"{overruns} overruns, {skipped} skipped and {abandoned} abandoned of {updates} updates")
    print(f"load average {' '.join(f'{v:.2f}' for v in os.getloadavg())} (1, 5, 15 min)")


def ipopt(model, problem, run, every: int, hoc_median_wall: float, hoc_median_cpu: float) -> None:
    """IPOPT on every ``every``-th cycle's problem, warm-started from the previous such cycle's solution."""
    import sys

    try:
        import casadi  # noqa: F401
    except ImportError:
        print("  IPOPT: casadi is not importable (pip install casadi)")
        return
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _casadi_goals import Goal, GoalCollocation
    from ipopt_limits import Limits

    goal = problem.link_goal
    free = problem.time
    prev, walls, iters = None, [], []
    for rec in run.records[::every]:
        t = rec.t_start
        q0, dq0 = rec.plan.state(t)[0], rec.plan.state(t, 1)[0]
        lo, hi = max(free.min - t, 1e-3), free.max - t
        c = GoalCollocation(model, q0, dq0, Goal(link=goal.link, position=rec.position, velocity=rec.velocity,
                                                 acceleration=rec.acceleration, match_velocity=True),
                            (lo, hi), problem.N, weight=free.weight, limits=Limits.from_model(model))
        if prev is None:
            sol = c.solve(c.guess(rec.plan.T, rec.plan.state(rec.plan.t_end)[0], rec.plan.state(rec.plan.t_end, 1)[0]))
        else:
            sol = c.solve(warm=prev)
            walls.append(sol.wall)
            iters.append(sol.iterations)
        prev = sol
    if walls:
        print(f"  IPOPT warm per cycle (every {every}th, {len(walls)} cycles): wall ms {dist(1e3 * np.array(walls))}, "
              f"iterations median {np.median(iters):.0f}; IPOPT wall / hoc real-time update median: wall "
              f"{np.median(walls) / hoc_median_wall:.1f}x, CPU {np.median(walls) / hoc_median_cpu:.1f}x")


if __name__ == "__main__":
    main()
