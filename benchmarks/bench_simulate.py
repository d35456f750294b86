"""Hermite collocation (``--method hermite``) against scipy's DOP853 (``--method rk``) at equal accuracy.

Run:  python benchmarks/bench_simulate.py            (about a minute)
      python benchmarks/bench_simulate.py --quick    (fewer settings)

Two problems, torque-free:
* pendulum (robots/pendulum.urdf), q0 = π/12 at rest, T = 10 s (≈ 5 periods). Truth: the exact
  solution sin(q/2) = k sn(K(k) − ω t | k²), k = sin(q0/2) (scipy.special.ellipj).
* lbr7 (robots/lbr7.urdf) hanging from a ceiling (gravity +z), a small swing, T = 2 s. Truth:
  quintic Hermite with N = 1600 (its own error ≈ 1e-14 by the measured h⁶ rate; DOP853 at
  rtol = atol = 1e-13 agrees to 2e-11, the floor of its accumulated round-off).

For each method we sweep its accuracy knob (N for hermite, rtol = atol for rk), measure the error
of x(T) (max over joints of |q − q*| and |q̇ − q̇*|), the wall time of the integration alone, the
steps (elements or accepted RK steps) per second and the dynamics calls (one hermite call is a
batch of m samples with derivatives; one rk call is one forward-dynamics sample). Then, for a few
target accuracies, the cheapest setting of each method that reaches it.
"""
from __future__ import annotations

# isort: off
import _blas_threads  # noqa: F401  (before numpy: one BLAS thread, as hoc_cli sets)
# isort: on
import argparse
import math
import time
from pathlib import Path

import numpy as np
from scipy.special import ellipj, ellipk

from hoc_cli.elements import HermiteMesh
from hoc_cli.model import load_robot
from hoc_cli.reference_integrator import simulate_reference
from hoc_cli.simulate import simulate_hermite
from hoc_cli.system import RobotSystem
from hoc_cli.torque import zero_torque

ROBOTS = Path(__file__).resolve().parent.parent / "robots"


def pendulum_problem():
    system = RobotSystem(load_robot(ROBOTS / "pendulum.urdf"))
    _, du_dq, _, M = system.id_derivatives(np.zeros((1, 1)), np.zeros((1, 1)), np.zeros((1, 1)))
    omega = math.sqrt(du_dq[0, 0, 0] / M[0, 0, 0])
    q0, T = math.pi / 12, 10.0
    k = math.sin(q0 / 2)
    K = ellipk(k * k)
    sn, cn, dn, _ = ellipj(K - omega * T, k * k)
    qT = 2 * math.asin(k * sn)
    dqT = -2 * k * omega * cn * dn / math.sqrt(1 - (k * sn) ** 2)  # d/dt of 2 asin(k sn(K − ωt))
    return "pendulum", system, np.array([q0]), np.zeros(1), T, (np.array([qT]), np.array([dqT]))


def arm_problem():
    system = RobotSystem(load_robot(ROBOTS / "lbr7.urdf", gravity=(0.0, 0.0, 9.81)))
    q0 = 0.3 * np.array([0.2, 0.4, -0.3, -0.5, 0.3, 0.5, -0.2])
    dq0 = 0.3 * np.array([0.2, -0.2, 0.3, 0.2, -0.3, 0.3, 0.4])
    T = 2.0
    truth = simulate_hermite(system, q0, dq0, zero_torque(7), HermiteMesh("quintic", T, 1600)).final_state()
    return "lbr7 (7-DOF)", system, q0, dq0, T, truth


def error(state, truth) -> float:
    return float(max(np.abs(state[0] - truth[0]).max(), np.abs(state[1] - truth[1]).max()))


def sweep(problem, Ns, rtols, orders):
    name, system, q0, dq0, T, truth = problem
    n = system.n
    rows = []
    for order in orders:
        for N in Ns[order]:
            started = time.perf_counter()
            r = simulate_hermite(system, q0, dq0, zero_torque(n), HermiteMesh(order, T, N))
            wall = time.perf_counter() - started
            rows.append(dict(problem=name, method=f"hermite {order}", setting=f"N={N}", steps=N, calls=r.evaluations,
                             wall=wall, error=error(r.final_state(), truth)))
    for rtol in rtols:
        started = time.perf_counter()
        r = simulate_reference(system, q0, dq0, zero_torque(n), T, rtol=rtol, atol=rtol)
        wall = time.perf_counter() - started
        rows.append(dict(problem=name, method="rk DOP853", setting=f"rtol={rtol:.0e}", steps=r.steps, calls=r.nfev,
                         wall=wall, error=error(r.final_state(), truth)))
    return rows


def print_sweep(rows) -> None:
    print(f"{'problem':<14}{'method':<18}{'setting':<13}{'steps':>7}{'dyn calls':>11}{'wall s':>9}"
          f"{'steps/s':>10}{'error x(T)':>12}")
    for r in rows:
        print(f"{r['problem']:<14}{r['method']:<18}{r['setting']:<13}{r['steps']:>7}{r['calls']:>11}{r['wall']:>9.3f}"
              f"{r['steps'] / r['wall']:>10.0f}{r['error']:>12.2e}")


def print_equal_accuracy(rows, targets) -> None:
    print("\nCheapest setting reaching each accuracy (wall time of the integration alone):")
    print(f"{'problem':<14}{'target':>8}  {'method':<18}{'setting':<13}{'wall s':>9}{'error x(T)':>12}")
    for problem in dict.fromkeys(r["problem"] for r in rows):
        for target in targets:
            for method in dict.fromkeys(r["method"] for r in rows):
                ok = [r for r in rows if r["problem"] == problem and r["method"] == method and r["error"] <= target]
                if ok:
                    best = min(ok, key=lambda r: r["wall"])
                    print(f"{problem:<14}{target:>8.0e}  {method:<18}{best['setting']:<13}{best['wall']:>9.3f}"
                          f"{best['error']:>12.2e}")
                else:
                    print(f"{problem:<14}{target:>8.0e}  {method:<18}{'(not reached)':<13}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer settings")
    args = parser.parse_args()
    rtols = [1e-6, 1e-8, 1e-10, 1e-12] if args.quick else [1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11, 1e-12, 1e-13]
    rows = []
    pend_N = {"quintic": [25, 50, 100, 200, 400], "cubic": [50, 100, 200, 400, 800, 1600]}
    arm_N = {"quintic": [25, 50, 100, 200, 400], "cubic": [50, 100, 200, 400, 800]}
    if args.quick:
        pend_N = {"quintic": [25, 100, 400], "cubic": [100, 400]}
        arm_N = {"quintic": [50, 200], "cubic": [200]}
    rows += sweep(pendulum_problem(), pend_N, rtols, ("quintic", "cubic"))
    rows += sweep(arm_problem(), arm_N, rtols, ("quintic", "cubic"))
    print_sweep(rows)
    print_equal_accuracy(rows, [1e-6, 1e-8, 1e-10])


if __name__ == "__main__":
    main()
