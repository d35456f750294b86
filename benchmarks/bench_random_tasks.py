"""hoc plan on random rest-to-rest tasks of every shipped robot: iterations, evaluations, time, J.

Run:  python benchmarks/bench_random_tasks.py [--N 16] [--T 1.5] [--seeds 4]

For each shipped URDF and seed, q0 and q1 are drawn uniformly in the middle 80 % of each joint's
range (±2 rad for unbounded joints), both at rest; the covariant cost is minimised with cubic and
quintic elements from the minimum-jerk guess. The tasks are large moves and non-convex, so the
local optimum reached depends on the optimiser's path: the totals (iterations, time, ΣJ) compare
optimiser variants (run it on two commits), not hoc against a peer.
"""
from __future__ import annotations

# isort: off
import _blas_threads  # noqa: F401  (before numpy: one BLAS thread, as hoc_cli sets)
# isort: on
import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import zlib  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from hoc_cli.elements import HermiteMesh  # noqa: E402
from hoc_cli.model import load_robot  # noqa: E402
from hoc_cli.planner import plan  # noqa: E402
from hoc_cli.system import RobotSystem  # noqa: E402

ROBOTS = Path(__file__).resolve().parent.parent / "robots"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--N", type=int, default=16)
    ap.add_argument("--T", type=float, default=1.5)
    ap.add_argument("--seeds", type=int, default=4)
    args = ap.parse_args()
    total_t = total_it = total_ev = 0.0
    total_J = 0.0
    failed = 0
    print(f"{'robot':16s} {'seed':>4s} {'order':7s} {'J':>16s} {'iters':>5s} {'evals':>5s} {'time [ms]':>9s} converged")
    for urdf in sorted(ROBOTS.glob("*.urdf")):
        model = load_robot(urdf)
        system = RobotSystem(model)
        for seed in range(args.seeds):
            rng = np.random.default_rng(seed + zlib.crc32(urdf.name.encode()))
            lo = np.where(np.isfinite(model.lower), model.lower, -2.0)
            hi = np.where(np.isfinite(model.upper), model.upper, 2.0)
            q0, q1 = (lo + (hi - lo) * rng.uniform(0.1, 0.9, model.n) for _ in range(2))
            rest = np.zeros(model.n)
            for order in ("quintic", "cubic"):
                r = plan(system, HermiteMesh(order, args.T, args.N), q0, rest, q1, rest)
                total_t += r.wall_time_s
                total_it += r.optimizer.iterations
                total_ev += r.optimizer.n_evals
                total_J += r.J
                failed += not r.converged
                print(f"{urdf.name:16s} {seed:4d} {order:7s} {r.J:16.10f} {r.optimizer.iterations:5d} "
                      f"{r.optimizer.n_evals:5d} {1e3 * r.wall_time_s:9.1f} {r.converged}")
    print(f"total: {total_it:.0f} iterations, {total_ev:.0f} evaluations, {total_t:.2f} s, sum of J {total_J:.4f}, "
          f"{failed} not converged")


if __name__ == "__main__":
    main()
