"""Signed distances of every primitive pair against coal (penetration included), and their gradients."""
import zlib

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hoc_cli.collision.distance import capsule_box, capsule_capsule, capsule_capsule_distance, capsule_halfspace
from hoc_cli.collision.evaluate import distance_gradient, distances, pair_gradient
from hoc_cli.collision.robot import robot_geometry
from hoc_cli.collision.scene import Obstacle, collision_scene
from hoc_cli.collision.shapes import Box, HalfSpace, cylinder_capsule, sphere
from hoc_cli.io.collision_geometry import read_collision_shapes
from hoc_cli.model import load_robot
from tests._robots import ERD

coal = pytest.importorskip("coal")
SAMPLES = 300


def _frame(a, b):
    """Rotation taking z to b − a, and the midpoint (coal's capsules and cylinders are centred, along z)."""
    d = b - a
    L = np.linalg.norm(d)
    z = d / L if L > 0 else np.array([0.0, 0.0, 1.0])
    x = np.cross(z, [1.0, 0, 0] if abs(z[0]) < 0.9 else [0, 1.0, 0])
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1), (a + b) / 2, L


def _coal_distance(s1, T1, s2, T2):
    req = coal.DistanceRequest()
    req.enable_signed_distance = True
    res = coal.DistanceResult()
    coal.distance(s1, coal.Transform3s(*T1), s2, coal.Transform3s(*T2), req, res)
    return res.min_distance


def _coal_capsule(a, b, r):
    R, c, L = _frame(a, b)
    return (coal.Sphere(r) if L == 0 else coal.Capsule(r, L)), (R, c)


def _random_capsules(rng, spheres: bool):
    """SAMPLES segments (a, b) and radii; points (a = b) when ``spheres``; close enough to overlap often."""
    a = rng.normal(size=(SAMPLES, 3)) * 0.25
    b = a if spheres else a + rng.normal(size=(SAMPLES, 3)) * 0.3
    return a, b.copy(), rng.uniform(0.01, 0.2, SAMPLES)


@pytest.mark.parametrize("kind_a", ["sphere", "capsule"])
@pytest.mark.parametrize("kind_b", ["sphere", "capsule", "box", "half_space"])
def test_signed_distance_equals_coal_to_1e_9_including_penetration(kind_a, kind_b):
    rng = np.random.default_rng(zlib.crc32(f"{kind_a}-{kind_b}".encode()))
    a1, b1, r1 = _random_capsules(rng, kind_a == "sphere")
    if kind_b in ("sphere", "capsule"):
        a2, b2, r2 = _random_capsules(rng, kind_b == "sphere")
        ours = capsule_capsule(a1, b1, r1, a2, b2, r2).distance
        ref = [_coal_distance(*_coal_capsule(a1[i], b1[i], r1[i]), *_coal_capsule(a2[i], b2[i], r2[i]))
               for i in range(SAMPLES)]
    elif kind_b == "box":
        R = Rotation.random(SAMPLES, random_state=1).as_matrix()
        c, h = rng.normal(size=(SAMPLES, 3)) * 0.2, rng.uniform(0.02, 0.3, (SAMPLES, 3))
        ours = capsule_box(a1, b1, r1, c, R, h).distance
        ref = [_coal_distance(*_coal_capsule(a1[i], b1[i], r1[i]), coal.Box(*(2 * h[i])), (R[i], c[i]))
               for i in range(SAMPLES)]
    else:
        n = rng.normal(size=(SAMPLES, 3))
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        o = rng.normal(size=SAMPLES) * 0.2
        ours = capsule_halfspace(a1, b1, r1, n, o).distance
        ref = [_coal_distance(*_coal_capsule(a1[i], b1[i], r1[i]), coal.Halfspace(n[i], o[i]), (np.eye(3), np.zeros(3)))
               for i in range(SAMPLES)]
    ref = np.array(ref)
    assert np.abs(ours - ref).max() < 1e-9
    assert 0.05 < (ref < 0).mean() < 0.95  # both separated and penetrating poses are exercised


def test_degenerate_poses_equal_coal():
    """Parallel segments, a segment along a box axis, a segment inside a box, a segment crossing another."""
    cases = [
        (np.array([0, 0, 0.0]), np.array([1, 0, 0.0]), np.array([0.2, 0.1, 0]), np.array([0.8, 0.1, 0])),  # parallel
        (np.array([0, 0, 0.0]), np.array([1, 0, 0.0]), np.array([0.5, -1, 0]), np.array([0.5, 1, 0])),     # crossing
        (np.array([0, 0, 0.0]), np.array([1, 0, 0.0]), np.array([2, 0, 0]), np.array([3, 0, 0])),          # collinear
    ]
    for a1, b1, a2, b2 in cases:
        ours = capsule_capsule(a1, b1, 0.05, a2, b2, 0.07).distance
        ref = _coal_distance(*_coal_capsule(a1, b1, 0.05), *_coal_capsule(a2, b2, 0.07))
        assert ours == pytest.approx(ref, abs=1e-9)
    h = np.array([0.3, 0.2, 0.1])
    for a, b in [([-0.1, 0, 0], [0.1, 0, 0]), ([-1, 0.05, 0], [1, 0.05, 0]), ([0, 0, 0.5], [0, 0, 0.9]),
                 ([0.29, 0.19, 0.09], [0.29, 0.19, 0.09])]:
        a, b = np.array(a, float), np.array(b, float)
        ours = capsule_box(a, b, 0.02, np.zeros(3), np.eye(3), h).distance
        ref = _coal_distance(*_coal_capsule(a, b, 0.02), coal.Box(*(2 * h)), (np.eye(3), np.zeros(3)))
        assert ours == pytest.approx(ref, abs=1e-9)


def test_witnesses_and_normal_are_consistent():
    """point_a − point_b = d·n, and moving A by δ along u changes d by n·u δ (first order)."""
    rng = np.random.default_rng(5)
    a1, b1, r1 = _random_capsules(rng, False)
    R = Rotation.random(SAMPLES, random_state=2).as_matrix()
    c, h = rng.normal(size=(SAMPLES, 3)) * 0.2, rng.uniform(0.02, 0.3, (SAMPLES, 3))
    a2, b2, r2 = _random_capsules(rng, False)
    u = rng.normal(size=(SAMPLES, 3))
    eps = 1e-7
    for f, args in ((capsule_box, (c, R, h)), (capsule_capsule, (a2, b2, r2))):
        k = f(a1, b1, r1, *args)
        assert np.allclose(k.point_a - k.point_b, k.distance[:, None] * k.normal, atol=1e-12)
        assert np.allclose(np.linalg.norm(k.normal, axis=1), 1.0)
        fd = (f(a1 + eps * u, b1 + eps * u, r1, *args).distance - f(a1 - eps * u, b1 - eps * u, r1, *args).distance) / (2 * eps)
        assert np.median(np.abs(fd - np.einsum("ij,ij->i", k.normal, u))) < 1e-6
        assert (np.abs(fd - np.einsum("ij,ij->i", k.normal, u)) < 1e-5).mean() > 0.97  # except at kinks


def test_a_cylinder_as_its_capsule_never_overestimates_the_distance():
    rng = np.random.default_rng(3)
    a1, b1, r1 = _random_capsules(rng, False)
    R = Rotation.random(SAMPLES, random_state=3).as_matrix()
    for i in range(SAMPLES):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R[i], rng.normal(size=3) * 0.2
        radius, length = rng.uniform(0.02, 0.2), rng.uniform(0.05, 0.6)
        cap = cylinder_capsule(T, radius, length)
        ours = capsule_capsule(a1[i], b1[i], r1[i], cap.a, cap.b, cap.radius).distance
        ref = _coal_distance(*_coal_capsule(a1[i], b1[i], r1[i]), coal.Cylinder(radius, length), (T[:3, :3], T[:3, 3]))
        assert ours <= ref + 1e-9


@pytest.fixture(scope="module")
def panda():
    path = ERD / "panda_description/urdf/panda.urdf"
    model = load_robot(path, joints=[f"panda_joint{i}" for i in range(1, 8)], locked={"panda_finger_joint1": 0.02})
    obstacles = [Obstacle("table", Box(np.array([0.5, 0, 0.3]), Rotation.from_euler("z", 0.3).as_matrix(), np.array([0.2, 0.3, 0.02]))),
                 Obstacle("ball", sphere([0.3, 0.3, 0.5], 0.1)),
                 Obstacle("floor", HalfSpace(np.array([0, 0, -0.1]), np.array([0, 0, 1.0])))]
    return model, collision_scene(model, robot_geometry(model, read_collision_shapes(path)), obstacles)


def test_distance_gradient_with_respect_to_q_matches_central_differences(panda):
    model, scene = panda
    rng = np.random.default_rng(0)
    q = rng.uniform(np.maximum(model.lower, -2.5), np.minimum(model.upper, 2.5), (6, model.n))
    d, g = distance_gradient(model, scene, q)
    assert d.shape == (6, scene.size) and g.shape == (6, scene.size, model.n)
    h = 1e-6
    fd = np.stack([(distances(model, scene, q + h * e) - distances(model, scene, q - h * e)) / (2 * h)
                   for e in np.eye(model.n)], axis=-1)
    err = np.abs(fd - g).max(axis=-1)
    assert np.median(err) < 1e-8
    assert (err < 1e-6).mean() > 0.98  # the rest: kinks (a witness switching ends), where d is not differentiable
    assert set(scene.kind.tolist()) == {0, 1, 2, 3}


def test_batched_distances_equal_one_sample_at_a_time(panda):
    model, scene = panda
    q = np.random.default_rng(1).uniform(-1, 1, (5, model.n))
    batch = distances(model, scene, q)
    for k in range(5):
        assert np.array_equal(batch[k], distances(model, scene, q[k:k + 1])[0])


def test_pair_gradient_on_chosen_rows_and_pairs_equals_the_full_grid(panda):
    model, scene = panda
    q = np.random.default_rng(2).uniform(-1, 1, (4, model.n))
    d, g = distance_gradient(model, scene, q)
    rng = np.random.default_rng(3)
    rows, pairs = rng.integers(0, 4, 50), rng.integers(0, scene.size, 50)
    d1, g1 = pair_gradient(model, scene, q, rows, pairs)
    assert np.array_equal(d1, d[rows, pairs]) and np.allclose(g1, g[rows, pairs], rtol=0, atol=1e-15)


def test_pair_hessian_matches_central_differences_of_the_gradient(panda):
    """∇²d of every kind of row the penalty takes (spheres against a box, a ball and a floor; capsule self pairs;
    capsules against the ball) equals the central differences of ∂d/∂q, where d is twice differentiable."""
    from hoc_cli.collision.constraint import sphere_rows_scene
    from hoc_cli.collision.evaluate import pair_hessian

    model, scene = panda
    rng = np.random.default_rng(7)
    q = rng.uniform(np.maximum(model.lower, -2.0), np.minimum(model.upper, 2.0), (16, model.n))
    kinds = set()
    for sc in (sphere_rows_scene(scene), scene):
        rows, pairs = np.repeat(np.arange(len(q)), sc.size), np.tile(np.arange(sc.size), len(q))
        d, _ = pair_gradient(model, sc, q, rows, pairs)
        capsule_box = (sc.kind[pairs] == 2) & np.any(sc.robot.a[sc.prim[pairs]] != sc.robot.b[sc.prim[pairs]], axis=1)
        keep = (d > 0) & (d < 0.4) & ~capsule_box  # a capsule against a box: its witness's slide is left out
        rows, pairs = rows[keep], pairs[keep]
        H = pair_hessian(model, sc, q, rows, pairs)
        h = 1e-6
        fd = np.zeros_like(H)
        for j, e in enumerate(np.eye(model.n)):
            fd[:, j] = (pair_gradient(model, sc, q + h * e, rows, pairs)[1]
                        - pair_gradient(model, sc, q - h * e, rows, pairs)[1]) / (2 * h)
        fd = 0.5 * (fd + np.swapaxes(fd, 1, 2))
        err = np.abs(H - fd).max(axis=(1, 2)) / np.maximum(np.abs(fd).max(axis=(1, 2)), 1e-2)
        assert np.allclose(H, np.swapaxes(H, 1, 2))
        for k in np.unique(sc.kind[pairs]):
            e = err[sc.kind[pairs] == k]
            assert np.median(e) < 1e-6 and np.mean(e < 1e-5) > 0.97, (k, np.median(e), np.max(e))  # the rest: kinks
            kinds.add(int(k))
    assert kinds == {0, 1, 2, 3}


def test_two_capsules_distance_alone_is_the_contacts_distance_bit_for_bit():
    """``capsule_capsule_distance`` (the distances of every pair at the points, the certificate) gives
    ``capsule_capsule``'s numbers: random, crossing, parallel and point segments."""
    rng = np.random.default_rng(11)
    M = 2000
    a1, b1, a2, b2 = (rng.normal(size=(M, 3)) for _ in range(4))
    b2[:200] = a2[:200] + (b1[:200] - a1[:200])          # parallel
    b1[200:300] = a1[200:300]                             # points
    b2[250:350] = a2[250:350]
    mid = 0.5 * (a1[400:500] + b1[400:500])               # crossing: the second segment through the first's midpoint
    a2[400:500], b2[400:500] = mid - 0.3 * rng.normal(size=(100, 3)), mid
    r1, r2 = rng.uniform(0.0, 0.2, M), rng.uniform(0.0, 0.2, M)
    assert np.array_equal(capsule_capsule_distance(a1, b1, r1, a2, b2, r2), capsule_capsule(a1, b1, r1, a2, b2, r2).distance)
