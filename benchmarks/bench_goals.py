"""hoc's free-T and link-goal optima beside CasADi + IPOPT direct collocation of the same continuous problems.

    python benchmarks/bench_goals.py [--hoc-N 8 16 32] [--ipopt-K 8 16 32 64] [--skip-catch] [--hoc-catch [N ...]]

1. Free T: the two-link arm (configs/two_link.yaml's move) with ``T: {free: true, min: 0.5, max: 4,
   weight: 1}``, J + weight·T minimised over T, URDF limits enforced. hoc (``minimize_time`` on quintic
   Hermite elements, N elements) against IPOPT (``_casadi_goals.GoalCollocation``: T a variable,
   flipped-Radau collocation of degree 3 on K intervals). Prints J, T, J + weight·T per mesh.
2. Link position: the lbr7's flange to a fixed point at rest (``x1: {link, position, dq: zero}``) in
   T = 1 s, from configs/lbr7_reach.yaml's x0, URDF limits enforced. Prints J, the final q's distance
   to the finest IPOPT final q, and the reached position's error by forward kinematics (hoc's own and
   the CasADi transcription, checked against each other to 1e-12 first).
3. The catch (configs/catch_ball.yaml: free T, a moving target, match_velocity) at K = N = 8: IPOPT cold,
   then warm-started (primal and dual) after the ball's initial position moves by 1 cm; then the catch
   cold at each K (and hoc's cold catch at N = 8, 16, 32 with ``--hoc-catch``), wall and CPU time (the process's
   over the solver call), and, where hoc's N equals IPOPT's K, the ratios hoc/IPOPT of both from this run.
   hoc's warm replan of the same change: ``python benchmarks/bench_replan.py --ipopt``.

The modules hoc imports on first use (``scipy.optimize``) are imported before the timings, as CasADi's are: both
times are the solves' (IPOPT's exclude building the NLP; the start-up of ``hoc plan`` is ``bench_startup.py``'s).

The two discretisations differ (Hermite elements with Gauss quadrature against Radau collocation), so
single meshes differ by their discretisation errors; the converged values are compared.
"""
from __future__ import annotations

# isort: off
import _blas_threads  # noqa: F401  (before numpy: one BLAS thread, as hoc_cli sets)
# isort: on
import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from hoc_cli.dynamics import link_poses
from hoc_cli.elements import HermiteMesh
from hoc_cli.free_time import joint_goal_solver, minimize_time
from hoc_cli.goals import plan_goals
from hoc_cli.io.robot import load_model
from hoc_cli.io.task import load_task, load_yaml, parse_task, resolve
from hoc_cli.io.task.problem import task_goals, task_limits
from hoc_cli.system import RobotSystem

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _casadi_goals import Goal, GoalCollocation, check_kinematics  # noqa: E402
from _casadi_robot import check_dynamics  # noqa: E402
from ipopt_limits import Limits  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

FREE_T = """
robot: ../robots/two_link.urdf
gravity: [0.0, 0.0, -9.81]
x0: {q: [0.0, 0.0], dq: [0.0, 0.0]}
x1: {q: [1.2, -0.6], dq: [0.0, 0.0]}
T: {free: true, min: 0.5, max: 4.0, guess: 1.5, weight: 1.0}
order: quintic
cost: covariant
"""

LINK = """
robot: ../robots/lbr7.urdf
x0: {q: [0.0, 0.6, 0.0, -1.4, 0.0, 0.9, 0.0]}
x1: {link: lbr_flange, position: [0.45, 0.25, 0.75], dq: zero}
T: 1.0
order: quintic
cost: covariant
"""


def task_from(text: str, N: int):
    """(task, model, states, limits) of a task text (robot path relative to configs/), N elements."""
    doc = load_yaml(text)
    doc["N"] = N
    task = parse_task(doc, path=ROOT / "configs" / "bench_goals.yaml", text=text)
    model = load_model(task)
    states = resolve(task, model.joint_names)
    return task, model, states, task_limits(model, states.limits)


def hoc_free_T(N: int):
    """(J, T, objective, wall [s]) of hoc's free-T solve on N elements."""
    task, model, st, limits = task_from(FREE_T, N)
    free = task.time.free
    solve = joint_goal_solver(RobotSystem(model), task.order, N, st.q0, st.dq0, st.q1, st.dq1, limits=limits,
                              cost=task.cost)
    start = time.perf_counter()
    ft = minimize_time(solve, free.min, free.max, guess=free.guess, weight=free.weight)
    return ft.J, ft.T, ft.objective, time.perf_counter() - start


def ipopt_free_T(K: int):
    task, model, st, _ = task_from(FREE_T, 8)
    free = task.time.free
    c = GoalCollocation(model, st.q0, st.dq0, Goal(q1=st.q1, dq1=st.dq1), (free.min, free.max), K,
                        weight=free.weight, limits=Limits.from_model(model))
    r = c.solve(c.guess(free.guess, st.q1, st.dq1))
    return r


def hoc_link(N: int):
    """(J, final q, reached position, wall [s]) of hoc's link-goal plan on N elements."""
    task, model, st, limits = task_from(LINK, N)
    goals = task_goals(task, model, st)
    start = time.perf_counter()
    r = plan_goals(RobotSystem(model), HermiteMesh(task.order, task.T, N), st.q0, st.dq0, goals, limits=limits,
                   cost=task.cost)
    wall = time.perf_counter() - start
    q1 = r.coeffs[-1, 0]
    return r.J, q1, link_poses(model, q1)["lbr_flange"][:3, 3], wall, goals.final.position


def ipopt_link(K: int):
    task, model, st, _ = task_from(LINK, 8)
    goals = task_goals(task, model, st)
    c = GoalCollocation(model, st.q0, st.dq0, Goal(link="lbr_flange", position=goals.final.position), task.T, K,
                        limits=Limits.from_model(model))
    return c.solve(c.guess(task.T, goals.q1_guess)), model


def catch(path: Path = ROOT / "configs" / "catch_ball.yaml", moves=(0.01,), repeat: int = 3, K: int | None = None):
    """IPOPT on the catch task at K = its N: (cold solve, [(move [m], warm, cold moved)]), warm = best of ``repeat``
    solves warm-started from the cold optimum's primal and dual values after the ball's initial position moves
    by ``move`` along x; cold moved = the same change solved from the cold start."""
    task = load_task(Path(path), purpose="plan")
    model = load_model(task)
    st = resolve(task, model.joint_names)
    goals = task_goals(task, model, st)
    f, free = goals.final, task.time.free
    c = GoalCollocation(model, st.q0, st.dq0, Goal(link=f.link, position=f.position, velocity=f.velocity,
                                                   acceleration=f.acceleration, match_velocity=f.match_velocity),
                        (free.min, free.max), K or task.N, weight=free.weight, limits=Limits.from_model(model))
    x0 = c.guess(free.guess, goals.q1_guess, goals.dq1_guess)
    cpu = time.process_time()
    cold = c.solve(x0)
    catch.cpu = time.process_time() - cpu  # the cold solve's CPU time [s] (the process's), read by ``main``
    rows = []
    for dx in moves:
        p1 = f.position + np.array([dx, 0.0, 0.0])
        warm = min((c.solve(warm=cold, p0=p1) for _ in range(max(repeat, 1))), key=lambda r: r.wall)
        rows.append((dx, warm, c.solve(x0, p0=p1)))
    return cold, rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hoc-N", type=int, nargs="+", default=[8, 16, 32])
    ap.add_argument("--ipopt-K", type=int, nargs="+", default=[8, 16, 32, 64])
    ap.add_argument("--skip-catch", action="store_true")
    ap.add_argument("--hoc-catch", type=int, nargs="*", default=None,
                    help="also hoc's cold catch on these N (default 8 16 32; seconds to a minute each)")
    args = ap.parse_args()
    import scipy.optimize  # noqa: F401  (hoc's first-use import, before the timings: module docstring)

    if args.hoc_catch is not None and not args.hoc_catch:
        args.hoc_catch = [8, 16, 32]
    _, m2, _, _ = task_from(FREE_T, 8)
    _, m7, _, _ = task_from(LINK, 8)
    print(f"CasADi dynamics vs hoc: two-link {check_dynamics(m2):.1e}, lbr7 {check_dynamics(m7):.1e} (relative); "
          f"lbr_flange kinematics {check_kinematics(m7, 'lbr_flange'):.1e} m")

    print("\n1. free T, two-link, weight 1, URDF limits: minimise J + T")
    print(f"{'solver':>10} {'mesh':>5} {'J':>16} {'T [s]':>14} {'J + w·T':>16} {'wall [s]':>9} {'status':>8}")
    for N in args.hoc_N:
        J, T, obj, wall = hoc_free_T(N)
        print(f"{'hoc':>10} {N:5d} {J:16.10f} {T:14.10f} {obj:16.10f} {wall:9.2f}", flush=True)
    for K in args.ipopt_K:
        r = ipopt_free_T(K)
        print(f"{'IPOPT':>10} {K:5d} {r.J:16.10f} {r.T:14.10f} {r.objective:16.10f} {r.wall:9.2f} "
              f"{'ok' if r.success else r.status:>8}", flush=True)

    print("\n2. link position, lbr7 flange at rest, T = 1 s, URDF limits")
    rows = [("IPOPT", K, *ipopt_link(K)) for K in args.ipopt_K]
    q_ref = rows[-1][2].q1
    model = rows[-1][3]
    print(f"{'solver':>10} {'mesh':>5} {'J':>16} {'|q1 − q1_ref|':>14} {'|p − p̄| [m]':>12} {'wall [s]':>9}")
    for N in args.hoc_N:
        J, q1, p, wall, target = hoc_link(N)
        print(f"{'hoc':>10} {N:5d} {J:16.10f} {np.abs(q1 - q_ref).max():14.2e} {np.linalg.norm(p - target):12.1e} "
              f"{wall:9.2f}", flush=True)
    for _, K, r, _ in rows:
        p = link_poses(model, r.q1)["lbr_flange"][:3, 3]
        print(f"{'IPOPT':>10} {K:5d} {r.J:16.10f} {np.abs(r.q1 - q_ref).max():14.2e} {np.linalg.norm(p - target):12.1e} "
              f"{r.wall:9.2f}  {'' if r.success else r.status}")
    print(f"   q1_ref (IPOPT K = {rows[-1][1]}) = {np.array2string(q_ref, precision=6)}")

    if not args.skip_catch:
        print("\n3. configs/catch_ball.yaml, IPOPT at K = 8: cold, warm after a 1 cm move of the ball (best of 3), "
              "cold after it")
        print(f"{'solve':>10} {'J':>16} {'T [s]':>12} {'iterations':>10} {'wall [ms]':>10} {'status':>8}")
        cold, [(_, warm, moved)] = catch()
        for name, r in (("cold", cold), ("warm", warm), ("cold moved", moved)):
            print(f"{name:>10} {r.J:16.10f} {r.T:12.8f} {r.iterations:10d} {1e3 * r.wall:10.1f} "
                  f"{'ok' if r.success else r.status:>8}")
        load = " ".join(f"{x:.2f}" for x in os.getloadavg())
        print(f"   the same catch, cold, as the mesh refines (ratio: hoc / IPOPT at N = K, wall and CPU, this run; load "
              f"average 1, 5, 15 min: {load})")
        print(f"{'solver':>10} {'mesh':>5} {'J':>16} {'T [s]':>12} {'wall [s]':>9} {'CPU [s]':>8} {'ratio wall':>10} "
              f"{'ratio CPU':>9}")
        hoc_times = {}
        if args.hoc_catch:
            from bench_replan import cold as hoc_cold
            text = (ROOT / "configs" / "catch_ball.yaml").read_text()
            for N in args.hoc_catch:
                task, model, st, limits = task_from(text, N)
                cpu = time.process_time()
                ft, wall = hoc_cold(RobotSystem(model), task, st, task_goals(task, model, st), limits)
                hoc_times[N] = (wall, time.process_time() - cpu)
                print(f"{'hoc':>10} {N:5d} {ft.J:16.10f} {ft.T:12.8f} {wall:9.2f} {hoc_times[N][1]:8.2f}", flush=True)
        for K in args.ipopt_K:
            r = catch(moves=(), K=K)[0]
            ratios = ""
            if K in hoc_times:
                ratios = f" {hoc_times[K][0] / r.wall:10.2f} {hoc_times[K][1] / max(catch.cpu, 1e-9):9.2f}"
            print(f"{'IPOPT':>10} {K:5d} {r.J:16.10f} {r.T:12.8f} {r.wall:9.2f} {catch.cpu:8.2f}{ratios}"
                  f"  {'' if r.success else r.status}", flush=True)


if __name__ == "__main__":
    main()
