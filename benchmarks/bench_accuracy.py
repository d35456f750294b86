"""Time to a J verified within 1e-8 of the continuous optimum: hoc ``N: auto`` beside CasADi + IPOPT.

Run:  python benchmarks/bench_accuracy.py          (about a minute on 2 cores; needs '.[bench]')
      python benchmarks/bench_accuracy.py --task configs/two_link.yaml   (one task)
      python benchmarks/bench_accuracy.py --refine   (N: auto splitting elements vs doubling N, a minute)
      python benchmarks/bench_accuracy.py --drift [--drift-N 16 32 64 128] [--drift-limits report]
          (issue 16 item 4, minutes: J(N) of the torque cost on light-wristed arms, DRIFT_TASKS,
          solved as ``hoc plan TASK -N N`` would, limits enforced; converged, max joint speed)

Tasks: configs/two_link.yaml and configs/lbr7_reach.yaml, each with its own cost (covariant), T and
boundary states, solved WITHOUT joint limits on both sides (hoc ``limits=None``, i.e. ``--limits
report``; IPOPT ``limits=None``). The script checks that the reference optimum stays within every URDF
limit, so the tasks' default ``limits: enforce`` has the same optimum.

Reference J*: one hoc solve on N = 256 quintic elements (tol 1e-13; nested continuation, so the same
solve holds the plans on 64 and 128 elements), Richardson-extrapolated with the measured order (capped
at 8, the order of J for quintic elements; 8 when the differences are at rounding level):
J* = J(256) − (J(128) − J(256)) / (2ᵖ − 1). It is checked against IPOPT's finest mesh (LGR K = 16,
degree 7): they must agree to 1e-10 (relative), and IPOPT's q must be within 1e-2 rad of hoc's (the
same local optimum).

hoc: ``hoc_cli.accuracy.plan_auto`` with accuracy 1e-8 (what ``N: auto`` runs): plans on 16, 32, …
elements until its own error estimate is below 5e-9; the time is the whole call, its verification
(the warm-started solves on 2N and N/2 elements) included. Also shown: the plan alone on the mesh
``N: auto`` chose (the time if that N were known in advance).

IPOPT (``ipopt_limits.LimitedCollocation``: flipped Legendre-Gauss-Radau collocation, exact Hessian,
MUMPS, tol 1e-10, from the minimum-jerk quintic): a sweep of K for degrees d = 3, 5, 7; for each d the
coarsest K whose J is within 1e-8 of J* (known here, not to a user). The mesh it needs is the fastest of
these. Two times: that mesh alone (an oracle that knows the mesh in advance), and that mesh plus the
mesh twice finer (what it takes to verify the accuracy the way ``N: auto`` does, by comparing J on
K and 2K intervals). IPOPT's symbolic setup (CasADi build + ``expand`` + ``nlpsol``, per mesh) is shown
apart and not counted. Every time is the best of 3 (wall clock; hoc: the ``plan_auto``/``plan`` call;
IPOPT: the solver call). BLAS is pinned to one thread.
"""
from __future__ import annotations

# isort: off
import _blas_threads  # noqa: F401  (before numpy: one BLAS thread, as hoc_cli sets)
# isort: on
import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import casadi as ca  # noqa: E402
import numpy as np  # noqa: E402

from hoc_cli.accuracy import SMOOTH_ORDER, plan_auto  # noqa: E402
from hoc_cli.elements import HermiteMesh  # noqa: E402
from hoc_cli.limits import dense_times, limit_violations  # noqa: E402
from hoc_cli.planner import plan  # noqa: E402
from hoc_cli.system import RobotSystem  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _casadi_robot import check_dynamics  # noqa: E402
from ipopt_limits import LimitedCollocation, load  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
TASKS = (ROOT / "configs" / "two_link.yaml", ROOT / "configs" / "lbr7_reach.yaml")
TARGET = 1e-8            # relative accuracy of J against the continuous optimum
REF_N = 256              # hoc reference mesh (quintic)
REF_TOL = 1e-13
REF_AGREE = 1e-10        # J* and IPOPT's finest J must agree to this (relative)
SAME = 1e-2              # rad: farther apart is another local optimum
IPOPT_FINEST = (16, 7)   # (K, d)
IPOPT_SWEEP = {3: (8, 16, 32, 64, 128), 5: (4, 8, 16, 32), 7: (4, 8, 16)}
RUNS = 3
DRIFT_TASKS = (ROOT / "benchmarks" / "tasks" / "panda_torque.yaml", ROOT / "benchmarks" / "tasks" / "kinova_torque.yaml")


def say(*args) -> None:
    print(*args, flush=True)


def rel(J: float, J_ref: float) -> float:
    return abs(J - J_ref) / abs(J_ref)


def best_of(fn, runs: int = RUNS):
    """(the result of the fastest call, its time [s]) over ``runs`` calls of fn() -> (result, seconds)."""
    return min((fn() for _ in range(runs)), key=lambda o: o[1])


def reference(system: RobotSystem, task, st) -> tuple[float, object, dict]:
    """(J*, the plan on REF_N elements, details): Richardson from J(REF_N/4), J(REF_N/2), J(REF_N)."""
    r = plan(system, HermiteMesh("quintic", task.T, REF_N), st.q0, st.dq0, st.q1, st.dq1, cost=task.cost,
             tol=REF_TOL, max_iter=task.max_iter)
    if not r.converged or r.coarser is None or r.coarser.coarser is None:
        raise SystemExit(f"{task.path}: the reference solve on {REF_N} elements did not converge "
                         f"({r.optimizer.message})")
    J = [r.coarser.coarser.J, r.coarser.J, r.J]
    d1, d2 = J[0] - J[1], J[1] - J[2]
    cap = SMOOTH_ORDER["quintic"]
    p = math.log2(d1 / d2) if d1 * d2 > 0 and abs(d1) > abs(d2) else cap
    p_used = min(p, cap)
    J_star = J[2] - d2 / (2.0**p_used - 1.0)
    return J_star, r, {"J": J, "order": p, "order_used": p_used, "correction": J_star - J[2]}


def within_limits(model, r) -> list[dict]:
    """URDF limit violations of the plan r, sampled densely (empty: within every limit)."""
    t = dense_times(r.mesh.T, r.mesh.N)
    q, dq, ddq = r.mesh.evaluate_all(r.coeffs, t)
    u = RobotSystem(model).inverse_dynamics(q, dq, ddq)
    return limit_violations(model.joint_names, model.lower, model.upper, model.velocity_limit, model.effort_limit,
                            t, q, dq, u)


def run_task(path: Path) -> dict:
    task, model, st = load(path)
    system = RobotSystem(model)
    say(f"\n=== {path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}: {model.n} joints, "
        f"T = {task.T:g} s, {task.cost} cost, limits not imposed (report mode) ===")
    say(f"CasADi RNEA, M, wᵀMw vs hoc_cli.dynamics at 50 random states: max relative difference "
        f"{check_dynamics(model):.1e}")

    # ---- the reference optimum
    started = time.perf_counter()
    J_star, ref, info = reference(system, task, st)
    say(f"hoc quintic N = {REF_N // 4}, {REF_N // 2}, {REF_N} (tol {REF_TOL:g}): J = "
        + ", ".join(f"{J:.13f}" for J in info["J"]) + f"  ({time.perf_counter() - started:.1f} s)")
    say(f"  Richardson: order measured {info['order']:.2f}, used {info['order_used']:.2f}; correction "
        f"{info['correction']:+.1e}  ->  J* = {J_star:.13f}")
    violations = within_limits(model, ref)
    say("  the reference optimum is within every URDF limit (limits: enforce has the same optimum)" if not violations
        else "  the reference optimum breaks URDF limits: " + "; ".join(f"{v['joint']} {v['kind']}" for v in violations))
    builds: dict[tuple[int, int], LimitedCollocation] = {}

    def colloc(K: int, d: int) -> LimitedCollocation:
        if (K, d) not in builds:
            builds[K, d] = LimitedCollocation(model, task.T, st.q0, st.dq0, st.q1, st.dq1, K, d, limits=None,
                                              cost=task.cost)
        return builds[K, d]

    def gap(c: LimitedCollocation, s) -> float:
        return float(np.abs(s.q - ref.mesh.evaluate(ref.coeffs, c.times, 0)).max())

    c = colloc(*IPOPT_FINEST)
    s = c.solve()
    agree = rel(s.J, J_star)
    say(f"IPOPT LGR K = {IPOPT_FINEST[0]} d = {IPOPT_FINEST[1]} (finest): J = {s.J:.13f}  {s.status}  "
        f"|J - J*|/J* = {agree:.1e}  max|q - q_hoc| = {gap(c, s):.1e} rad")
    if not (s.success and agree <= REF_AGREE and gap(c, s) < SAME):
        raise SystemExit(f"the reference J* and IPOPT's finest mesh disagree ({agree:.1e} > {REF_AGREE:g}, "
                         "or another local optimum)")

    # ---- hoc N: auto
    def timed_auto():
        t0 = time.perf_counter()
        a = plan_auto(system, "quintic", task.T, st.q0, st.dq0, st.q1, st.dq1, accuracy=TARGET, cost=task.cost,
                      method=task.method, tol=task.tol, max_iter=task.max_iter, limits=None)
        return a, time.perf_counter() - t0

    a, t_auto = best_of(timed_auto)
    N_auto = a.plan.mesh.N
    err_auto = rel(a.plan.J, J_star)
    say(f"hoc N: auto (accuracy {TARGET:g}): " + ", ".join(
        f"N = {s['N']}: J = {s['J']:.13f}, estimate {s['J_error_estimate']:.1e}" for s in a.steps)
        + f"; true error {err_auto:.1e}; reached = {a.reached}")
    if not (a.reached and err_auto <= TARGET):
        raise SystemExit(f"hoc N: auto missed the target: true error {err_auto:.1e}")

    def fixed():
        r = plan(system, HermiteMesh("quintic", task.T, N_auto), st.q0, st.dq0, st.q1, st.dq1, cost=task.cost,
                 method=task.method, tol=min(task.tol, TARGET / 100), max_iter=task.max_iter)
        return r, r.wall_time_s

    r_fixed, t_fixed = best_of(fixed)

    # ---- IPOPT sweep
    say(f"IPOPT sweep (LGR, from the minimum-jerk quintic): the coarsest K per degree with J within {TARGET:g} of J*")
    hits = []
    for d, Ks in IPOPT_SWEEP.items():
        for K in Ks:
            c = colloc(K, d)
            s = c.solve()
            e, g = rel(s.J, J_star), gap(c, s)
            say(f"  K = {K:<3d} d = {d}  J = {s.J:.13f}  |J - J*|/J* = {e:.1e}  solve {s.wall:.3f} s  "
                f"setup {c.setup:.2f} s  iterations {s.iterations}  unknowns {c.n_unknowns}  {s.status}")
            if s.success and e <= TARGET and g < SAME:
                hits.append((K, d))
                break
        else:
            say(f"  degree {d}: no K in {Ks} reached the target")
    if not hits:
        raise SystemExit("IPOPT reached the target on no mesh of the sweep")
    timed = {}
    for K, d in hits:
        c = colloc(K, d)
        timed[K, d] = best_of(lambda c=c: (lambda s: (s, s.wall))(c.solve()))
    K, d = min(hits, key=lambda kd: timed[kd][1])
    s_ip, t_ip = timed[K, d]
    c2 = colloc(2 * K, d)
    s_ver, t_ver = best_of(lambda: (lambda s: (s, s.wall))(c2.solve()))
    say(f"  the mesh IPOPT needs: K = {K} d = {d} (fastest of {', '.join(f'K = {k} d = {e}' for k, e in hits)}); "
        f"verification mesh K = {2 * K}: |J(K) - J(2K)|/J = {rel(s_ip.J, s_ver.J):.1e}")
    return dict(name=path.name, n=model.n, J_star=J_star, agree=agree,
                rows=[("hoc N: auto (incl. its estimate)", f"N = {N_auto} quintic", a.plan.J, err_auto, t_auto, 0.0),
                      (f"hoc N = {N_auto} alone (N known)", f"N = {N_auto} quintic", r_fixed.J, rel(r_fixed.J, J_star),
                       t_fixed, 0.0),
                      ("IPOPT, the mesh it needs (oracle)", f"K = {K} d = {d}", s_ip.J, rel(s_ip.J, J_star), t_ip,
                       colloc(K, d).setup),
                      ("IPOPT, that mesh + K doubled", f"K = {K}, {2 * K} d = {d}", s_ver.J, rel(s_ver.J, J_star),
                       t_ip + t_ver, colloc(K, d).setup + c2.setup)])


def drift(paths, Ns, mode: str) -> None:
    """J(N) for each task and N, each N solved on its own from the minimum-jerk guess (``hoc plan -N N``)."""
    from hoc_cli.commands.plan import solve
    from hoc_cli.io.task.problem import task_limits

    say(f"torque-cost drift: each N solved on its own (as `hoc plan TASK -N N`), limits: {mode}")
    for path in paths:
        task, model, st = load(path)
        task = dataclasses.replace(task, limits=dataclasses.replace(task.limits, mode=mode))
        limits = task_limits(model, st.limits)
        say(f"\n=== {path.relative_to(ROOT)}: {model.n} joints, T = {task.T:g} s, {task.cost} cost, "
            f"tol {task.tol:g}, max_iter {task.max_iter}; velocity limits "
            + ", ".join(f"{v:.3g}" for v in model.velocity_limit) + " rad/s ===")
        say(f"{'N':>4s} {'J':>16s} {'converged':>9s} {'status':>20s} {'iter':>5s} {'time [s]':>8s} "
            f"{'max |dq| [rad/s] (joint)':>26s} {'|dq|/limit':>10s} {'violations':>10s}")
        for N in Ns:
            started = time.perf_counter()
            r, _ = solve(task, model, st, HermiteMesh(task.order, task.T, N), limits)
            wall = time.perf_counter() - started
            t = dense_times(task.T, N)
            dq = np.abs(r.mesh.evaluate(r.coeffs, t, 1)).max(axis=0)
            j = int(np.argmax(dq))
            ratio = float(np.max(dq / model.velocity_limit))
            say(f"{N:4d} {r.J:16.9f} {str(r.converged):>9s} {r.optimizer.status.value:>20s} "
                f"{r.optimizer.iterations:5d} {wall:8.1f} {dq[j]:14.4f} ({model.joint_names[j]}) {ratio:10.4f} "
                f"{len(within_limits(model, r)):10d}")


def refine_table() -> None:
    """``N: auto`` with h-refinement beside uniform doubling: elements, J, estimate, true error (when known)."""
    from hoc_cli.constraints import JointLimits
    from hoc_cli.io.task.problem import task_limits
    from hoc_cli.system import LinearOscillator

    osc = LinearOscillator(1, omega=0.0)
    t1 = 1.5 * (1.0 - 1.0 / 1.3)
    cases = [("1-DOF, |q̇| <= 1.3 (analytic J*)", osc, ("quintic", 1.0, [0.0], [0.0], [1.0], [0.0]), "covariant",
              JointLimits.from_arrays(osc.joint_names, velocity=[1.3]), 4 * 1.3**2 / (3 * t1), 1e-6)]
    for path, cost, accuracy, enforce in ((ROOT / "benchmarks" / "tasks" / "ur5_limits.yaml", None, 1e-6, True),
                                          (ROOT / "configs" / "two_link.yaml", "torque", 1e-9, False)):
        task, model, st = load(path)
        cost = cost or task.cost
        cases.append((f"{path.stem} {cost} ({'limits enforced' if enforce else 'no limits'})", RobotSystem(model),
                      (task.order, task.T, st.q0, st.dq0, st.q1, st.dq1), cost,
                      task_limits(model, st.limits) if enforce else None, None, accuracy))
    say(f"{'task':34s} {'accuracy':8s} {'refine':8s} {'N':>4s} {'meshes (N)':28s} {'J':>18s} {'estimate':>9s} {'true':>9s} "
        f"{'time [s]':>8s}")
    for name, system, args, cost, limits, J_star, accuracy in cases:
        for refine in ("h", "uniform"):
            started = time.perf_counter()
            f = plan_auto(system, *args, cost=cost, limits=limits, accuracy=accuracy, refine=refine)
            wall = time.perf_counter() - started
            true = "-" if J_star is None else f"{(f.plan.J - J_star) / J_star:9.1e}"
            est = "-" if f.error.relative is None else f"{f.error.relative:9.1e}"
            meshes = ", ".join(str(s["N"]) for s in f.steps)
            say(f"{name:34s} {accuracy:8.0e} {refine:8s} {f.plan.mesh.N:4d} {meshes:28s} {f.plan.J:18.10f} {est:>9s} {true:>9s} "
                f"{wall:8.1f}{'' if f.reached else '  (accuracy not reached)'}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--task", action="append", type=Path,
                    help="a task file (repeatable; default: configs/two_link.yaml and configs/lbr7_reach.yaml)")
    ap.add_argument("--refine", action="store_true", help="N: auto splitting elements beside doubling N instead")
    ap.add_argument("--drift", action="store_true", help="the torque-cost drift table instead (issue 16 item 4)")
    ap.add_argument("--drift-N", type=int, nargs="+", default=[16, 32, 64, 128])
    ap.add_argument("--drift-limits", choices=("enforce", "report"), default="enforce")
    args = ap.parse_args()
    if args.refine:
        refine_table()
        return
    if args.drift:
        drift([Path(p).resolve() for p in (args.task or DRIFT_TASKS)], args.drift_N, args.drift_limits)
        return
    total = time.perf_counter()
    say(f"casadi {ca.__version__} (IPOPT + MUMPS); OPENBLAS_NUM_THREADS={os.environ['OPENBLAS_NUM_THREADS']}; "
        f"target |J - J*|/J* <= {TARGET:g}; times best of {RUNS}")
    say(f"J*: hoc quintic N = {REF_N} (tol {REF_TOL:g}), Richardson from N = {REF_N // 4}, {REF_N // 2}, {REF_N}; "
        f"checked against IPOPT LGR K = {IPOPT_FINEST[0]} d = {IPOPT_FINEST[1]}; no joint limits on either side")
    results = [run_task(Path(p).resolve()) for p in (args.task or TASKS)]

    say(f"\n== time to J within {TARGET:g} of J* (best of {RUNS}; IPOPT setup not counted) ==")
    head = f"{'task':16s} {'method':34s} {'mesh':16s} {'J':>18s} {'|J-J*|/J*':>9s} {'time [s]':>8s} " \
           f"{'setup [s]':>9s}"
    say(head)
    say("-" * len(head))
    for res in results:
        for method, mesh, J, err, t, setup in res["rows"]:
            setup_text = f"{setup:.2f}" if setup else "-"
            say(f"{res['name']:16s} {method:34s} {mesh:16s} {J:18.12f} {err:9.1e} {t:8.3f} {setup_text:>9s}")
    say("\nratios hoc / IPOPT (time):")
    for res in results:
        auto, fixed, oracle, verified = (row[4] for row in res["rows"])
        say(f"  {res['name']:16s} N: auto / IPOPT oracle {auto / oracle:5.2f}   N: auto / IPOPT verified "
            f"{auto / verified:5.2f}   hoc N known / IPOPT oracle {fixed / oracle:5.2f}")
    say(f"J* checked against IPOPT LGR K = {IPOPT_FINEST[0]} d = {IPOPT_FINEST[1]}: " + ", ".join(
        f"{res['name']} {res['agree']:.1e}" for res in results) + " (relative)")
    say(f"\ntotal benchmark time {time.perf_counter() - total:.0f} s")


if __name__ == "__main__":
    main()
