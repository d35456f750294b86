"""Clearance certified between samples: a thin obstacle crossed between samples is caught, a clear motion is
certified, and the certified lower bound never exceeds the densely sampled true minimum."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hoc_cli.collision.certify import certify, pair_speeds
from hoc_cli.collision.evaluate import distances
from hoc_cli.collision.geometry import Shape
from hoc_cli.collision.robot import robot_geometry
from hoc_cli.collision.scene import Obstacle, collision_scene
from hoc_cli.collision.shapes import Box, HalfSpace, sphere
from hoc_cli.dynamics.kinematics import link_poses
from hoc_cli.elements import HermiteMesh
from hoc_cli.io.collision_geometry import read_collision_shapes
from hoc_cli.model import load_robot
from tests._robots import ERD, ROBOTS


def rest_to_rest(mesh, q0, q1):
    """Hermite coefficients (N+1, 3, n) of the quintic blend q0 → q1 at rest at both ends."""
    T = mesh.T
    s = mesh.nodes / T
    b = 10 * s**3 - 15 * s**4 + 6 * s**5
    db = (30 * s**2 - 60 * s**3 + 30 * s**4) / T
    ddb = (60 * s - 180 * s**2 + 120 * s**3) / T**2
    dq = q1 - q0
    return np.stack([q0 + np.outer(b, dq), np.outer(db, dq), np.outer(ddb, dq)], axis=1)


@pytest.fixture(scope="module")
def lbr7():
    model = load_robot(ROBOTS / "lbr7.urdf")
    shapes = {"lbr_link_7": [Shape("sphere", np.eye(4), radius=0.04)],
              "lbr_link_4": [Shape("capsule", np.eye(4), radius=0.05, a=np.zeros(3), b=np.array([0, 0, 0.2]))]}
    return model, robot_geometry(model, {}, shapes)


def base_swing() -> tuple[HermiteMesh, np.ndarray]:
    """The lbr7's base joint from −1.2 to 1.2 rad at rest to rest in 1 s, on 2 quintic elements."""
    q0 = np.array([-1.2, 0.8, 0, -0.6, 0, 0.5, 0])
    q1 = q0.copy()
    q1[0] = 1.2
    mesh = HermiteMesh("quintic", 1.0, 2)
    return mesh, rest_to_rest(mesh, q0, q1)


def test_a_thin_plate_crossed_between_samples_is_caught(lbr7):
    model, robot = lbr7
    mesh, C = base_swing()
    # a 2 mm plate across the wrist's path at t = 0.45 s, between two 10 Hz samples
    poses = link_poses(model, mesh.evaluate(C, np.array([0.449, 0.45, 0.451])))["lbr_link_7"][:, :3, 3]
    normal = (poses[2] - poses[0]) / np.linalg.norm(poses[2] - poses[0])
    R = Rotation.align_vectors([normal], [[0, 1.0, 0]])[0].as_matrix()  # the plate's thin axis y along the path
    plate = Obstacle("plate", Box(poses[1], R, np.array([0.1, 0.001, 0.1])))
    scene = collision_scene(model, robot, [plate], self_collision=False, margin=0.01)
    samples = np.linspace(0, 1, 11)  # 10 Hz: every sample is clear
    assert distances(model, scene, mesh.evaluate(C, samples)).min() > 0.01
    assert distances(model, scene, mesh.evaluate(C, mesh.nodes)).min() > 0.01
    dense = distances(model, scene, mesh.evaluate(C, np.linspace(0, 1, 20001)))
    assert dense.min() < 0  # it does go through
    cert = certify(model, scene, mesh, C)
    assert not cert.certified and cert.lower_bound < 0
    assert cert.collisions and all(c["pair"][1] == "plate" for c in cert.collisions)
    assert any(c["certain"] and c["depth"] > 0 for c in cert.collisions)
    hit = [c for c in cert.collisions if c["certain"]]
    t_hit = np.linspace(0, 1, 20001)[(dense < 0).any(axis=1)]
    assert min(c["interval"][0] for c in hit) <= t_hit.min() and max(c["interval"][1] for c in hit) >= t_hit.max()
    assert cert.distance < 0 and cert.pair[1] == "plate"


def test_a_clear_motion_is_certified(lbr7):
    model, robot = lbr7
    mesh, C = base_swing()
    wall = Obstacle("wall", Box(np.array([0.0, 0.0, 1.6]), np.eye(3), np.array([1.0, 1.0, 0.05])))
    floor = Obstacle("floor", HalfSpace(np.array([0, 0, -0.05]), np.array([0, 0, 1.0])))
    scene = collision_scene(model, robot, [wall, floor], margin=0.01)
    cert = certify(model, scene, mesh, C)
    dense = distances(model, scene, mesh.evaluate(C, np.linspace(0, 1, 4001))).min()
    assert cert.certified and cert.collisions == ()
    assert 0.01 <= cert.lower_bound <= dense <= cert.distance
    s = cert.summary()
    assert s["min_clearance"]["certified"] and s["collisions"] == []


@pytest.fixture(scope="module")
def panda():
    path = ERD / "panda_description/urdf/panda.urdf"
    model = load_robot(path, joints=[f"panda_joint{i}" for i in range(1, 8)], locked={"panda_finger_joint1": 0.02})
    return model, robot_geometry(model, read_collision_shapes(path))


@pytest.mark.parametrize("seed", range(6))
def test_the_certified_bound_never_exceeds_the_dense_minimum(panda, seed):
    """Random smooth trajectories among random obstacles: the certified bound is below the densely sampled minimum,
    tight enough to prove a margin 2 cm below it, and the pair speed bound V holds between dense samples."""
    model, robot = panda
    rng = np.random.default_rng(seed)
    N = int(rng.integers(1, 5))
    mesh = HermiteMesh("quintic", float(rng.uniform(0.5, 2.0)), N)
    home = np.array([0, -0.785, 0, -2.356, 0, 1.571, 0.785])
    C = np.stack([home + rng.normal(size=(N + 1, model.n)) * 0.6, rng.normal(size=(N + 1, model.n)),
                  rng.normal(size=(N + 1, model.n)) * 3], axis=1)
    obstacles = [Obstacle(f"box{i}", Box(rng.uniform([0.2, -0.5, 0.0], [0.7, 0.5, 0.8]),
                                         Rotation.random(random_state=seed * 10 + i).as_matrix(),
                                         rng.uniform(0.01, 0.15, 3))) for i in range(3)]
    obstacles += [Obstacle("ball", sphere(rng.uniform([0.2, -0.5, 0.2], [0.6, 0.5, 0.8]), 0.08)),
                  Obstacle("floor", HalfSpace(np.array([0, 0, -0.2]), np.array([0, 0, 1.0])))]
    t = np.linspace(0, mesh.T, 1000 * N + 1)
    scene = collision_scene(model, robot, obstacles)
    D = distances(model, scene, mesh.evaluate(C, t))
    low = D.min()
    # a margin just above the sampled minimum is violated: never certified, and the bound is below the minimum
    scene = collision_scene(model, robot, obstacles, margin=low + 1e-9)
    cert = certify(model, scene, mesh, C)
    assert not cert.certified and cert.lower_bound <= low + 1e-12 and cert.distance <= low + 1e-9
    worst = scene.names[int(np.argmin(D.min(axis=0)))]
    t_worst = t[int(np.argmin(D.min(axis=1)))]
    assert any(c["pair"] == list(worst) and c["interval"][0] <= t_worst <= c["interval"][1] for c in cert.collisions)
    # 2 cm below it, the clearance is proven on the whole trajectory
    scene = collision_scene(model, robot, obstacles, margin=low - 0.02)
    cert = certify(model, scene, mesh, C)
    assert cert.certified and cert.collisions == () and low - 0.02 <= cert.lower_bound <= low + 1e-12
    # the Lipschitz bound itself, element by element
    V = pair_speeds(model, scene, mesh, C)
    e = np.minimum((t / mesh.h).astype(int), N - 1)
    rate = np.abs(np.diff(D, axis=0)) / np.diff(t)[:, None]
    same = e[1:] == e[:-1]
    assert np.all(rate[same] <= V[e[1:][same]] * (1 + 1e-6) + 1e-9)


def test_no_pairs_is_trivially_certified(lbr7):
    model, robot = lbr7
    scene = collision_scene(model, robot, [], self_collision=False)
    mesh = HermiteMesh("quintic", 1.0, 2)
    cert = certify(model, scene, mesh, rest_to_rest(mesh, np.zeros(7), np.ones(7)))
    assert cert.certified and cert.summary() == {"min_clearance": None, "collisions": []}


def test_velocity_bounds_on_sub_intervals_enclose_and_tighten():
    """The Bernstein bound of |q̇| on [s0, s1] is >= every sampled |q̇| there, and within 1 % of it on short pieces."""
    from hoc_cli.collision.certify import velocity_bounds
    from hoc_cli.constraints.extrema import element_polynomials

    rng = np.random.default_rng(4)
    for mesh in (HermiteMesh("quintic", 1.3, 5), HermiteMesh("cubic", 0.7, 3)):
        n = 3
        C = rng.normal(size=(mesh.N + 1, mesh.m, n))
        poly = element_polynomials(mesh, C, 1)
        M = 40
        e = rng.integers(0, mesh.N, M)
        s0 = rng.uniform(0, 0.9, M)
        for width in (None, 1e-3):
            s1 = rng.uniform(s0, 1.0) if width is None else s0 + width
            B = velocity_bounds(poly, e, s0, s1)
            sig = np.linspace(0, 1, 201)
            t = mesh.nodes[e][:, None] + (s0[:, None] + sig * (s1 - s0)[:, None]) * mesh.hs[e][:, None]
            v = np.abs(mesh.evaluate(C, t.ravel(), 1).reshape(M, sig.size, n)).max(axis=1)
            assert np.all(B >= v * (1 - 1e-12) - 1e-12)
            if width is not None:
                assert np.all(B <= v * 1.01 + 1e-9)
