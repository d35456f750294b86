"""hoc with joint limits enforced beside CasADi + IPOPT collocation with the same limits (issue 11).

Run:  python benchmarks/bench_limits.py              (3 tasks × N = 16, 32, 64; a few minutes on 2 cores)
      python benchmarks/bench_limits.py --quick      (N = 16, 32; one timing run)
      python benchmarks/bench_limits.py --N 16 32 64 128 --d 3 --json limits.json --task configs/lbr7_swing.yaml

Tasks: configs/lbr7_swing.yaml, configs/dual_arm.yaml and benchmarks/tasks/ur5_limits.yaml (a UR5
# isort: off
import _blas_threads  # noqa: F401  (before numpy: one BLAS thread, as hoc_cli sets)
# isort: on
from example-robot-data, its path resolved at run time), each with its URDF limits (position,
velocity, effort; no acceleration limit unless ``--acceleration``), the task's cost (``--cost torque``
to change it, e.g. ``--task configs/lbr7_reach.yaml --cost torque --skip-free``).

IPOPT side (benchmarks/ipopt_limits.py): flipped-Radau collocation, N intervals of degree d, the
limits imposed at every collocation node; exact Hessian, MUMPS, tol 1e-10. Columns: J, the solver
call's wall time (fastest of --repeat solves after one setup), the time at which its iterate was
first within 1e-6 (relative) of its own final J AND feasible to 1e-8 (iteration callback),
iterations; the setup (symbolic build) is reported apart. Per task: J's successive differences as
N doubles and the order they show; the limits active at the finest mesh. Before the limits, one
unconstrained IPOPT solve (finest mesh) beside hoc's unconstrained plan checks that the two
transcribe the same problem (same J to the discretisation error).

hoc side: ``hoc_side(task, N)`` below: ``hoc_cli.planner.plan(..., limits=...)`` with the same
limits, the task's tol (fastest of --repeat plans); columns hoc's J, solve time and "to 1e-6", and
the ratios hoc/IPOPT. hoc's
"to 1e-6" is its whole solve time (coarse levels included): its iterates are only certified within
the limits by the exact check at the end of a level, so no earlier time is claimed (an upper bound).
Compare CONVERGED values (J as both meshes refine), not one mesh: the two methods impose the
limits at different points.

BLAS is pinned to one thread (before numpy loads), as in bench_plan.py.
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import inspect  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import casadi as ca  # noqa: E402
import numpy as np  # noqa: E402

from hoc_cli.constraints import JointLimits  # noqa: E402
from hoc_cli.elements import HermiteMesh  # noqa: E402
from hoc_cli.io.task import apply_overrides  # noqa: E402
from hoc_cli.planner import plan  # noqa: E402
from hoc_cli.system import RobotSystem  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import ipopt_limits as il  # noqa: E402
from _casadi_robot import check_dynamics  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
TASKS = [ROOT / "configs" / "lbr7_swing.yaml", ROOT / "configs" / "dual_arm.yaml",
         ROOT / "benchmarks" / "tasks" / "ur5_limits.yaml"]
RTOL = 1e-6      # time to J within RTOL of the method's own converged J ...
FEAS = 1e-8      # ... with every limit and every equality within FEAS (absolute)


def time_to_tol(rows, J_final: float, level: int | None = None) -> float:
    """First time [s] in rows (time, J, level, violation) with |J − J_final| <= RTOL |J_final|,
    violation <= FEAS and (if given) on mesh ``level``; nan if never."""
    for t, J, lev, viol in rows:
        if (level is None or lev == level) and abs(J - J_final) <= RTOL * abs(J_final) and viol <= FEAS:
            return t
    return math.nan


# =========================================================================== HOC SIDE
def hoc_side(task, N: int, acceleration: float | None = None, repeat: int = 1) -> dict | None:
    """hoc's plan of ``task`` on N elements with the same limits IPOPT gets (``JointLimits``).

    Time to 1e-6: hoc's iterates are only certified feasible when its augmented-Lagrangian loop
    stops (the exact check of every element), so the whole solve time is reported: an upper bound;
    the fastest of ``repeat`` plans (the same plan each time), as IPOPT's fastest of ``repeat`` solves.
    Returns {J, wall, t_to_tol, iterations, converged, q}: q(t) -> (m, n) the plan's positions.
    """
    task, model, st = il.load(task)
    lim = il.Limits.from_model(model, acceleration=acceleration)
    limits = JointLimits.from_arrays(model.joint_names, lim.lower, lim.upper, lim.velocity, lim.acceleration, lim.effort)
    walls = []
    for _ in range(max(repeat, 1)):
        r = plan(RobotSystem(model), HermiteMesh(task.order, task.T, N), st.q0, st.dq0, st.q1, st.dq1,
                 cost=task.cost, method=task.method, tol=task.tol, max_iter=task.max_iter, limits=limits)
        walls.append(r.wall_time_s)
    return dict(J=r.J, wall=min(walls), t_to_tol=min(walls), iterations=r.optimizer.iterations,
                converged=r.converged, q=lambda t: r.mesh.evaluate(r.coeffs, t, 0))


# =========================================================================== end of the hoc side


def hoc_unconstrained(task, N: int) -> float:
    """hoc's J for the unconstrained problem (today's plan, no limits) on N elements.

    ``limits=None`` is the paper's unconstrained problem (``--limits report``)."""
    task, model, st = il.load(task)
    r = plan(RobotSystem(model), HermiteMesh(task.order, task.T, N), st.q0, st.dq0, st.q1, st.dq1, cost=task.cost,
             method=task.method, tol=1e-12, limits=None)
    return r.J


def fmt(x: float | None, spec: str) -> str:
    return "—" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, spec)


def say(*args) -> None:
    print(*args, flush=True)


def free_check(task, model, limits: il.Limits, N: int, d: int) -> None:
    """The same problem: unconstrained IPOPT on N intervals beside hoc's unconstrained plan; and how
    far that optimum breaks the limits."""
    free = il.solve(task, N, limits=None, d=d)
    N_hoc = max(N, 32)
    J_hoc = hoc_unconstrained(task, N_hoc)
    say(f"unconstrained: IPOPT N={N} d={d} J = {free.J:.10f} ({free.status}); hoc quintic "
        f"N={N_hoc} J = {J_hoc:.10f}; |ΔJ|/J = {abs(free.J - J_hoc) / abs(J_hoc):.1e}")
    excess = {}  # the unconstrained optimum's worst excess over each kind of limit, relative to the limit
    series = {"position": free.q, "velocity": free.dq, "acceleration": free.ddq, "effort": free.u}
    for k, X in series.items():
        lo, hi = limits.bounds(k)
        scale = np.where(np.isfinite(hi) & (hi != 0), np.abs(hi), 1.0)
        e = float(np.max(np.maximum(lo - X, X - hi) / scale, initial=0.0))
        if e > 1e-9:
            excess[k] = e
    say("unconstrained optimum's worst excess over the limits (relative to the limit): "
        + (", ".join(f"{k} {v:.3f}" for k, v in excess.items()) if excess else "none (no limit is broken)"))


def run_task(path: Path, Ns: list[int], d: int, acceleration: float | None, repeat: int, cost: str | None = None,
             skip_free: bool = False) -> list[dict]:
    task = apply_overrides(il.load_task(path), cost=cost)
    task, model, _ = il.load(task)
    limits = il.Limits.from_model(model, acceleration=acceleration)
    say(f"\n== {path.name}: {model.n} joints, T = {task.T} s, cost {task.cost}, robot {task.robot.name} ==")
    say(f"CasADi RNEA, M, wᵀMw vs hoc_cli.dynamics: max relative difference {check_dynamics(model):.1e}")
    lim = [f"{k} {int(np.isfinite(limits.bounds(k)[1]).sum())}" for k in il.KINDS]
    say("joints with a limit: " + ", ".join(lim))

    if not skip_free:
        free_check(task, model, limits, Ns[-1], d)

    rows = []
    for N in Ns:
        r = il.solve(task, N, d=d, acceleration=acceleration, repeat=repeat)
        h = hoc_side(task, N, acceleration, repeat)
        if h:
            tt = np.linspace(0.0, task.T, 1001)
            h["gap"] = float(np.abs(h.pop("q")(tt) - r.interpolate(tt)[0]).max())
        rows.append(dict(task=path.name, N=N, d=d, J=r.J, wall=r.wall, t_to_tol=r.t_to_tol, setup=r.setup,
                         iterations=r.iterations, status=r.status, violation=r.max_violation,
                         unknowns=r.n_unknowns, active=r.active, hoc=h))
        say(f"  IPOPT N={N:<4d} d={d} J = {r.J:.10f}  {r.status}  it {r.iterations:3d}  solve {r.wall:6.2f} s  "
            f"to 1e-6 {r.t_to_tol:6.2f} s  setup {r.setup:5.1f} s  violation {r.max_violation:.0e}  "
            f"active limits {len(r.active)}" + (f"   hoc J = {h['J']:.10f}, max|q_hoc − q_IPOPT| = "
                                                  f"{h['gap']:.1e} rad" if h else ""))
    J = [row["J"] for row in rows]
    for k in range(1, len(J)):
        p = ""
        if k >= 2 and J[k] != J[k - 1] and J[k - 1] != J[k - 2]:
            p = f"  order ≈ {math.log2(abs(J[k - 1] - J[k - 2]) / abs(J[k] - J[k - 1])):.1f}"
        say(f"  J(N={Ns[k]}) − J(N={Ns[k - 1]}) = {J[k] - J[k - 1]:+.3e}{p}")
    say(f"limits active at N={Ns[-1]} (joint, kind, side: time intervals in s, samples within 1e-6 of the limit):")
    for a in rows[-1]["active"]:
        spans = ", ".join(f"[{t0:.3f}, {t1:.3f}]" for t0, t1 in a["intervals"])
        say(f"  {a['joint']:22s} {a['kind']:12s} {a['side']:5s} {a['limit']:+9.4f}: {spans}")
    if not rows[-1]["active"]:
        say("  none: the unconstrained optimum is within the limits")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="N = 16, 32 only")
    ap.add_argument("--task", action="append", help="a task file (repeatable; default: the three above)")
    ap.add_argument("--N", type=int, nargs="+", help="collocation intervals (default 16 32 64)")
    ap.add_argument("--d", type=int, default=3, help="collocation degree per interval (default 3)")
    ap.add_argument("--acceleration", type=float, help="a uniform acceleration limit [rad/s²] (default: none)")
    ap.add_argument("--repeat", type=int, default=3, help="IPOPT solves and hoc plans per mesh, the fastest counts "
                    "(default 3)")
    ap.add_argument("--cost", choices=("covariant", "torque"), help="override the tasks' cost")
    ap.add_argument("--skip-free", action="store_true", help="skip the unconstrained IPOPT-vs-hoc check")
    ap.add_argument("--json", type=Path, help="write the figures to this file")
    args = ap.parse_args()
    Ns = args.N or ([16, 32] if args.quick else [16, 32, 64])
    started = time.perf_counter()
    say(f"casadi {ca.__version__} (IPOPT + MUMPS), threads OPENBLAS_NUM_THREADS={os.environ['OPENBLAS_NUM_THREADS']}; "
        f"hoc {'takes' if 'limits' in inspect.signature(plan).parameters else 'does NOT yet take'} limits=")
    rows = []
    for path in [Path(t) for t in args.task] if args.task else TASKS:
        rows += run_task(path, Ns, args.d, args.acceleration, 1 if args.quick else args.repeat, args.cost,
                         args.skip_free)

    say(f"\n== summary: time to J within {RTOL:.0e} of each method's own converged J, feasible to {FEAS:.0e} ==")
    head = (f"{'task':18s} {'N':>4s} {'IPOPT J':>16s} {'IPOPT [s]':>9s} {'to 1e-6':>8s} {'active':>6s} "
            f"{'hoc J':>16s} {'hoc [s]':>8s} {'to 1e-6':>8s} {'ΔJ/J':>8s} {'max|Δq|':>8s} {'time':>6s} {'to 1e-6':>7s}")
    say(head + "\n" + " " * 93 + "hoc/IPOPT ratios ↑")
    say("-" * len(head))
    for r in rows:
        h = r["hoc"] or {}
        dJ = abs(h["J"] - r["J"]) / abs(r["J"]) if h else None
        ratio = h["wall"] / r["wall"] if h else None
        ratio_t = h["t_to_tol"] / r["t_to_tol"] if h else None
        say(f"{r['task']:18s} {r['N']:4d} {r['J']:16.10f} {r['wall']:9.3f} {r['t_to_tol']:8.3f} {len(r['active']):6d} "
            f"{fmt(h.get('J'), '16.10f'):>16s} {fmt(h.get('wall'), '8.3f'):>8s} {fmt(h.get('t_to_tol'), '8.3f'):>8s} "
            f"{fmt(dJ, '8.1e'):>8s} {fmt(h.get('gap'), '8.1e'):>8s} {fmt(ratio, '6.2f'):>6s} {fmt(ratio_t, '7.2f'):>7s}")
    say(f"\n(IPOPT: flipped Radau degree {args.d}, N intervals; hoc: the task's order, N elements. "
        f"Total {time.perf_counter() - started:.0f} s)")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1, default=float))
        say(f"wrote {args.json}")


if __name__ == "__main__":
    main()
