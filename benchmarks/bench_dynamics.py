"""Time per sample of hoc's batched dynamics beside Pinocchio called once per sample from Python.

Run:  python benchmarks/bench_dynamics.py [URDF] [--repeat R]

For robots/lbr7.urdf (7 DOF) at K = 1, 100, 1000, 10000 random samples it prints the time per sample
of batched inverse dynamics (RNEA), the mass matrix, and inverse dynamics with its derivatives
(∂u/∂q, ∂u/∂q̇, M), and of the vector-Jacobian product λᵀ∂u/∂(q, q̇), next to pinocchio.rnea,
pinocchio.crba and pinocchio.computeRNEADerivatives called in a Python loop over the same samples,
in the same run. ratio = hoc / Pinocchio (below 1: hoc is faster per sample). Best of R repeats.
"""
from __future__ import annotations

# isort: off
import _blas_threads  # noqa: F401  (before numpy: one BLAS thread, as hoc_cli sets)
# isort: on
import argparse
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hoc_cli import dynamics as D  # noqa: E402
from hoc_cli.model import load_robot  # noqa: E402


def best_time(fn, repeat: int, min_time: float = 0.05) -> float:
    """Best wall time (s) of one call of ``fn`` over ``repeat`` rounds of enough calls to last min_time."""
    calls = 1
    while True:
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        if time.perf_counter() - t0 >= min_time:
            break
        calls *= 2
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        best = min(best, (time.perf_counter() - t0) / calls)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("urdf", nargs="?", default=str(ROOT / "robots" / "lbr7.urdf"))
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 100, 1000, 10000])
    args = parser.parse_args()

    import pinocchio as pin

    model = load_robot(args.urdf)
    pm = pin.buildModelFromUrdf(args.urdf)
    if pm.nq != model.n or pm.nv != model.n:
        raise SystemExit("this benchmark needs a URDF without continuous or mimic joints")
    pm.gravity.linear[:] = model.gravity
    pd = pm.createData()
    rng = np.random.default_rng(0)

    print(f"robot {model.name} ({args.urdf}), n = {model.n}; numpy {np.__version__}, "
          f"pinocchio {pin.__version__}, Python {platform.python_version()}, {platform.machine()}")
    print("time per sample in µs (hoc: one batched call over K samples; Pinocchio: a Python loop of K calls)")
    header = (f"{'K':>6} | {'ID hoc':>8} {'pin':>6} {'ratio':>6} | {'M hoc':>8} {'pin':>6} {'ratio':>6} | "
              f"{'ID+deriv hoc':>12} {'pin':>6} {'ratio':>6} | {'VJP hoc':>8}")
    print(header)
    print("-" * len(header))
    for K in args.sizes:
        q = rng.uniform(-np.pi, np.pi, (K, model.n))
        dq, ddq, lam = (rng.standard_normal((K, model.n)) for _ in range(3))
        rows = [np.ascontiguousarray(x) for x in (q, dq, ddq)]
        qs, dqs, ddqs = ([r[k].copy() for k in range(K)] for r in rows)

        def pin_rnea():
            for k in range(K):
                pin.rnea(pm, pd, qs[k], dqs[k], ddqs[k])

        def pin_crba():
            for k in range(K):
                pin.crba(pm, pd, qs[k])

        def pin_deriv():
            for k in range(K):
                pin.computeRNEADerivatives(pm, pd, qs[k], dqs[k], ddqs[k])

        us = 1e6 / K
        t_id = best_time(lambda: D.inverse_dynamics(model, q, dq, ddq), args.repeat) * us
        t_pid = best_time(pin_rnea, args.repeat) * us
        t_m = best_time(lambda: D.mass_matrix(model, q), args.repeat) * us
        t_pm = best_time(pin_crba, args.repeat) * us
        t_d = best_time(lambda: D.id_derivatives(model, q, dq, ddq), args.repeat) * us
        t_pd = best_time(pin_deriv, args.repeat) * us
        t_v = best_time(lambda: D.id_vjp(model, q, dq, ddq, lam), args.repeat) * us
        print(f"{K:>6} | {t_id:8.3f} {t_pid:6.3f} {t_id / t_pid:6.2f} | {t_m:8.3f} {t_pm:6.3f} {t_m / t_pm:6.2f} | "
              f"{t_d:12.3f} {t_pd:6.3f} {t_d / t_pd:6.2f} | {t_v:8.3f}")


if __name__ == "__main__":
    main()
