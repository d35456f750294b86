"""hoc's collision-enforced plans on Panda problems among boxes, in the MotionBenchMaker style (issue 25).

Run:  python benchmarks/bench_collision.py              (3 problems, N = 8: about 1.5 minutes on 2 cores)
      python benchmarks/bench_collision.py --count 20 --N 16 --json collision.json
      python benchmarks/bench_collision.py --drake      (Drake's sampled constraint beside hoc)

Problems (seeded, reproducible): the Panda (example-robot-data, its SRDF's pairs off, fingers
locked at 0.02 m) over a table, with a wall standing between the start and the goal and 2 boxes on
the table at random; start and goal are reaches to the left and to the right of the wall, perturbed
at random and kept when every pair is at least 3 cm clear. T = 2 s, covariant cost, URDF limits.

Per problem: whether the minimum-jerk guess collides (hoc's distances at 1 kHz), ``hoc plan``'s
outcome (status, J, wall time, certified lower bound), and the clearance of the written plan at
1 kHz by coal with Pinocchio's kinematics (the same capsules, coal's distances: independent of
hoc's distance and certificate code; skipped without coal). Summary: success rate (converged and
certified), plan time median and 98th percentile, the smallest coal clearance over the successes
(it must be >= margin − 1e-9: no collision between samples).

``--drake`` (benchmark-only: ``pip install drake``): beside it, Drake's KinematicTrajectoryOptimization
with MinimumDistanceLowerBoundConstraint at 25 sampled points of the path, on the same capsules and
pairs (benchmarks/_drake_collision.py; its cost is the path length, not hoc's effort: compare the
clearance, not J), and its clearance at 1 kHz by hoc's distances: a sampled constraint can pass an
obstacle between its samples.
"""
from __future__ import annotations

# isort: off
import _blas_threads  # noqa: F401  (before numpy: one BLAS thread, as hoc_cli sets)
# isort: on
import argparse
import json
import sysconfig
import tempfile
from pathlib import Path

import numpy as np
import yaml
from typer.testing import CliRunner

from hoc_cli.cli import app

ERD = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix" / "share" / "example-robot-data" / "robots"
PANDA = ERD / "panda_description" / "urdf" / "panda.urdf"
SRDF = ERD / "panda_description" / "srdf" / "panda.srdf"
JOINTS = [f"panda_joint{i}" for i in range(1, 8)]
LEFT = np.array([-1.2, 0.4, 0.0, -1.8, 0.0, 2.2, 0.785])
RIGHT = np.array([1.2, 0.4, 0.0, -1.8, 0.0, 2.2, 0.785])
MARGIN = 0.01
START_CLEARANCE = 0.03


def _scene(rng) -> list[dict]:
    boxes = [{"name": "table", "box": {"size": [0.6, 1.4, 0.04]}, "position": [0.55, 0.0, 0.0]},
             {"name": "wall", "box": {"size": [float(rng.uniform(0.2, 0.35)), 0.04, float(rng.uniform(0.25, 0.4))]},
              "position": [float(rng.uniform(0.45, 0.6)), 0.0, 0.2]}]
    for i in range(2):
        side = 1 if i == 0 else -1
        boxes.append({"name": f"box{i}", "box": {"size": [float(v) for v in rng.uniform(0.05, 0.12, 3)]},
                      "position": [float(rng.uniform(0.45, 0.8)), float(side * rng.uniform(0.3, 0.6)), 0.1]})
    return boxes


def problems(count: int, N: int, seed: int = 0) -> list[dict]:
    """``count`` task documents whose start and goal are ``START_CLEARANCE`` clear (hoc's distances)."""
    from hoc_cli.collision.evaluate import distances
    from hoc_cli.io.robot import load_model
    from hoc_cli.io.task import load_task
    from hoc_cli.report.collision import task_collision

    rng = np.random.default_rng(seed)
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        while len(out) < count:
            q0 = LEFT + rng.normal(size=7) * 0.15
            q1 = RIGHT + rng.normal(size=7) * 0.15
            doc = {"robot": str(PANDA), "joints": JOINTS, "locked": {"panda_finger_joint1": 0.02},
                   "x0": {"q": [float(v) for v in q0]}, "x1": {"q": [float(v) for v in q1]}, "T": 2.0, "N": N,
                   "output": {"rate": 1000.0},
                   "collision": {"margin": MARGIN, "srdf": str(SRDF), "obstacles": _scene(rng)}}
            path = Path(tmp) / "task.yaml"
            path.write_text(yaml.safe_dump(doc, sort_keys=False))
            task = load_task(path, purpose="plan")
            model = load_model(task)
            scene = task_collision(task, model)
            if distances(model, scene, np.stack([q0, q1])).min() >= START_CLEARANCE:
                out.append(doc)
    return out


def _coal_clearance(doc: dict, csv_path: Path) -> float | None:
    """The smallest signed distance over the scene's pairs at every CSV sample by coal and Pinocchio (None without them)."""
    try:
        import coal
        import pinocchio as pin
    except ImportError:
        return None
    from hoc_cli.collision.scene import KIND_SELF
    from hoc_cli.io.robot import load_model
    from hoc_cli.io.task import load_task
    from hoc_cli.report.collision import task_collision

    path = csv_path.with_name("task.yaml")
    task = load_task(path, purpose="plan")
    model = load_model(task)
    scene = task_collision(task, model)
    full = pin.buildModelFromUrdf(str(PANDA))
    q_lock = pin.neutral(full)
    lock = [full.getJointId(n) for n in full.names if "finger" in n]
    for j in lock:
        q_lock[full.joints[j].idx_q] = 0.02
    pm = pin.buildReducedModel(full, lock, q_lock)
    data = pm.createData()
    robot = scene.robot
    shapes = []
    for p in range(robot.size):
        a, b, r = robot.a[p], robot.b[p], float(robot.radius[p])
        d = b - a
        L = float(np.linalg.norm(d))
        z = d / L if L > 0 else np.array([0.0, 0, 1])
        x = np.cross(z, [1.0, 0, 0] if abs(z[0]) < 0.9 else [0, 1.0, 0])
        x /= np.linalg.norm(x)
        shapes.append((pm.getFrameId(robot.links[p]), coal.Sphere(r) if L == 0 else coal.Capsule(r, L),
                       pin.SE3(np.stack([x, np.cross(z, x), z], axis=1), (a + b) / 2)))
    obstacles = [(coal.Box(*(2 * o.primitive.half)), coal.Transform3s(o.primitive.rotation, o.primitive.center))
                 for o in scene.obstacles]
    import csv

    rows = list(csv.DictReader(csv_path.open()))
    qs = np.array([[float(row[f"q.{j}"]) for j in JOINTS] for row in rows])
    req = coal.DistanceRequest()
    req.enable_signed_distance = True
    worst = np.inf
    for q in qs:
        pin.framesForwardKinematics(pm, data, q)
        placed = []
        for frame, shape, local in shapes:
            M = data.oMf[frame] * local
            placed.append(coal.Transform3s(M.rotation, M.translation))
        for k in range(scene.size):
            a = int(scene.prim[k])
            if scene.kind[k] == KIND_SELF:
                other, T2 = shapes[int(scene.other[k])][1], placed[int(scene.other[k])]
            else:
                other, T2 = obstacles[int(scene.other[k])]
            res = coal.DistanceResult()
            coal.distance(shapes[a][1], placed[a], other, T2, req, res)
            worst = min(worst, res.min_distance)
    return float(worst)


def run(doc: dict, workdir: Path) -> dict:
    from hoc_cli.collision.evaluate import distances
    from hoc_cli.elements import HermiteMesh
    from hoc_cli.io.robot import load_model
    from hoc_cli.io.task import load_task
    from hoc_cli.problem import minimum_jerk_guess
    from hoc_cli.report.collision import task_collision

    path = workdir / "task.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    task = load_task(path, purpose="plan")
    model = load_model(task)
    scene = task_collision(task, model)
    mesh = HermiteMesh("quintic", 2.0, doc["N"])
    z = np.zeros(7)
    C = minimum_jerk_guess(mesh, np.array(doc["x0"]["q"]), z, np.array(doc["x1"]["q"]), z)
    guess = float(distances(model, scene, mesh.evaluate(C, np.linspace(0, 2.0, 2001))).min())
    r = CliRunner().invoke(app, ["plan", str(path), "--json", "-q", "-o", str(workdir / "out.csv")])
    s = json.loads(r.stdout)
    c = s["min_clearance"]
    ok = r.exit_code == 0 and s["converged"] and c["certified"]
    return {"guess_clearance": guess, "exit": r.exit_code, "status": s["status"], "converged": s["converged"],
            "certified": c["certified"], "J": s["cost"], "time_s": s["wall_time_s"], "lower_bound": c["lower_bound"],
            "start": (s.get("collision_enforce") or {}).get("start"), "success": ok,
            "coal_1khz": _coal_clearance(doc, workdir / "out.csv") if ok else None}


def drake_row(doc: dict, workdir: Path) -> dict:
    """Drake's plan of the same problem: success, solve time, its smallest distance at 1 kHz (hoc's distances)."""
    from _drake_collision import drake_plan

    from hoc_cli.collision.evaluate import distances
    from hoc_cli.io.robot import load_model
    from hoc_cli.io.task import load_task
    from hoc_cli.report.collision import task_collision

    path = workdir / "task.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    task = load_task(path, purpose="plan")
    model = load_model(task)
    scene = task_collision(task, model)
    ok, elapsed, Q, _ = drake_plan(PANDA.read_text(), scene, np.array(doc["x0"]["q"]), np.array(doc["x1"]["q"]),
                                   2.0, MARGIN)
    return {"success": ok, "time_s": elapsed, "clearance_1khz": float(distances(model, scene, Q).min())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--count", type=int, default=3)
    ap.add_argument("--N", type=int, default=8)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", type=Path)
    ap.add_argument("--drake", action="store_true", help="Drake's sampled minimum-distance plan beside each")
    args = ap.parse_args()
    docs = problems(args.count, args.N, args.seed)
    results = []
    print(f"{'#':>3} {'guess d':>8} {'status':>11} {'J':>10} {'time s':>7} {'proven >=':>10} {'coal 1 kHz':>10}  start")
    with tempfile.TemporaryDirectory() as tmp:
        for i, doc in enumerate(docs):
            r = run(doc, Path(tmp))
            results.append(r)
            coal = "-" if r["coal_1khz"] is None else f"{r['coal_1khz']:.5f}"
            drake = ""
            if args.drake:
                r["drake"] = d = drake_row(doc, Path(tmp))
                drake = f"  | Drake {'ok' if d['success'] else 'failed'} {d['time_s']:.2f} s, 1 kHz {d['clearance_1khz']:.5f}"
            print(f"{i:>3} {r['guess_clearance']:>8.4f} {r['status']:>11} {r['J']:>10.4f} {r['time_s']:>7.2f} "
                  f"{r['lower_bound']:>10.5f} {coal:>10}  {r['start']}{drake}", flush=True)
    ok = [r for r in results if r["success"]]
    times = np.array([r["time_s"] for r in results])
    coal = [r["coal_1khz"] for r in ok if r["coal_1khz"] is not None]
    print(f"success {len(ok)}/{len(results)} (converged and certified); guesses in collision "
          f"{sum(r['guess_clearance'] < MARGIN for r in results)}/{len(results)}; plan time median "
          f"{np.median(times):.2f} s, 98th percentile {np.percentile(times, 98):.2f} s; smallest coal clearance at 1 kHz "
          f"over the successes {min(coal) if coal else float('nan'):.5f} m (margin {MARGIN} m)")
    if args.drake:
        dr = [r["drake"] for r in results]
        dok = [d for d in dr if d["success"]]
        print(f"Drake: success {len(dok)}/{len(dr)} (SNOPT's own test), plan time median "
              f"{np.median([d['time_s'] for d in dr]):.2f} s; of its successes, below the margin between its samples "
              f"{sum(d['clearance_1khz'] < MARGIN - 1e-9 for d in dok)}, in collision (< 0) "
              f"{sum(d['clearance_1khz'] < 0 for d in dok)}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
