"""hoc's collision-enforced plans on Panda problems in cluttered scenes, in the MotionBenchMaker style (issue 25).

Run:  python benchmarks/bench_collision.py              (4 problems, one per scene family: about a minute)
      python benchmarks/bench_collision.py --count 20 --drake --json collision.json   (docs/collision.md §6)

Problems (seeded, reproducible): the Panda (example-robot-data, its SRDF's pairs off, fingers
locked at 0.02 m) over a table, the scene families in turn (``FAMILIES``): ``wall`` (a wall between
a start reaching to one side and a goal reaching to the other, and 2 boxes), ``shelf`` (the goal's
hand level in a compartment built round it: boards below and above, a back and two sides),
``cage`` (that compartment made of bars, a bar across the bottom of its opening) and ``clutter``
(a block where the straight path's midpoint puts the hand, and 4 boxes). Start and goal are
perturbed at random, within the joint limits, and kept when every pair is at least 3 cm clear.
T = 2 s, covariant cost, URDF limits, margin 1 cm.

Per problem: the minimum-jerk guess's clearance (hoc's distances at 1 kHz), ``hoc plan``'s outcome
in a subprocess stopped after ``--timeout`` s (status, J, wall time, certified lower bound), and the
clearance of the written plan at 1 kHz by coal with Pinocchio's kinematics (the same capsules,
coal's distances: independent of hoc's distance and certificate code; skipped without coal).
Summary: success rate (converged and certified), plan time median and 98th percentile (the summary's
``wall_time_s``; beside it the median CPU time of the ``hoc plan`` subprocess, start included: the
machine is shared), how many
successes come below the margin between samples by coal (0 when the certificate holds).

``--drake`` (benchmark-only: ``pip install drake``): beside it, Drake's KinematicTrajectoryOptimization
with MinimumDistanceLowerBoundConstraint at 25 sampled points of the path, on the same capsules and
pairs (benchmarks/_drake_collision.py; its cost is the path length, not hoc's effort: compare the
clearance, not J), its plan measured by coal at 1 kHz too: a sampled constraint can pass an
obstacle between its samples. The ratios hoc/Drake of success and of the time's median and 98th
percentile close the report.
"""
from __future__ import annotations

# isort: off
import _blas_threads  # noqa: F401  (before numpy: one BLAS thread, as hoc_cli sets)
# isort: on
import argparse
import json
import resource
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

import numpy as np
import yaml

ERD = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix" / "share" / "example-robot-data" / "robots"
PANDA = ERD / "panda_description" / "urdf" / "panda.urdf"
SRDF = ERD / "panda_description" / "srdf" / "panda.srdf"
JOINTS = [f"panda_joint{i}" for i in range(1, 8)]
LEFT = np.array([-1.2, 0.4, 0.0, -1.8, 0.0, 2.2, 0.785])
RIGHT = np.array([1.2, 0.4, 0.0, -1.8, 0.0, 2.2, 0.785])
MARGIN = 0.01
START_CLEARANCE = 0.03


FAMILIES = ("wall", "shelf", "cage", "clutter")
TABLE = {"name": "table", "box": {"size": [0.6, 1.4, 0.04]}, "position": [0.55, 0.0, 0.0]}
DISTAL = ("panda_link6", "panda_link7", "panda_hand", "panda_leftfinger", "panda_rightfinger")
FOREARM = ("panda_link5",)
REACH = np.array([0.0, 1.0, 0.0, -0.8, 0.0, 3.0, 0.785])  # the hand level, pointing ahead over the table


def _box(name: str, size, center, yaw: float = 0.0) -> dict:
    """A box obstacle: full sides ``size`` (m) in a frame turned by ``yaw`` about z, centred at ``center``."""
    return {"name": name, "box": {"size": [float(v) for v in size]}, "position": [float(v) for v in center],
            "orientation": [float(np.cos(yaw / 2)), 0.0, 0.0, float(np.sin(yaw / 2))]}


def _extent(ends: tuple, yaw: float) -> np.ndarray:
    """(3, 2) the box [lo, hi] along depth u, lateral v and z that holds the capsules ``ends`` = (a, b, r)
    of the hand's links, in the frame turned by ``yaw`` about z.
    """
    a, b, r = ends
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.array([[c, s, 0], [-s, c, 0], [0, 0, 1.0]])  # world → (u, v, z)
    pts = np.concatenate([a @ R.T, b @ R.T])
    rr = np.concatenate([r, r])[:, None]
    return np.stack([(pts - rr).min(axis=0), (pts + rr).max(axis=0)], axis=1)


def _compartment(rng, ends, arm, yaw: float, *, front: bool) -> list[dict]:
    """A shelf compartment round the hand's links (open towards the robot: boards below and above, a back, two
    sides, gaps 4–7 cm), its open face 3 cm beyond the forearm (``arm``: its capsules), standing on the table on
    its side panels; with ``front`` a cage: the back and sides are bars (corner posts, two rails a side) and a
    bar lies across the bottom of the opening, so the hand must come in over it.
    """
    box = _extent(ends, yaw)
    g = rng.uniform(0.04, 0.07, 5)
    t = 0.02
    u0, u1 = max(box[0, 0] - 0.02, _extent(arm, yaw)[0, 1] + 0.03), box[0, 1] + g[0]
    v0, v1 = box[1, 0] - g[1], box[1, 1] + g[2]
    z0, z1 = box[2, 0] - g[3], box[2, 1] + g[4]
    depth, width = u1 - u0, v1 - v0 + 2 * t
    uc, vc = (u0 + u1) / 2, (v0 + v1) / 2
    c, s = np.cos(yaw), np.sin(yaw)

    def world(u, v, z):
        return [u * c - v * s, u * s + v * c, z]

    top = z1 + t
    out = [_box("shelf_bottom", [depth, width, t], world(uc, vc, z0 - t / 2), yaw),
           _box("shelf_top", [depth, width, t], world(uc, vc, z1 + t / 2), yaw)]
    if not front:
        return out + [_box("shelf_back", [t, width, top], world(u1 + t / 2, vc, top / 2), yaw),
                      _box("shelf_left", [depth, t, top], world(uc, v1 + t / 2, top / 2), yaw),
                      _box("shelf_right", [depth, t, top], world(uc, v0 - t / 2, top / 2), yaw)]
    # a cage of 2 cm bars: corner posts, two rails along the back and each side, a lip across the opening
    for i, (u, v) in enumerate([(u0, v0), (u0, v1), (u1, v0), (u1, v1)]):
        out.append(_box(f"cage_post{i}", [t, t, top], world(u + t / 2 * np.sign(u - uc), v + t / 2 * np.sign(v - vc),
                                                            top / 2), yaw))
    for k, z in enumerate((z0 + (z1 - z0) / 3, z0 + 2 * (z1 - z0) / 3)):
        out.append(_box(f"cage_back{k}", [t, width, t], world(u1 + t / 2, vc, z), yaw))
        out.append(_box(f"cage_left{k}", [depth, t, t], world(uc, v1 + t / 2, z), yaw))
        out.append(_box(f"cage_right{k}", [depth, t, t], world(uc, v0 - t / 2, z), yaw))
    out.append(_box("cage_lip", [t, width, t], world(u0 + t / 2, vc, z0 + t / 2), yaw))
    return out


def _candidate(rng, family: str, capsules) -> tuple[np.ndarray, np.ndarray, list[dict]]:
    """One draw of (q0, q1, obstacles) for ``family``; ``capsules(q, links=DISTAL)`` gives (a, b, r) of the links'
    capsules at q.
    """
    side = rng.choice([-1.0, 1.0])
    if family in ("wall", "clutter"):
        q0 = LEFT + rng.normal(size=7) * 0.15
        q1 = RIGHT + rng.normal(size=7) * 0.15
        if side < 0:
            q0, q1 = q1, q0
    else:  # the goal in a compartment ahead, the start off to one side
        q1 = REACH + rng.normal(size=7) * 0.08
        q1[0] = rng.uniform(-0.6, 0.6)
        q0 = (LEFT if side > 0 else RIGHT) + rng.normal(size=7) * 0.15
    obstacles = [dict(TABLE)]
    if family == "wall":
        obstacles.append(_box("wall", [rng.uniform(0.2, 0.35), 0.04, rng.uniform(0.25, 0.4)],
                              [rng.uniform(0.45, 0.6), 0.0, 0.2]))
        for i in range(2):
            s = 1 if i == 0 else -1
            obstacles.append(_box(f"box{i}", rng.uniform(0.05, 0.12, 3),
                                  [rng.uniform(0.45, 0.8), s * rng.uniform(0.3, 0.6), 0.1]))
    elif family == "clutter":  # boxes on the table, one where the straight path's midpoint holds the hand
        a, b, _ = capsules((q0 + q1) / 2)
        mid = (a.mean(axis=0) + b.mean(axis=0)) / 2
        size = rng.uniform(0.1, 0.2, 3)
        size[2] = max(size[2], mid[2] + 0.05)
        obstacles.append(_box("block", size, [mid[0], mid[1], size[2] / 2], rng.uniform(-0.5, 0.5)))
        for i in range(4):
            size = rng.uniform(0.05, 0.15, 3)
            obstacles.append(_box(f"box{i}", size, [rng.uniform(0.35, 0.8), rng.uniform(-0.6, 0.6), size[2] / 2],
                                  rng.uniform(-np.pi, np.pi)))
    else:
        a, b, _ = capsules(q1)
        hand = (a.mean(axis=0) + b.mean(axis=0)) / 2
        obstacles += _compartment(rng, capsules(q1), capsules(q1, FOREARM), float(np.arctan2(hand[1], hand[0])),
                                  front=family == "cage")
    return q0, q1, obstacles


def problems(count: int, N: int, seed: int = 0) -> list[dict]:
    """``count`` task documents, the families in turn, whose start and goal are ``START_CLEARANCE`` clear
    (hoc's distances) and within the joint limits.
    """
    from hoc_cli.collision.evaluate import distances, world_capsules
    from hoc_cli.io.robot import load_model
    from hoc_cli.io.task import load_task
    from hoc_cli.report.collision import task_collision

    rng = np.random.default_rng(seed)
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "task.yaml"
        base = {"robot": str(PANDA), "joints": JOINTS, "locked": {"panda_finger_joint1": 0.02},
                "x0": {"q": LEFT.tolist()}, "x1": {"q": RIGHT.tolist()}, "T": 2.0, "N": N,
                "output": {"rate": 1000.0}, "collision": {"margin": MARGIN, "srdf": str(SRDF), "obstacles": [TABLE]}}
        path.write_text(yaml.safe_dump(base, sort_keys=False))
        task = load_task(path, purpose="plan")
        model = load_model(task)
        robot = task_collision(task, model).robot
        lo, hi = model.lower + 0.05, model.upper - 0.05

        def capsules(q, links=DISTAL):
            from types import SimpleNamespace
            which = np.array([name in links for name in robot.links])
            a, b = world_capsules(model, SimpleNamespace(robot=robot), np.asarray(q)[None])
            return a[0, which], b[0, which], robot.radius[which]

        while len(out) < count:
            family = FAMILIES[len(out) % len(FAMILIES)]
            q0, q1, obstacles = _candidate(rng, family, capsules)
            if not (np.all((q0 > lo) & (q0 < hi)) and np.all((q1 > lo) & (q1 < hi))):
                continue
            doc = dict(base, x0={"q": [float(v) for v in q0]}, x1={"q": [float(v) for v in q1]},
                       collision=dict(base["collision"], obstacles=obstacles))
            doc["family"] = family
            path.write_text(_task_text(doc))
            task = load_task(path, purpose="plan")
            scene = task_collision(task, model)
            if distances(model, scene, np.stack([q0, q1])).min() >= START_CLEARANCE:
                out.append(doc)
    return out


def _task_text(doc: dict) -> str:
    """The task file of a problem (its ``family`` left out)."""
    return yaml.safe_dump({k: v for k, v in doc.items() if k != "family"}, sort_keys=False)


def _csv_q(csv_path: Path) -> np.ndarray:
    """The joint positions (K, 7) of a plan's CSV."""
    import csv

    rows = list(csv.DictReader(csv_path.open()))
    return np.array([[float(row[f"q.{j}"]) for j in JOINTS] for row in rows])


def _coal_clearance(doc: dict, qs: np.ndarray, workdir: Path) -> float | None:
    """The smallest signed distance over the scene's pairs at every configuration qs (K, 7) by coal and Pinocchio
    (None without them).
    """
    try:
        import coal
        import pinocchio as pin
    except ImportError:
        return None
    from hoc_cli.collision.scene import KIND_SELF
    from hoc_cli.io.robot import load_model
    from hoc_cli.io.task import load_task
    from hoc_cli.report.collision import task_collision

    path = workdir / "task.yaml"
    path.write_text(_task_text(doc))
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


def run(doc: dict, workdir: Path, timeout: float) -> dict:
    """``hoc plan`` on one problem (a subprocess, stopped after ``timeout`` s: a failure), the guess's clearance, the
    plan's clearance at 1 kHz by coal.
    """
    from hoc_cli.collision.evaluate import distances
    from hoc_cli.elements import HermiteMesh
    from hoc_cli.io.robot import load_model
    from hoc_cli.io.task import load_task
    from hoc_cli.problem import minimum_jerk_guess
    from hoc_cli.report.collision import task_collision

    path = workdir / "task.yaml"
    path.write_text(_task_text(doc))
    task = load_task(path, purpose="plan")
    model = load_model(task)
    scene = task_collision(task, model)
    mesh = HermiteMesh("quintic", 2.0, doc["N"])
    z = np.zeros(7)
    C = minimum_jerk_guess(mesh, np.array(doc["x0"]["q"]), z, np.array(doc["x1"]["q"]), z)
    guess = float(distances(model, scene, mesh.evaluate(C, np.linspace(0, 2.0, 2001))).min())
    out = workdir / "out.csv"
    out.unlink(missing_ok=True)
    hoc = Path(sys.executable).with_name("hoc")
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    try:
        r = subprocess.run([str(hoc), "plan", str(path), "--json", "-q", "-o", str(out)], capture_output=True,
                           text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"guess_clearance": guess, "exit": None, "status": "timeout", "converged": False, "certified": False,
                "J": None, "time_s": timeout, "cpu_s": None, "lower_bound": None, "start": None, "success": False, "coal_1khz": None}
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime  # the subprocess's, its start included
    s = json.loads(r.stdout)
    c = s["min_clearance"]
    ok = r.returncode == 0 and s["converged"] and c["certified"]
    return {"guess_clearance": guess, "exit": r.returncode, "status": s["status"], "converged": s["converged"],
            "certified": c["certified"], "J": s["cost"], "time_s": s["wall_time_s"], "cpu_s": cpu,
            "lower_bound": c["lower_bound"],
            "start": (s.get("collision_enforce") or {}).get("start"), "success": ok,
            "coal_1khz": _coal_clearance(doc, _csv_q(out), workdir) if out.exists() else None}


def drake_row(doc: dict, workdir: Path) -> dict:
    """Drake's plan of the same problem: success, solve time, its smallest distance at 1 kHz (hoc's and coal's)."""
    import logging

    from _drake_collision import drake_plan

    logging.getLogger("drake").setLevel(logging.ERROR)  # its URDF parser's notes on tags it ignores

    from hoc_cli.collision.evaluate import distances
    from hoc_cli.io.robot import load_model
    from hoc_cli.io.task import load_task
    from hoc_cli.report.collision import task_collision

    path = workdir / "task.yaml"
    path.write_text(_task_text(doc))
    task = load_task(path, purpose="plan")
    model = load_model(task)
    scene = task_collision(task, model)
    ok, elapsed, Q, _ = drake_plan(PANDA.read_text(), scene, np.array(doc["x0"]["q"]), np.array(doc["x1"]["q"]),
                                   2.0, MARGIN)
    return {"success": ok, "time_s": elapsed, "clearance_1khz": float(distances(model, scene, Q).min()),
            "coal_1khz": _coal_clearance(doc, Q, workdir)}


def _fmt(v, spec: str) -> str:
    return "-" if v is None else format(v, spec)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--count", type=int, default=4)
    ap.add_argument("--N", type=int, default=8)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--timeout", type=float, default=120.0, help="s per hoc plan (then counted as a failure)")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--drake", action="store_true", help="Drake's sampled minimum-distance plan beside each")
    args = ap.parse_args()
    docs = problems(args.count, args.N, args.seed)
    results = []
    head = f"{'#':>3} {'scene':>7} {'guess d':>8} {'status':>13} {'J':>9} {'time s':>7} {'proven >=':>9} {'coal 1 kHz':>10}"
    print(head + ("  | Drake: ok  time s  coal 1 kHz" if args.drake else ""))
    with tempfile.TemporaryDirectory() as tmp:
        for i, doc in enumerate(docs):
            r = run(doc, Path(tmp), args.timeout)
            r["family"] = doc["family"]
            results.append(r)
            drake = ""
            if args.drake:
                r["drake"] = d = drake_row(doc, Path(tmp))
                drake = f"  | {'yes' if d['success'] else 'no':>8} {d['time_s']:>7.2f} {_fmt(d['coal_1khz'], '10.5f')}"
            print(f"{i:>3} {doc['family']:>7} {r['guess_clearance']:>8.4f} {r['status']:>13} {_fmt(r['J'], '9.3f')} "
                  f"{r['time_s']:>7.2f} {_fmt(r['lower_bound'], '9.5f')} {_fmt(r['coal_1khz'], '10.5f')}{drake}", flush=True)
    n = len(results)
    ok = [r for r in results if r["success"]]
    times = np.array([r["time_s"] for r in results])
    coal = [r["coal_1khz"] for r in ok if r["coal_1khz"] is not None]
    between = sum(c < MARGIN - 1e-9 for c in coal)
    print(f"hoc: success {len(ok)}/{n} = {100 * len(ok) / n:.0f} % (converged and certified); guesses in collision "
          f"{sum(r['guess_clearance'] < 0 for r in results)}/{n}; plan time median {np.median(times):.2f} s, 98th "
          f"percentile {np.percentile(times, 98):.2f} s (CPU time of hoc plan, its start included: median "
          f"{np.nanmedian([np.nan if r['cpu_s'] is None else r['cpu_s'] for r in results]):.2f} s); of its successes below the margin between samples (coal, "
          f"1 kHz) {between}, smallest clearance {min(coal) if coal else float('nan'):.5f} m (margin {MARGIN} m)")
    if args.drake:
        dr = [r["drake"] for r in results]
        dok = [d for d in dr if d["success"]]
        dtimes = np.array([d["time_s"] for d in dr])
        c = [d["coal_1khz"] if d["coal_1khz"] is not None else d["clearance_1khz"] for d in dok]
        print(f"Drake: success {len(dok)}/{n} = {100 * len(dok) / n:.0f} % (SNOPT's own test); plan time median "
              f"{np.median(dtimes):.2f} s, 98th percentile {np.percentile(dtimes, 98):.2f} s; of its successes below "
              f"the margin between samples {sum(v < MARGIN - 1e-9 for v in c)}, in collision (< 0) "
              f"{sum(v < 0 for v in c)}")
        print(f"ratios hoc/Drake: success {len(ok) / max(len(dok), 1):.2f}, median time "
              f"{np.median(times) / np.median(dtimes):.2f}, 98th percentile time "
              f"{np.percentile(times, 98) / np.percentile(dtimes, 98):.2f}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
