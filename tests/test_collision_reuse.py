"""What an inner iteration of the collision loop evaluates once and reuses: the joint limits' penalty at the accepted
point (gradient, Newton blocks, first step's rows), the collision rows' poses and contacts (gradient, distance
curvature), checked against fresh evaluations and counted."""
from __future__ import annotations

import dataclasses

import numpy as np

from hoc_cli.collision.constraint import RowStart, point_configurations, row_reach, sphere_rows_scene
from hoc_cli.collision.step import limit_rows
from hoc_cli.constraints import JointLimits
from hoc_cli.constraints.augmented_lagrangian import MARGIN
from hoc_cli.constraints.bounds import KINDS
from hoc_cli.constraints.penalty import LimitRows, LimitTerms
from hoc_cli.elements import HermiteMesh
from hoc_cli.model import load_robot
from hoc_cli.problem import ControlProblem
from hoc_cli.system import RobotSystem
from tests._robots import ROBOTS
from tests.test_collision_enforce import lbr7_scene, swing_rows  # noqa: F401  (the fixture)


def _limit_terms():
    model = load_robot(ROBOTS / "two_link.urdf")
    system = RobotSystem(model)
    problem = ControlProblem(system, HermiteMesh("quintic", 1.5, 6), [0.0, 0.0], [0.0, 0.0], [1.2, -0.6], [0.0, 0.0])
    limits = JointLimits.from_arrays(model.joint_names, lower=[-0.1, -0.5], upper=[0.9, 0.2], velocity=[1.0, 0.5],
                                     acceleration=[3.0, 2.0], effort=[5.0, 2.0])
    rows = LimitRows.build(problem.mesh, problem.layout.free, 2)
    rng = np.random.default_rng(5)
    lam = [tuple(rng.uniform(0, 1, rows.shape(k, 2)) * (rng.uniform(size=rows.shape(k, 2)) < 0.3)
                 for k in range(len(KINDS))) for _ in range(2)]
    working = np.ones((len(KINDS), 2), bool)
    make = lambda: LimitTerms(system, limits, rows, working, lam[0], lam[1], rho=300.0, margin=MARGIN)  # noqa: E731
    C = problem.coefficients(problem.initial_guess())
    dC = problem.layout.unpack(rng.normal(size=problem.layout.size) * 0.3, np.zeros_like(C))
    return make, C, dC


def test_the_limits_penalty_is_evaluated_once_at_a_point_for_the_gradient_the_newton_blocks_and_the_first_step(monkeypatch):
    make, C, dC = _limit_terms()
    fresh = make()
    ref = fresh.evaluate(C)
    ref_blocks = make().newton_blocks(C)
    ref_rows = limit_rows(make(), C, dC)
    terms = make()
    calls = []
    values = LimitTerms._values
    monkeypatch.setattr(LimitTerms, "_values", lambda self, C: calls.append(np.array(C)) or values(self, C))
    got = terms.evaluate(C)                       # the line search's trial, accepted: the gradient
    blocks = terms.newton_blocks(C.copy())        # the Newton matrix there
    rows = limit_rows(terms, C.copy(), dC)        # the first step from there (effort: its secant at C + dC too)
    again = terms.evaluate(C.copy(), grad=False)  # the loop's update
    assert len(calls) == 2 and np.array_equal(calls[1], C + dC), len(calls)  # C once, C + dC once
    assert got.value == ref.value and np.array_equal(got.grad, ref.grad) and again.value == ref.value
    assert again.grad is None
    np.testing.assert_array_equal(blocks, ref_blocks)
    for x, y in zip(rows, ref_rows):
        np.testing.assert_array_equal(x, y)
    other = terms.evaluate(C + 1e-3 * dC, grad=False)  # another point is evaluated
    assert len(calls) == 3 and other.value != ref.value


def test_the_distance_curvature_at_the_point_just_evaluated_reuses_its_poses_and_contacts(lbr7_scene, monkeypatch):  # noqa: F811
    """The Newton matrix's −Σ μ ∇²d at the accepted point takes the body poses and contacts its gradient placed: the
    same blocks as placed afresh (``pair_hessian`` from q), with every row evaluated and with rows skipped."""
    import hoc_cli.collision.evaluate as ev

    model, scene = lbr7_scene
    rows_scene = sphere_rows_scene(scene)
    C0, points, D, full = swing_rows(model, rows_scene, near=0.3, every=3)
    full = dataclasses.replace(full, curvature=True, _last=[])
    start = RowStart(point_configurations(points, C0), D[full.rows, full.pairs],
                     row_reach(model, rows_scene, np.arange(rows_scene.size))[full.pairs])
    C = C0 + 1e-3 * np.random.default_rng(9).normal(size=C0.shape)
    poses = []
    placed = ev._poses
    for terms in (full, dataclasses.replace(full, start=start, _last=[], _anchor=[])):
        ref = dataclasses.replace(terms, _last=[], _anchor=[]).curvature_blocks(C)  # no gradient at C: placed afresh
        terms.evaluate(C)                                                           # the line search's accepted trial
        monkeypatch.setattr(ev, "_poses", lambda model, q: poses.append(len(q)) or placed(model, q))
        got = terms.curvature_blocks(C.copy())
        monkeypatch.setattr(ev, "_poses", placed)
        assert ref is not None and np.abs(ref).max() > 0
        np.testing.assert_array_equal(got, ref)
    assert poses == []


def test_the_banded_assembly_reuses_its_pattern_and_factors_the_summed_blocks():
    """``BandedSPD.assemble`` places the blocks by a pattern kept per (blocks' shape, free mask): the factor is that of
    the blocks summed densely (fixed rows and columns a scaled identity), with a second mask a pattern of its own."""
    from scipy.linalg import cholesky

    from hoc_cli.banded import BandedSPD, _pattern

    rng = np.random.default_rng(11)
    E, L, stride = 5, 12, 6
    size = E * stride + L - stride
    masks = [np.ones(size, bool), rng.uniform(size=size) < 0.8]
    masks[1][0] = True
    before = _pattern.cache_info()
    for free in masks + masks:
        A = rng.normal(size=(E, L, L))
        blocks = np.einsum("eij,ekj->eik", A, A) + L * np.eye(L)
        got = BandedSPD.assemble(blocks, stride, size, free, shift=0.0)
        dense = np.zeros((size, size))
        for e in range(E):
            dense[e * stride:e * stride + L, e * stride:e * stride + L] += blocks[e]
        dense = np.where(free[:, None] & free[None, :], dense, 0.0)
        scale = np.mean(np.diag(dense)[free])
        dense[~free, ~free] = scale
        U = cholesky(dense)                                     # upper: the banded storage's rows are its diagonals
        for k in range(L):
            np.testing.assert_allclose(got.factor[L - 1 - k, k:], np.diag(U, k), rtol=1e-12, atol=1e-12)
    after = _pattern.cache_info()
    assert after.misses - before.misses <= 2 and after.hits - before.hits >= 2


def test_the_penalty_gradient_maps_the_points_of_active_rows_alone_with_the_same_numbers(lbr7_scene):  # noqa: F811
    """∂Φ/∂C by ``PointSet.transpose_q`` over the points holding a row with μ > 0 equals ``transpose`` of the full
    (3, P, n) sensitivities (q̇ and q̈ rows zero), bit for bit."""
    from hoc_cli.collision.constraint import group_sum

    model, scene = lbr7_scene
    C0, points, D, terms = swing_rows(model, sphere_rows_scene(scene), near=0.3, every=5)
    for C in (C0, C0 + 1e-2 * np.random.default_rng(12).normal(size=C0.shape)):
        _, got = dataclasses.replace(terms, _last=[], _anchor=[]).evaluate(C)
        d, dd = terms._gradient(C)
        mu = terms.multipliers(d)
        assert 0 < (mu > 0).sum() < mu.size
        G = np.zeros((3, points.size, dd.shape[-1]))
        G[0] = group_sum(terms.rows, -mu[:, None] * dd, points.size)
        assert np.array_equal(got, points.transpose(G))
    which = np.array([3, 7, 7, 20])  # a point twice: both added
    Gq = np.random.default_rng(13).normal(size=(which.size, 7))
    G = np.zeros((3, points.size, 7))
    np.add.at(G[0], which, Gq)
    np.testing.assert_allclose(points.transpose_q(Gq, which), points.transpose(G), rtol=1e-14, atol=1e-14)


def test_row_distances_place_only_the_rows_primitives_with_the_distances_of_every_pair(lbr7_scene):  # noqa: F811
    """``row_distances`` (the certificate's midpoints: about one row per time) equals ``distances`` on every pair, spheres
    in and out of boxes and self pairs included; the certificate's grouping of intervals equals ``np.unique``'s."""
    from hoc_cli.collision.certify import _distinct
    from hoc_cli.collision.evaluate import distances, row_distances

    model, scene = lbr7_scene
    q = np.random.default_rng(14).uniform(-2.5, 2.5, (150, model.n))
    for sc in (scene, sphere_rows_scene(scene)):
        every = distances(model, sc, q)
        rng = np.random.default_rng(15)
        rows, pairs = rng.integers(0, len(q), 3000), rng.integers(0, sc.size, 3000)
        assert np.array_equal(row_distances(model, sc, q, rows, pairs), every[rows, pairs])
    rng = np.random.default_rng(16)
    e, a, b = rng.integers(0, 3, 60), rng.choice([0.0, 0.25, 0.5], 60), rng.choice([0.5, 0.75, 1.0], 60)
    first, inverse = _distinct(e, a, b)
    _, ref_first, ref_inverse = np.unique(np.stack([e, a, b]), axis=1, return_index=True, return_inverse=True)
    assert np.array_equal(first, ref_first) and np.array_equal(inverse, ref_inverse.ravel())


def test_a_carried_cost_hessian_serves_the_next_newton_matrix_at_that_point_once(monkeypatch):
    """``ControlProblem.carry_hessian(x)``: the next Newton matrix, at x, takes the cost Hessian of the last one (no
    sweep; the same matrix as the last one's cost part), and a Newton matrix elsewhere sweeps again."""
    model = load_robot(ROBOTS / "two_link.urdf")
    problem = ControlProblem(RobotSystem(model), HermiteMesh("quintic", 1.5, 4), [0.0, 0.0], [0.0, 0.0], [1.2, -0.6],
                             [0.0, 0.0])
    x0 = problem.initial_guess()
    rng = np.random.default_rng(17)
    x1 = x0 + 1e-3 * rng.normal(size=x0.shape)
    sweeps = []
    sweep = ControlProblem.hessian_samples
    monkeypatch.setattr(ControlProblem, "hessian_samples", lambda self, ev, samples=None: sweeps.append(1) or sweep(self, ev, samples))
    e0 = problem.evaluate(x0)
    P0 = problem.newton(e0)
    problem.carry_hessian(x1)
    P1 = problem.newton(problem.evaluate(x1))
    assert len(sweeps) == 1
    np.testing.assert_array_equal(P1.factor, P0.factor)  # the cost part alone: the same matrix
    problem.newton(problem.evaluate(x1 + 1e-3))           # elsewhere: a sweep
    problem.carry_hessian(x1)
    problem.newton(problem.evaluate(x0))                  # carried to x1, asked at x0: a sweep
    assert len(sweeps) == 3


def test_the_kinematic_limit_blocks_kept_for_the_same_active_rows_are_those_made_afresh():
    """``LimitTerms.newton_blocks`` keeps its kinematic kinds' blocks by the active rows: at another point with the same
    active rows the same blocks as made afresh, with other active rows the new ones (a guard: a stale kept block fails)."""
    make, C, dC = _limit_terms()
    terms = make()
    first = terms.newton_blocks(C)
    pv = terms.evaluate(C, grad=False)
    for scale in (1e-9, 0.3):
        C2 = C + scale * dC
        pv2 = terms.evaluate(C2, grad=False)
        same = all(np.array_equal((terms.lam_lo[k] + terms.rho * terms.rows.weight(k) * a.g_lo[k] > 0),
                                  (terms.lam_lo[k] + terms.rho * terms.rows.weight(k) * pv2.g_lo[k] > 0))
                   for k in range(4) for a in (pv,))
        assert same == (scale < 1e-6)
        np.testing.assert_array_equal(terms.newton_blocks(C2), make().newton_blocks(C2))
    assert not np.array_equal(terms.newton_blocks(C + 0.3 * dC), first)


def test_the_report_takes_the_certificate_of_the_plan_the_loop_certified(tmp_path, monkeypatch):
    """``hoc plan``'s summary of an enforced plan takes the collision loop's certificate of the same coefficients (no
    second ``certify``): ``min_clearance`` and ``collisions`` equal those of the plan certified afresh; another plan
    (other coefficients) is certified again."""
    from _collision_tasks import plan, task_folder

    import hoc_cli.collision.certify as certify_module
    import hoc_cli.report.summary as summary_module
    from hoc_cli.report.collision import collision_summary
    from tests.test_collision_enforce import BALL, two_link

    workdir = task_folder(tmp_path, monkeypatch, ("two_link.urdf",))
    asked, seen = [], []
    certify = certify_module.certify
    monkeypatch.setattr(certify_module, "certify", lambda *a, **k: asked.append(1) or certify(*a, **k))
    monkeypatch.setattr(summary_module, "collision_summary",
                        lambda model, scene, mode, result: seen.append((model, scene, mode, result))
                        or collision_summary(model, scene, mode, result))
    r, s = plan(workdir, two_link([BALL], N=4))
    assert r.exit_code == 0, r.stderr
    assert s["collision_mode"] == "enforce" and s["min_clearance"]["certified"] and asked == []
    model, scene, mode, result = seen[0]
    fresh = collision_summary(model, scene, mode, dataclasses.replace(result, constraint=None))
    assert len(asked) == 1 and {k: s[k] for k in fresh if k != "collision_mode"} == {
        k: v for k, v in fresh.items() if k != "collision_mode"}
    moved = dataclasses.replace(result, coeffs=result.coeffs * (1 + 1e-12))
    collision_summary(model, scene, mode, moved)
    assert len(asked) == 2


def test_world_capsules_are_the_rotated_and_translated_ends_with_a_sphere_s_b_its_a(lbr7_scene):  # noqa: F811
    """``world_capsules`` (every primitive at every sample, written out without einsum's broadcast) equals R·a + t and
    R·b + t by ``np.einsum`` from the body poses, on a scene of capsules and one of spheres along them (b is a)."""
    import hoc_cli.collision.evaluate as ev

    model, scene = lbr7_scene
    q = np.random.default_rng(18).uniform(-2.5, 2.5, (40, model.n))
    for sc in (scene, sphere_rows_scene(scene)):
        a, b = ev.world_capsules(model, sc, q)
        body, la, lb = ev._primitive_frames(model, sc)
        T = ev._poses(model, q)[:, np.where(body < 0, model.n, body)]
        for got, x in ((a, la), (b, lb)):
            ref = np.einsum("kpij,pj->kpi", T[..., :3, :3], x) + T[..., :3, 3]
            np.testing.assert_allclose(got, ref, rtol=0, atol=1e-15)
        ball = np.all(sc.robot.a == sc.robot.b, axis=1)
        assert ball.any() == (sc is not scene) and np.array_equal(a[:, ball], b[:, ball])


def test_the_effort_rows_gradient_takes_the_vjp_from_the_torques_pass(monkeypatch):
    """The limits' penalty at a point with effort rows active makes one Newton-Euler pass (the torques'), its VJP
    reusing it: Φ and its gradient bit for bit those of a system without kept passes (two passes)."""
    from hoc_cli.dynamics import _passes

    make, C, _ = _limit_terms()

    class Plain:  # the System without inverse_dynamics_kept: torques and VJP in passes of their own
        def __init__(self, system):
            self.s = system

        def inverse_dynamics(self, q, dq, ddq):
            return self.s.inverse_dynamics(q, dq, ddq)

        def id_vjp(self, q, dq, ddq, lam):
            return self.s.id_vjp(q, dq, ddq, lam)

    terms = make()
    plain = dataclasses.replace(terms, system=Plain(terms.system))
    passes = []
    forward = _passes._forward
    monkeypatch.setattr(_passes, "_forward", lambda *a, **k: passes.append(1) or forward(*a, **k))
    ref = plain.evaluate(C)
    assert len(passes) == 2
    got = terms.evaluate(C)
    assert len(passes) == 3  # one more pass: the torques' alone
    assert np.any(ref.grad) and got.value == ref.value and np.array_equal(got.grad, ref.grad)


def test_the_distances_of_spheres_to_boxes_take_one_product_per_box_with_each_entry_s_numbers(lbr7_scene):  # noqa: F811
    """``distances`` puts the sphere centres in each box's frame with one product per box (``_box_frames``): the numbers
    of a 1 × 3 by 3 × 3 product per entry bit for bit, and every distance that of ``pair_contacts`` (the contact path),
    among three turned boxes, centres inside and outside."""
    from hoc_cli.collision.evaluate import _box_frames, _cached, _obstacle_arrays, _sphere_box_columns, distances, pair_contacts, world_capsules
    from hoc_cli.collision.scene import KIND_BOX, Obstacle, collision_scene
    from hoc_cli.collision.shapes import Box

    model, base = lbr7_scene
    rng = np.random.default_rng(21)
    turn = [np.linalg.qr(rng.normal(size=(3, 3)))[0] for _ in range(3)]
    boxes = [Obstacle(f"box{i}", Box(rng.uniform(-0.4, 0.4, 3) + [0.3, 0.0, 0.5], R * np.sign(np.linalg.det(R)),
                                     rng.uniform(0.05, 0.2, 3))) for i, R in enumerate(turn)]
    scene = sphere_rows_scene(collision_scene(model, base.robot, boxes, margin=0.02))
    q = rng.uniform(-2.5, 2.5, (70, model.n))
    cols, runs = _sphere_box_columns(scene)
    assert len(runs) == 3 and cols.size == np.sum(scene.kind == KIND_BOX)
    a, _ = world_capsules(model, scene, q)
    c = a[:, scene.prim[cols]]
    obs = _cached("obstacles", scene, lambda: _obstacle_arrays(scene))
    o = scene.other[cols]
    each = np.matmul((c - obs["center"][o])[..., None, :], obs["rot"][o])[..., 0, :]
    assert np.array_equal(_box_frames(c, runs, obs), each)
    D = distances(model, scene, q)
    rows, pairs = np.nonzero(np.ones(D.shape, bool))
    a, b = world_capsules(model, scene, q)
    assert np.array_equal(D.ravel(), pair_contacts(scene, a, b, rows, pairs).distance)
    assert (D[:, cols] < 0).any() and (D[:, cols] > 0).any()


def test_the_limits_gradient_at_the_first_step_s_secant_point_reuses_its_values(monkeypatch):
    """The first step evaluates the limits at C + dC without the gradient (its effort secant); the line search's unit
    trial asks the gradient there: the values, the torques' pass and Φ are taken from that evaluation (one ``_values``
    call at C + dC), and the result is a fresh evaluation's bit for bit."""
    make, C, dC = _limit_terms()
    ref = make().evaluate(C + dC)
    terms = make()
    calls = []
    values = LimitTerms._values
    monkeypatch.setattr(LimitTerms, "_values", lambda self, C: calls.append(np.array(C)) or values(self, C))
    limit_rows(terms, C, dC)               # the first step from C: the limits at C and at C + dC, no gradient
    got = terms.evaluate(C + dC)           # the unit trial: the gradient at C + dC
    assert len(calls) == 2, len(calls)
    assert got.value == ref.value and np.array_equal(got.grad, ref.grad) and np.any(got.grad)
    for a, b in zip(got.mu_lo + got.mu_hi + got.g_lo + got.g_hi, ref.mu_lo + ref.mu_hi + ref.g_lo + ref.g_hi):
        assert np.array_equal(a, b)


def test_the_limits_newton_blocks_take_the_effort_points_of_the_evaluation_at_their_point(monkeypatch):
    """The Newton blocks at the point just evaluated take that evaluation's (q, q̇, q̈) at the effort points: one
    ``PointSet.apply`` at C instead of two, the blocks those made afresh."""
    from hoc_cli.constraints.points import PointSet

    make, C, _ = _limit_terms()
    ref = make().newton_blocks(C)
    terms = make()
    calls = []
    apply = PointSet.apply
    monkeypatch.setattr(PointSet, "apply", lambda self, C: calls.append(1) or apply(self, C))
    terms.evaluate(C)
    blocks = terms.newton_blocks(C.copy())
    assert len(calls) == 1 and np.array_equal(blocks, ref)
    eff = terms.working[-1].any() and any(np.any(m) for m in (terms.evaluate(C).mu_lo[-1], terms.evaluate(C).mu_hi[-1]))
    assert eff  # effort rows active: the blocks need the points
