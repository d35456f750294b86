"""Why hoc preconditions: plain Polak-Ribière CG slows down as h shrinks; the banded preconditioner does not.

Run:  python benchmarks/bench_cg.py

The paper's validation problem (q̈ + q = u, T = π, x0 = (0, 1), x1 = (0, −1), cost ½∫u²) is a
quadratic in the Hermite coefficients whose Hessian has condition number growing like h⁻⁴. The
table gives iterations and cost+gradient evaluations to the stopping test for plain PR+ CG (the
paper's method, P = I) and for hoc's default (PR+ CG preconditioned by the banded Gauss-Newton /
Newton matrix), plus the measured condition number of the Hessian.
"""
from __future__ import annotations

import time

import numpy as np

from hoc_cli.elements import HermiteMesh
from hoc_cli.planner import plan
from hoc_cli.problem import ControlProblem
from hoc_cli.system import LinearOscillator


def hessian_condition(order: str, N: int) -> float:
    P = ControlProblem(LinearOscillator(), HermiteMesh(order, np.pi, N), [0.0], [1.0], [0.0], [-1.0], cost="torque")
    x = P.initial_guess()
    n = x.size
    H = np.empty((n, n))
    g0 = P.evaluate(x).grad
    for i in range(n):  # exact for a quadratic: columns of H are gradient differences
        e = np.zeros(n)
        e[i] = 1.0
        H[:, i] = P.evaluate(x + e).grad - g0
    w = np.linalg.eigvalsh(0.5 * (H + H.T))
    return float(w[-1] / w[0])


def main() -> None:
    print(f"{'order':8s} {'N':>4s} {'cond(H)':>10s} | {'plain PR CG: iters':>18s} {'evals':>6s} {'time':>8s} "
          f"| {'preconditioned: iters':>21s} {'evals':>6s} {'time':>8s}")
    for order in ("cubic", "quintic"):
        for N in (4, 8, 16, 32):
            mesh = HermiteMesh(order, np.pi, N)
            row = [f"{order:8s} {N:4d} {hessian_condition(order, N):10.2e}"]
            for pre in (False, True):
                t0 = time.perf_counter()
                r = plan(LinearOscillator(), mesh, [0.0], [1.0], [0.0], [-1.0], cost="torque",
                         precondition=pre, max_iter=20000, tol=1e-10)
                dt = time.perf_counter() - t0
                flag = "" if r.converged else "*"
                width = 18 if not pre else 21
                row.append(f"{str(r.optimizer.iterations) + flag:>{width}s} {r.optimizer.n_evals:6d} {dt:8.3f}")
            print(" | ".join(row))
    print("* = stopped without meeting the stopping test (line search stalled at the rounding level, or max_iter)")


if __name__ == "__main__":
    main()
