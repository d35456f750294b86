"""Collision avoidance enforced: the penalty's gradient and curvature, plans certified clear (coal at 1 kHz),
J against the margin, an infeasible task, link goals and vias enforced, a free T refused."""
from __future__ import annotations

import csv
import dataclasses
from pathlib import Path

import numpy as np
import pytest
from _collision_tasks import coal_two_link, plan, task_folder

from hoc_cli.collision.constraint import SPHERE_PADDING, CollisionTerms, RowStart, point_configurations, row_reach, sphere_rows_scene
from hoc_cli.collision.enforce import RHO_RANGE_STEPS, base_points
from hoc_cli.collision.evaluate import contacts, distances, pair_distances, pair_gradient, row_contacts, row_distances, world_capsules
from hoc_cli.collision.geometry import Shape
from hoc_cli.collision.robot import robot_geometry
from hoc_cli.collision.scene import KIND_BOX, KIND_CAPSULE, KIND_SELF, Obstacle, collision_scene
from hoc_cli.collision.shapes import Box, sphere
from hoc_cli.elements import HermiteMesh
from hoc_cli.model import load_robot
from hoc_cli.problem import minimum_jerk_guess

ROOT = Path(__file__).resolve().parents[1]
ARM = {"upper_arm": [{"capsule": {"a": [0, 0, 0], "b": [1, 0, 0], "radius": 0.05}}],
       "forearm": [{"capsule": {"a": [0, 0, 0], "b": [1, 0, 0], "radius": 0.05}}]}
BALL = {"name": "ball", "sphere": {"radius": 0.1}, "position": [1.75, 0, 0.55]}  # on the free plan's path


def two_link(obstacles: list, margin: float = 0.01, N: int = 8) -> dict:
    return {"robot": "../robots/two_link.urdf", "x0": {"q": [0.0, 0.0]}, "x1": {"q": [1.2, -0.6]}, "T": 1.5,
            "N": N, "output": {"rate": 1000.0},
            "collision": {"margin": margin, "robot": ARM, "obstacles": obstacles}}


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    return task_folder(tmp_path, monkeypatch, ("two_link.urdf", "lbr7.urdf"))


def test_the_arm_goes_round_a_ball_certified_and_coal_agrees_at_1_khz_and_J_grows_with_the_margin(workdir):
    r, free = plan(workdir, two_link([BALL]), "--collision", "check")
    assert r.exit_code == 0 and free["min_clearance"]["distance"] < -0.1  # the free optimum goes through it
    costs = []
    for margin in (0.01, 0.03, 0.06):
        r, s = plan(workdir, two_link([BALL], margin))
        assert r.exit_code == 0, r.stderr
        c = s["min_clearance"]
        assert s["collision_mode"] == "enforce" and s["converged"] and s["collisions"] == []
        assert c["certified"] and c["lower_bound"] >= margin - 1e-9
        assert coal_two_link(workdir / "out.csv", BALL) >= margin - 1e-9
        assert c["distance"] < margin + 0.005  # the constraint binds
        costs.append(s["cost"])
    assert free["cost"] < costs[0] <= costs[1] <= costs[2]


def test_a_binding_velocity_limit_and_the_ball_are_met_together_in_one_loop(workdir):
    """The joint limits' rounds run inside the collision loop (``limit_rounds``): the plan meets the limit exactly
    (the check finds nothing beyond it, the limit is active) and its clearance is certified, coal agreeing."""
    doc = two_link([BALL], N=16)
    r, free = plan(workdir, doc)
    assert r.exit_code == 0 and free["active_limits"] == []
    with open(workdir / "out.csv") as f:
        fastest = max(abs(float(row["dq.elbow"])) for row in csv.DictReader(f))
    assert fastest > 2.5  # the enforced plan without the limit swings the elbow faster than it
    doc["limits"] = {"velocity": {"shoulder": 1.5, "elbow": 1.5}}
    s = _plan_with_binding_elbow_limit(workdir, doc, 1.5)
    assert s["cost"] > free["cost"]


def _plan_with_binding_elbow_limit(workdir, doc: dict, limit: float) -> dict:
    """``hoc plan`` of ``doc``, checked: converged within its limits, the elbow's velocity ``limit`` active and met
    in the CSV, the clearance certified and coal's at the samples at least the margin; its summary."""
    r, s = plan(workdir, doc)
    assert r.exit_code == 0, r.stderr
    assert s["converged"] and s["limit_violations"] == []
    assert {"joint": "elbow", "kind": "velocity"} in [{k: a[k] for k in ("joint", "kind")} for a in s["active_limits"]]
    with open(workdir / "out.csv") as f:
        assert max(abs(float(row["dq.elbow"])) for row in csv.DictReader(f)) <= limit * (1 + 1e-9)
    c = s["min_clearance"]
    assert c["certified"] and c["lower_bound"] >= 0.01 - 1e-9 and coal_two_link(workdir / "out.csv", BALL) >= 0.01 - 1e-9
    return s


def test_an_arm_that_must_pass_through_a_box_is_infeasible_naming_the_pair(workdir):
    wall = {"name": "wall", "box": {"size": [0.1, 0.1, 0.1]}, "position": [0.33, 0, 0.226]}  # across the upper arm's sweep
    r, s = plan(workdir, two_link([wall], N=4))
    assert r.exit_code == 1 and s["status"] == "infeasible" and not s["converged"]
    assert "no collision-free trajectory was found:" in s["message"] and "and wall overlap by" in s["message"]
    assert "hoc: infeasible: no collision-free trajectory" in r.stderr
    assert (workdir / "out.csv").exists()  # the closest attempt is written, as for infeasible limits
    # declared once ρ has grown RHO_RANGE-fold with the violation stalled: the first outer iteration, then one per
    # growth by RHO_GROWTH (not one more at 10·RHO_RANGE, where the inner solves crawl)
    assert s["collision_enforce"]["outer_iterations"] <= 1 + RHO_RANGE_STEPS + 1


@pytest.mark.parametrize("goal", [
    {"N": 4, "x1": {"link": "tool", "position": [1.2, 0.0, 1.4]}},                 # a link goal: the final q free
    {"via": [{"t": 0.5, "link": "tool", "position": [1.6, 0.0, 0.9]}]},            # a link via: a goal row mid-way
], ids=["link_goal", "link_via"])
def test_a_goal_task_is_planned_round_the_ball_meeting_its_goal_certified_and_coal_agrees_at_1_khz(workdir, goal):
    doc = two_link([BALL]) | goal
    r, free = plan(workdir, doc, "--collision", "check")
    assert r.exit_code == 0 and free["min_clearance"]["distance"] < 0  # the free plan drives the forearm through it
    r, s = plan(workdir, doc)
    assert r.exit_code == 0, r.stderr
    assert "warning" not in r.stderr  # enforced, no fallback to check
    assert s["collision_mode"] == "enforce" and s["converged"] and s["collisions"] == []
    assert s["collision_enforce"]["status"] == "converged"
    c = s["min_clearance"]
    assert c["certified"] and c["lower_bound"] >= 0.01 - 1e-9
    met = [s["reached"]] if "x1" in goal else s["vias"]
    assert met and all(g["position_error"] <= 1e-9 for g in met)
    assert coal_two_link(workdir / "out.csv", BALL) >= 0.01 - 1e-9
    assert s["cost"] >= free["cost"]


def test_a_link_goal_with_a_binding_velocity_limit_and_the_ball_meets_all_three(workdir):
    """The goal rows, the joint limits' rounds and the collision loop together: the elbow's velocity limit binds (the
    enforced plan without it swings faster), and the plan meets it, its goal, and the certified clearance."""
    doc = two_link([BALL], N=4) | {"x1": {"link": "tool", "position": [1.2, 0.0, 1.4]}}
    r, free = plan(workdir, doc)
    assert r.exit_code == 0 and free["collision_mode"] == "enforce"
    with open(workdir / "out.csv") as f:
        assert max(abs(float(row["dq.elbow"])) for row in csv.DictReader(f)) > 3.2
    doc["limits"] = {"velocity": {"elbow": 3.0}}
    s = _plan_with_binding_elbow_limit(workdir, doc, 3.0)
    assert s["reached"]["position_error"] <= 1e-9 and s["cost"] > free["cost"]


def test_enforce_refuses_N_auto_in_one_line_and_the_default_falls_back_to_check(workdir):
    doc = two_link([BALL], N=4)
    doc["N"] = "auto"
    r, _ = plan(workdir, doc, "--collision", "enforce")
    assert r.exit_code == 2 and r.stderr.count("\n") == 1
    assert "task.yaml: collision.mode: collision enforcement plans in a fixed N with one start, not N: auto" \
        in r.stderr and "--collision check" in r.stderr
    r, s = plan(workdir, doc)
    assert r.exit_code == 0, r.stderr
    assert s["collision_mode"] == "check" and "min_clearance" in s and "collision_enforce" not in s
    assert "hoc: warning: collision enforcement plans in a fixed N" in r.stderr and "planned with collision check" in r.stderr


@pytest.fixture(scope="module")
def lbr7_scene():
    model = load_robot(ROOT / "robots" / "lbr7.urdf")
    shapes = {f"lbr_link_{i}": [Shape("capsule", radius=0.06, a=np.array([0, 0, 0.03]), b=np.array([0, 0, 0.15]))]
              for i in range(1, 8)}
    robot = robot_geometry(model, {}, shapes)
    obstacles = [Obstacle("ball", sphere([0.35, 0.0, 0.55], 0.12)),
                 Obstacle("box", Box(np.array([0.2, -0.3, 0.5]), np.eye(3), np.array([0.1, 0.05, 0.2])))]
    return model, collision_scene(model, robot, obstacles, margin=0.02)


def test_the_spheres_standing_for_a_capsule_keep_within_the_padding_of_its_distance(lbr7_scene):
    model, scene = lbr7_scene
    rows = sphere_rows_scene(scene)
    assert rows.size > scene.size
    q = np.random.default_rng(3).uniform(-1.5, 1.5, (40, model.n))
    D, Ds = distances(model, scene, q), distances(model, rows, q)   # (K, Q), (K, Q')
    spheres = 0
    for names in set(scene.names):
        exact = D[:, [k for k in range(scene.size) if scene.names[k] == names]].min(axis=1)
        cover = Ds[:, [k for k in range(rows.size) if rows.names[k] == names]].min(axis=1)
        assert np.all(cover <= exact + 1e-12) and np.all(cover >= exact - SPHERE_PADDING - 1e-12)
        spheres += np.sum([rows.names[k] == names for k in range(rows.size)]) > 1
    assert spheres == 14  # 7 links against the ball and the box: spheres; the self pairs as they are
    self_pairs = scene.kind == 0
    assert np.array_equal(D[:, self_pairs], Ds[:, rows.kind == 0])


def test_row_contacts_place_only_the_rows_primitives_and_agree_with_every_pair_at_every_sample(lbr7_scene):
    model, scene = lbr7_scene
    rows_scene = sphere_rows_scene(scene)
    q = np.random.default_rng(5).uniform(-1.5, 1.5, (12, model.n))
    for sc in (scene, rows_scene):  # self pairs (both ends on the robot) and obstacle pairs
        every = distances(model, sc, q)                                           # (K, Q)
        rng = np.random.default_rng(6)
        rows, pairs = rng.integers(0, len(q), 300), rng.integers(0, sc.size, 300)
        got = row_contacts(model, sc, q, rows, pairs)
        assert np.array_equal(got.distance, every[rows, pairs])
        d, _ = pair_gradient(model, sc, q, rows, pairs)
        assert np.array_equal(d, every[rows, pairs])


def test_distances_alone_are_the_contacts_distances_spheres_in_and_out_of_boxes_included(lbr7_scene):
    """``distances`` and ``pair_distances`` take a sphere outside a box on a path of their own: the same numbers."""
    model, scene = lbr7_scene
    rows_scene = sphere_rows_scene(scene)
    q = np.random.default_rng(7).uniform(-2.5, 2.5, (200, model.n))
    for sc in (scene, rows_scene):
        every = contacts(model, sc, q).distance                                    # (K, Q)
        assert np.array_equal(distances(model, sc, q), every)
        a, b = world_capsules(model, sc, q)
        rng = np.random.default_rng(8)
        rows, pairs = rng.integers(0, len(q), 4000), rng.integers(0, sc.size, 4000)
        assert np.array_equal(pair_distances(sc, a, b, rows, pairs), every[rows, pairs])
        assert np.array_equal(row_distances(model, sc, q, rows, pairs), every[rows, pairs])
    assert (scene.kind == KIND_CAPSULE).any() and (scene.kind == KIND_SELF).any()  # two capsules' distance alone
    box = rows_scene.kind == KIND_BOX
    assert (every[:, box] < -rows_scene.robot.radius[rows_scene.prim[box]]).any()  # centres in the box: the depth path


def _terms(model, scene, mesh, C, rho=50.0):
    points = base_points(mesh)
    D = distances(model, scene, point_configurations(points, C))
    p, k = np.nonzero(D < 0.1)
    lam = np.random.default_rng(1).uniform(0, 2, p.size) * (np.arange(p.size) % 2)  # half of them with λ > 0
    return CollisionTerms(model, scene, points, p, k, lam, rho, np.full(p.size, 0.03)), D


def test_the_penalty_gradient_matches_central_differences(lbr7_scene):
    model, scene = lbr7_scene
    mesh = HermiteMesh("quintic", 1.5, 4)
    q0, q1 = np.array([-0.9, 0.7, 0, -1.2, 0, 0.9, 0]), np.array([0.9, 0.8, 0, -1.0, 0, 1.0, 0])
    C = minimum_jerk_guess(mesh, q0, np.zeros(7), q1, np.zeros(7))
    terms, D = _terms(model, scene, mesh, C)
    assert terms.rows.size > 20 and (D < 0.03).any()  # rows in contact, penetrating and near
    value, G = terms.evaluate(C)
    assert value > 0 and terms.evaluate(C, grad=False)[0] == pytest.approx(value, rel=1e-12)
    rng = np.random.default_rng(0)
    errors = []
    for _ in range(40):
        idx = tuple(rng.integers(0, s) for s in C.shape)
        h = 1e-6
        Cp, Cm = C.copy(), C.copy()
        Cp[idx] += h
        Cm[idx] -= h
        fd = (terms.evaluate(Cp, grad=False)[0] - terms.evaluate(Cm, grad=False)[0]) / (2 * h)
        errors.append(abs(fd - G[idx]) / max(abs(G).max(), 1e-12))
    assert np.median(errors) < 1e-7 and np.mean(np.array(errors) < 1e-6) >= 0.95  # a kink may sit in a step


def test_the_curvature_blocks_are_the_gauss_newton_matrix_of_the_active_rows(lbr7_scene):
    model, scene = lbr7_scene
    mesh = HermiteMesh("quintic", 1.5, 4)
    q0, q1 = np.array([-0.9, 0.7, 0, -1.2, 0, 0.9, 0]), np.array([0.9, 0.8, 0, -1.0, 0, 1.0, 0])
    C = minimum_jerk_guess(mesh, q0, np.zeros(7), q1, np.zeros(7))
    terms, _ = _terms(model, scene, mesh, C)
    blocks = terms.newton_blocks(C)                                   # (N, 2mn, 2mn)
    assert np.allclose(blocks, np.swapaxes(blocks, 1, 2))
    delta = np.random.default_rng(2).normal(size=C.shape)
    loc = mesh.local_coefficients(delta).reshape(mesh.N, -1)          # element order a·n + j
    quad = float(np.einsum("ea,eab,eb->", loc, blocks, loc))
    h = 1e-6  # Σ_active ρ_r (∇d_r · δ)², the directional derivatives by central differences
    dd = (terms.distances(C + h * delta) - terms.distances(C - h * delta)) / (2 * h)
    d = terms.distances(C)
    active = terms.lam + terms.rho_rows * (terms.bound - d) > 0
    assert active.sum() >= 5
    ref = float(np.sum(terms.rho_rows[active] * dd[active] ** 2))
    assert quad == pytest.approx(ref, rel=1e-5)


def test_the_distance_curvature_blocks_are_minus_mu_times_the_second_derivative_of_the_active_rows(lbr7_scene):
    model, scene = lbr7_scene
    mesh = HermiteMesh("quintic", 1.5, 4)
    q0, q1 = np.array([-0.9, 0.7, 0, -1.2, 0, 0.9, 0]), np.array([0.9, 0.8, 0, -1.0, 0, 1.0, 0])
    C = minimum_jerk_guess(mesh, q0, np.zeros(7), q1, np.zeros(7))
    terms, _ = _terms(model, sphere_rows_scene(scene), mesh, C)
    assert terms.curvature_blocks(C) is None  # asked for only
    terms = dataclasses.replace(terms, curvature=True, _last=[])
    blocks = terms.curvature_blocks(C)                                # (N, 2mn, 2mn)
    assert np.allclose(blocks, np.swapaxes(blocks, 1, 2))
    delta = np.random.default_rng(2).normal(size=C.shape) * 0.1
    loc = mesh.local_coefficients(delta).reshape(mesh.N, -1)
    quad = float(np.einsum("ea,eab,eb->", loc, blocks, loc))
    h = 1e-4  # −Σ μ_r δᵀ∇²d_r δ over the active rows clear of contact: second differences (q is linear in C)
    d = terms.distances(C)
    second = (terms.distances(C + h * delta) - 2 * d + terms.distances(C - h * delta)) / h ** 2
    on = (terms.multipliers(d) > 0) & (d > 0)
    assert on.sum() >= 5 and (~on & (terms.multipliers(d) > 0)).sum() >= 1  # penetrating rows are left out
    ref = float(-np.sum(terms.multipliers(d)[on] * second[on]))
    assert quad == pytest.approx(ref, rel=1e-4) and abs(ref) > 0


def swing_rows(model, scene, near: float, every: int):
    """The lbr7's minimum-jerk swing on 4 quintic elements (1.5 s) and its collision rows: (C (5, 3, 7), the base
    points, their distances (points, pairs), ``CollisionTerms`` of every pair nearer than ``near`` [m], seeded λ > 0 on
    one row in ``every``, ρ = 50, margin 0.03 m)."""
    mesh = HermiteMesh("quintic", 1.5, 4)
    q0, q1 = np.array([-0.9, 0.7, 0, -1.2, 0, 0.9, 0]), np.array([0.9, 0.8, 0, -1.0, 0, 1.0, 0])
    C = minimum_jerk_guess(mesh, q0, np.zeros(7), q1, np.zeros(7))
    points = base_points(mesh)
    D = distances(model, scene, point_configurations(points, C))
    p, k = np.nonzero(D < near)
    lam = np.random.default_rng(1).uniform(0, 2, p.size) * (np.arange(p.size) % every == 0)
    return C, points, D, CollisionTerms(model, scene, points, p, k, lam, 50.0, np.full(p.size, 0.03))


def test_rows_that_cannot_reach_their_bound_from_the_start_are_skipped_without_changing_phi(lbr7_scene):
    """Skipped rows (``RowStart``: the reach bound from the inner solve's start, or from the last plan where every
    row was evaluated) add exactly nothing: Φ, its gradient and its blocks equal those of every row evaluated, at
    plans moved a little and far from the start."""
    model, scene = lbr7_scene
    C0, points, D, full = swing_rows(model, scene, near=0.3, every=8)  # near and far rows, λ > 0 on one in eight
    start = RowStart(point_configurations(points, C0), D[full.rows, full.pairs],
                     row_reach(model, scene, np.arange(scene.size))[full.pairs])
    pruned = dataclasses.replace(full, start=start, _last=[], _anchor=[])
    rng = np.random.default_rng(4)
    skipped = []
    far = C0 + 1.5 * rng.normal(size=C0.shape)
    for C in [C0 + size * rng.normal(size=C0.shape) for size in (1e-3, 3e-2)] + [far, far + 1e-3 * rng.normal(size=C0.shape)]:
        v, G = full.evaluate(C)
        vp, Gp = pruned.evaluate(C)
        assert vp == pytest.approx(v, rel=1e-13, abs=1e-13) and np.allclose(Gp, G, rtol=0, atol=1e-12 * np.abs(G).max())
        assert np.allclose(pruned.newton_blocks(C), full.newton_blocks(C), rtol=1e-13, atol=0)
        d, dp = full.distances(C), pruned.distances(C)
        live = np.isfinite(dp)
        assert np.array_equal(dp[live], d[live]) and np.all(d[~live] >= full.bound[~live])  # a skipped row is clear
        assert np.all(full.lam[~live] == 0)
        skipped.append(int((~live).sum()))
    # rows are skipped near the start; far from it every row is evaluated and the anchor moves there, so rows are
    # skipped again near the far plan, more than from the start
    fresh = dataclasses.replace(full, start=start, _last=[], _anchor=[])
    assert skipped[0] > 0 and skipped[3] > int(np.isinf(fresh.distances(C)).sum())
    # each row's bound starts where it was last evaluated: after a plan that moves the end of the path only,
    # the rows evaluated there are bounded from it, the others still from the start
    part = C0.copy()
    part[-2:] += 0.5 * rng.normal(size=part[-2:].shape)
    pruned = dataclasses.replace(full, start=start, _last=[], _anchor=[])
    first = np.isinf(pruned.distances(part))
    assert 0.5 * first.size < first.sum() < first.size  # some rows evaluated, not most
    near = part + 1e-4 * rng.normal(size=C0.shape)
    again = np.isinf(pruned.distances(near))
    fresh = dataclasses.replace(full, start=start, _last=[], _anchor=[])
    assert again.sum() > np.isinf(fresh.distances(near)).sum()
    assert np.array_equal(pruned.evaluate(near)[1], full.evaluate(near)[1])


def test_a_batch_plans_a_collision_task_as_hoc_plan_does_with_its_clearance_column(workdir):
    pytest.importorskip("pyarrow")
    pytest.importorskip("distributed")
    from hoc_cli.batch import execute_batch
    from hoc_cli.batch.engine import connect

    r, single = plan(workdir, two_link([BALL]))
    assert r.exit_code == 0 and single["collision_mode"] == "enforce"
    with connect(workers=1) as client:
        run = execute_batch([str(workdir / "task.yaml")], client, out_dir=workdir / "out")
    (row,) = run.table.to_pylist()
    assert row["status"] == "converged" and abs(row["cost"] - single["cost"]) <= 1e-12 * single["cost"]
    assert row["min_clearance"] == single["min_clearance"]["distance"] >= 0.01


def test_via_candidates_are_clear_shortest_first_where_the_straight_path_is_not():
    from hoc_cli.collision.guess import FINE_SAMPLES, via_candidates, via_guess

    model = load_robot(ROOT / "robots" / "two_link.urdf")
    shapes = {k: [Shape("capsule", radius=0.05, a=np.zeros(3), b=np.array([1.0, 0, 0]))] for k in ARM}
    robot = robot_geometry(model, {}, shapes)
    scene = collision_scene(model, robot, [Obstacle("ball", sphere(BALL["position"], 0.1))], margin=0.01)
    q0, q1 = np.zeros(2), np.array([1.2, -0.6])
    s = np.linspace(0, 1, 201)[1:-1, None]
    assert distances(model, scene, q0 + s * (q1 - q0)).min() < 0  # the straight path hits the ball
    vias = via_candidates(model, scene, q0, q1, count=3)
    clear = [c >= 0.01 for _, c in vias]
    assert clear[0] and clear == sorted(clear, reverse=True)  # the clear ones first
    fine = np.linspace(0, 1, 8 * FINE_SAMPLES + 1)[1:, None]
    lengths = []
    for qv, _ in vias[:sum(clear)]:
        path = np.concatenate([q0 + fine * (qv - q0), qv + fine * (q1 - qv)])
        assert distances(model, scene, path).min() > 0  # clear between its samples too
        lengths.append(np.linalg.norm(qv - q0) + np.linalg.norm(q1 - qv))
    assert lengths == sorted(lengths)
    mesh = HermiteMesh("quintic", 1.5, 4)
    C = via_guess(mesh, q0, np.zeros(2), vias[0][0], q1, np.zeros(2))
    assert np.allclose(mesh.evaluate(C, np.array([0.75]))[0], vias[0][0])
    assert np.allclose(C[0, 0], q0) and np.allclose(C[-1, 0], q1) and not C[0, 1].any() and not C[-1, 1].any()


def test_a_start_the_loop_cannot_free_is_replanned_from_vias(workdir, monkeypatch):
    import dataclasses

    import hoc_cli.collision.enforce as enforce

    loop = enforce.CollisionConstraint._loop

    def failing(self, *args, **kw):  # the loop from the level's own start ends infeasible (as from a start it cannot free)
        got = loop(self, *args, **kw)
        return got if kw["start"] != "start" else got[:3] + (dataclasses.replace(got[3], status="infeasible"),)

    monkeypatch.setattr(enforce.CollisionConstraint, "_loop", failing)
    r, s = plan(workdir, two_link([BALL], N=4))
    assert r.exit_code == 0, r.stderr
    assert s["collision_enforce"]["start"] in ("guess", "via") and s["min_clearance"]["certified"]
    assert coal_two_link(workdir / "out.csv", BALL) >= 0.01 - 1e-9
