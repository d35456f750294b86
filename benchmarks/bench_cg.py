"""Why hoc preconditions: plain Polak-Ribière CG slows down as h shrinks; the banded preconditioner does not.

Run:  python benchmarks/bench_cg.py

The oscillator q̈ + q = u, T = π, x0 = (0, 0), x1 = (1, 0), cost ½∫u² (exact optimum J* = 1/π, so
the relative stopping test is reachable) is a quadratic in the Hermite coefficients whose Hessian
has a condition number growing like h⁻⁴. The
table gives iterations and cost+gradient evaluations to the stopping test for plain PR+ CG (the
paper's method, P = I) and for hoc's default (PR+ CG preconditioned by the banded Gauss-Newton /
Newton matrix), plus the measured condition number of the Hessian.
"""
from __future__ import annotations

# isort: off
import _blas_threads  # noqa: F401  (before numpy: one BLAS thread, as hoc_cli sets)
# isort: on
import time

import numpy as np

from hoc_cli.elements import HermiteMesh
from hoc_cli.planner import plan
from hoc_cli.problem import ControlProblem
from hoc_cli.system import LinearOscillator

BOUNDARY = ([0.0], [0.0], [1.0], [0.0])  # q0, q̇0, q1, q̇1


def hessian_condition(order: str, N: int) -> float:
    P = ControlProblem(LinearOscillator(), HermiteMesh(order, np.pi, N), *BOUNDARY, cost="torque")
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


def iterations_to(history, J_ref: float, rel: float) -> str:
    """First iteration whose J is within rel·|J_ref| of J_ref, or '—' if none."""
    for log in history:
        if log.J - J_ref <= rel * abs(J_ref):
            return str(log.iteration)
    return "—"


def main() -> None:
    print("iterations of PR+ CG until J is within 1e-6 / 1e-10 (relative) of the discrete optimum J_N*")
    print(f"{'order':8s} {'N':>4s} {'unknowns':>8s} {'cond(H)':>10s} | {'plain PR CG (P = I)':>22s} {'time':>7s} "
          f"| {'preconditioned (hoc)':>22s} {'time':>7s}")
    for order in ("cubic", "quintic"):
        for N in (4, 8, 16, 32):
            mesh = HermiteMesh(order, np.pi, N)
            size = (N + 1) * mesh.m - 4
            runs = {}
            for pre in (True, False):
                t0 = time.perf_counter()
                r = plan(LinearOscillator(), mesh, *BOUNDARY, cost="torque", precondition=pre,
                         max_iter=20000, tol=1e-14)
                runs[pre] = (r, time.perf_counter() - t0)
            J_ref = runs[True][0].J
            cells = []
            for pre in (False, True):
                r, dt = runs[pre]
                cells.append(f"{iterations_to(r.optimizer.history, J_ref, 1e-6):>10s} / "
                             f"{iterations_to(r.optimizer.history, J_ref, 1e-10):>9s} {dt:7.3f}")
            print(f"{order:8s} {N:4d} {size:8d} {hessian_condition(order, N):10.2e} | " + " | ".join(cells))
    print("'—': not reached within 20000 iterations (rounding: the gradient's noise grows with cond(H))")


if __name__ == "__main__":
    main()
