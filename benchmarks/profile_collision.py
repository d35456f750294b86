"""Where a collision-enforced plan's CPU time goes: the Panda problems of bench_collision.py planned in-process.

Run:  python benchmarks/profile_collision.py                 (problems 4, 6, 12 and 16: about 10 s)
      python benchmarks/profile_collision.py --problems 0-19

Each problem is planned as ``hoc plan TASK --json -q -o none`` in this process (a first plan, untimed, warms it up);
the script prints per problem the CPU time of the plan (``time.process_time``), its J, iterations, evaluations and
Newton matrices, then per level (N = 2, the coarse level; N = 8) the CPU time and calls of the parts of an inner
iteration: an evaluation of J + Φ and its gradient (the cost's samples, the collision rows, the joint limits'
penalty), a Newton matrix (the cost's Hessian sweep, the distances' curvature, the factorisation with its
modification), the first step's rows; the polish after a limits' round (its evaluation and Newton matrix are counted
in those lines too) and the limits' measure after each round (its exact check of the limits); the certificates and the
distances of every pair at the points (once an outer iteration); and the solve itself (``planner.plan``, what the
summary's ``wall_time_s`` times: loading the task and the report are outside it). The parts nest (an evaluation holds
its rows' and its cost's time; the joint limits' penalty is a term of the inner problem beside the evaluation, not in
it); CPU time on a shared machine varies with the load: compare runs made together, or instruction counts.
"""
from __future__ import annotations

# isort: off
import _blas_threads  # noqa: F401  (before numpy: one BLAS thread, as hoc_cli sets)
# isort: on
import argparse
import collections
import contextlib
import functools
import io
import json
import sys
import tempfile
import time
from pathlib import Path

import bench_collision

#: the parts timed: label → (owner, function name); an indented label is part of the one above it
PARTS = {
    "evaluation (J + Φ, gradient)": ("problem", "evaluate"),
    "  the cost's samples": ("problem", "sample_gradients"),
    "  the collision rows": ("terms", "evaluate"),
    "the joint limits' penalty (every call; beside the evaluation)": ("limits", "evaluate"),
    "Newton matrix": ("problem", "newton"),
    "  the cost's Hessian sweep": ("problem", "hessian_samples"),
    "  the distances' curvature": ("terms", "curvature_blocks"),
    "  the collision rows' Gauss-Newton blocks": ("terms", "newton_blocks"),
    "  factorisation (and modification)": ("problem", "positive_definite"),
    "first step: the collision rows": ("terms", "step_rows"),
    "first step: the limits' rows": ("step", "limit_rows"),
    "polish (one Newton step after a limits' round)": ("auglag", "polish"),
    "the limits' measure (after each round)": ("limit_term", "measure"),
    "  their exact check": ("augmented_lagrangian", "check_limits"),
    "certificate": ("enforce", "certify"),
    "distances of every pair at the points": ("enforce", "distances"),
    "the solve (planner.plan: wall_time_s)": ("planner", "plan"),
}


def _instrument(acc: dict, calls: collections.Counter) -> None:
    """Wrap the parts (module docstring) with CPU-time counters keyed by (part, level N)."""
    import hoc_cli.collision.constraint as constraint
    import hoc_cli.collision.enforce as enforce
    import hoc_cli.collision.step as step
    import hoc_cli.constraints.auglag as auglag
    import hoc_cli.constraints.augmented_lagrangian as augmented_lagrangian
    import hoc_cli.constraints.penalty as penalty
    import hoc_cli.planner as planner
    import hoc_cli.problem as problem

    def level(args) -> int | None:
        owner = args[0] if args else None
        for path in (("mesh",), ("points", "mesh"), ("rows", "mesh")):
            obj = owner
            for name in path:
                obj = getattr(obj, name, None)
            if obj is not None and hasattr(obj, "N"):
                return obj.N
        return None

    def wrap(owner, name: str, label: str) -> None:
        f = getattr(owner, name)

        @functools.wraps(f)
        def timed(*args, **kwargs):
            t = time.process_time()
            try:
                return f(*args, **kwargs)
            finally:
                key = (label, level(args))
                acc[key] += time.process_time() - t
                calls[key] += 1
        setattr(owner, name, timed)

    owners = {"problem": problem.ControlProblem, "terms": constraint.CollisionTerms, "limits": penalty.LimitTerms,
              "step": step, "enforce": enforce, "auglag": auglag, "limit_term": augmented_lagrangian.LimitTerm,
              "augmented_lagrangian": augmented_lagrangian, "planner": planner}
    for label, (owner, name) in PARTS.items():
        wrap(owners[owner], name, label)


def _plan(path: Path) -> dict:
    from hoc_cli.cli import app

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        try:
            app(["plan", str(path), "--json", "-q", "-o", "none"], standalone_mode=False)
        except SystemExit:
            pass
    return json.loads(out.getvalue())


def _indices(text: str) -> list[int]:
    out: list[int] = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b or a) + 1))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--problems", default="4,6,12,16", help="indices of bench_collision.py's problems (e.g. 0-19)")
    ap.add_argument("--N", type=int, default=8)
    args = ap.parse_args()
    idx = _indices(args.problems)
    docs = bench_collision.problems(max(idx) + 1, args.N)
    acc: dict = collections.defaultdict(float)
    calls: collections.Counter = collections.Counter()
    with tempfile.TemporaryDirectory() as tmp:
        paths = []
        for i in idx:
            paths.append(Path(tmp) / f"p{i:02d}.yaml")
            paths[-1].write_text(bench_collision._task_text(docs[i]))
        _plan(paths[0])  # warm-up: imports and caches
        _instrument(acc, calls)
        total = 0.0
        print(f"{'#':>3} {'CPU s':>6} {'J':>10} {'iterations':>10} {'evaluations':>11} {'Newton':>6}")
        for i, path in zip(idx, paths):
            t = time.process_time()
            s = _plan(path)
            cpu = time.process_time() - t
            total += cpu
            print(f"{i:>3} {cpu:>6.2f} {s['cost']:>10.4f} {s['iterations']:>10} {s['evaluations']:>11} {s['hessians']:>6}")
    print(f"CPU in all {total:.2f} s")
    print(f"{'part':<52} {'N':>3} {'CPU s':>7} {'calls':>6} {'ms a call':>9}")
    order = {label: k for k, label in enumerate(PARTS)}
    for (label, N), v in sorted(acc.items(), key=lambda kv: (kv[0][1] is None, kv[0][1] or 0, order[kv[0][0]])):
        print(f"{label:<52} {'-' if N is None else N:>3} {v:>7.2f} {calls[(label, N)]:>6} {1e3 * v / calls[(label, N)]:>9.2f}")


if __name__ == "__main__":
    sys.exit(main())
