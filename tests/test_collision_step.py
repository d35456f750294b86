"""The Newton iteration's first trial step with the penalty rows it would activate (``collision.step``): the model's
minimiser against a dense grid, its rows against finite differences, the optimiser's hook, and a plan's evaluations."""
from __future__ import annotations

import numpy as np
import pytest

from hoc_cli.collision.step import limit_rows, model_step
from hoc_cli.constraints import JointLimits
from hoc_cli.constraints.augmented_lagrangian import MARGIN
from hoc_cli.constraints.bounds import EFFORT, KINDS
from hoc_cli.constraints.penalty import LimitRows, LimitTerms
from hoc_cli.elements import HermiteMesh
from hoc_cli.model import load_robot
from hoc_cli.optimize import minimize
from hoc_cli.problem import ControlProblem
from hoc_cli.system import RobotSystem
from tests._robots import ROBOTS
from tests.test_collision_enforce import lbr7_scene, swing_rows  # noqa: F401  (the fixture)


def _model(alpha, slope, a, b, rho):
    """m(α) of ``collision.step`` on a grid α (G,): the Newton model plus the rows inactive at 0 that rise."""
    s = (a <= 0) & (b > 0)
    arg = np.maximum(0.0, a[s, None] + alpha[None] * b[s, None])
    return slope * (alpha - alpha ** 2 / 2) + 0.5 * np.sum(rho[s, None] * arg ** 2, axis=0)


@pytest.mark.parametrize("seed", range(6))
def test_the_first_step_minimises_the_model_with_the_rows_the_step_activates(seed):
    rng = np.random.default_rng(seed)
    M = 200
    a = rng.uniform(-1.0, 0.3, M)                 # some rows active already (a > 0): in the Newton matrix, left out
    b = rng.normal(size=M) * rng.uniform(0.1, 3.0, M)  # rising and falling rows
    rho = 10 ** rng.uniform(-2, 2, M)
    slope = -10 ** rng.uniform(-1, 1)
    alpha = model_step(slope, a, b, rho)
    grid = np.linspace(0.0, 1.0, 200_001)
    ref = grid[np.argmin(_model(grid, slope, a, b, rho))]
    assert 0 < alpha < 1 and alpha == pytest.approx(ref, abs=2e-5)


def test_without_a_row_rising_to_its_bound_within_the_step_the_first_step_is_one():
    a, b, rho = np.array([-1.0, -2.0, 0.5, -np.inf]), np.array([0.5, -1.0, 3.0, 1.0]), np.ones(4)
    assert model_step(-1.0, a, b, rho) == 1.0      # the first row reaches its bound at α = 2, the others never
    assert model_step(-1.0, a, 2.5 * b, rho) < 1.0  # ... at 0.8 when it rises faster


def test_the_optimiser_starts_its_line_search_at_the_first_step():
    A = np.diag([1.0, 4.0, 9.0])
    x_star = np.array([1.0, -2.0, 0.5])
    f = lambda x: (0.5 * (x - x_star) @ A @ (x - x_star), A @ (x - x_star), x)  # noqa: E731

    class Exact:
        def solve(self, g):
            return np.linalg.solve(A, g)

    asked = []
    res = minimize(f, np.zeros(3), precondition=lambda x: Exact(), method="newton", c2=0.9, max_iter=1,
                   first_step=lambda x, d, slope: asked.append((d, slope)) or 0.5)
    assert len(asked) == 1 and asked[0][1] == pytest.approx(float(-x_star @ A @ x_star))
    np.testing.assert_allclose(res.x, 0.5 * x_star, rtol=1e-12)  # the half step satisfies Wolfe (c2 = 0.9): taken


def test_the_collision_rows_rates_along_a_step_are_their_directional_derivatives(lbr7_scene):  # noqa: F811
    model, scene = lbr7_scene
    C, points, D, terms = swing_rows(model, scene, near=0.2, every=3)
    dC = np.random.default_rng(2).normal(size=C.shape) * 0.1
    dC[0] = dC[-1] = 0.0
    a, b, rho = terms.step_rows(C, dC)
    h = 1e-6
    fd = -(terms.distances(C + h * dC) - terms.distances(C - h * dC)) / (2 * h)
    d = terms.distances(C)
    np.testing.assert_allclose(a, terms.lam / terms.rho_rows + 0.03 - d, rtol=1e-12, atol=1e-15)
    assert np.median(np.abs(b - fd)) < 1e-7 * np.abs(fd).max() and np.mean(np.abs(b - fd) < 1e-5) >= 0.95
    np.testing.assert_array_equal(rho, terms.rho_rows)


def test_the_limit_rows_along_a_step_are_exact_for_kinematic_limits():
    model = load_robot(ROBOTS / "two_link.urdf")
    system = RobotSystem(model)
    problem = ControlProblem(system, HermiteMesh("quintic", 1.5, 6), [0.0, 0.0], [0.0, 0.0], [1.2, -0.6], [0.0, 0.0])
    limits = JointLimits.from_arrays(model.joint_names, lower=[-0.1, -0.5], upper=[0.9, 0.2], velocity=[1.0, 0.5],
                                     acceleration=[3.0, 2.0])
    rows = LimitRows.build(problem.mesh, problem.layout.free, 2)
    rng = np.random.default_rng(3)
    lam = [tuple(rng.uniform(0, 1, rows.shape(k, 2)) * (rng.uniform(size=rows.shape(k, 2)) < 0.3)
                 for k in range(len(KINDS))) for _ in range(2)]
    working = np.zeros((len(KINDS), 2), bool)
    working[:3] = True  # position, velocity and acceleration rows
    terms = LimitTerms(system, limits, rows, working, lam[0], lam[1], rho=300.0, margin=MARGIN)
    C = problem.coefficients(problem.initial_guess())
    dC = problem.layout.unpack(rng.normal(size=problem.layout.size) * 0.3, np.zeros_like(C))
    a, b, rho = limit_rows(terms, C, dC)
    for alpha in (0.0, 0.37, 1.0, 2.5):  # λ/ρ_w + g at C + α dC, row by row in the same order
        pv = terms.evaluate(C + alpha * dC, grad=False)
        ref = []
        for kk in range(len(KINDS)):
            rw = np.broadcast_to(terms.rho * rows.weight(kk), np.shape(pv.g_lo[kk]))
            ref += [(terms.lam_lo[kk] / rw + pv.g_lo[kk]).ravel(), (terms.lam_hi[kk] / rw + pv.g_hi[kk]).ravel()]
        ref = np.concatenate(ref)
        on = np.isfinite(ref)
        assert on.sum() > 50 and np.all(np.isneginf(a[~on]))
        np.testing.assert_allclose(a[on] + alpha * b[on], ref[on], rtol=1e-10, atol=1e-12)
    assert np.all(rho > 0)
    limits = JointLimits.from_arrays(model.joint_names, lower=[-0.1, -0.5], upper=[0.9, 0.2], effort=[5.0, 2.0])
    working = np.zeros((len(KINDS), 2), bool)
    working[0] = working[EFFORT] = True  # effort's rate is the secant: exact at α = 0 and 1
    terms = LimitTerms(system, limits, rows, working, lam[0], lam[1], rho=300.0, margin=MARGIN)
    a, b, _ = limit_rows(terms, C, dC)
    for alpha in (0.0, 1.0):
        pv = terms.evaluate(C + alpha * dC, grad=False)
        ref = np.concatenate([x for kk in range(len(KINDS)) for x in (
            (terms.lam_lo[kk] / np.broadcast_to(terms.rho * rows.weight(kk), np.shape(pv.g_lo[kk])) + pv.g_lo[kk]).ravel(),
            (terms.lam_hi[kk] / np.broadcast_to(terms.rho * rows.weight(kk), np.shape(pv.g_hi[kk])) + pv.g_hi[kk]).ravel())])
        on = np.isfinite(ref)
        assert on.sum() > 50
        np.testing.assert_allclose(a[on] + alpha * b[on], ref[on], rtol=1e-10, atol=1e-12)



def test_a_panda_plan_past_a_wall_takes_fewer_evaluations_with_the_first_step_in_the_same_minimum(tmp_path, monkeypatch):
    """Problem 0 of benchmarks/bench_collision.py (the Panda reaching past a wall over a table, URDF limits):
    certified both ways, J within 1e-4, and the first step saves evaluations (measured: 264 instead of 465)."""
    import hoc_cli.planner as planner
    from tests._collision_tasks import plan
    from tests._robots import ERD

    box = lambda name, size, position: {"name": name, "box": {"size": size}, "position": position}  # noqa: E731
    doc = {"robot": str(ERD / "panda_description/urdf/panda.urdf"), "joints": [f"panda_joint{i}" for i in range(1, 8)],
           "locked": {"panda_finger_joint1": 0.02}, "T": 2.0, "N": 8,
           "x0": {"q": [-1.2198, 0.4961, 0.0157, -1.8804, 0.0542, 2.3956, 0.9271]},
           "x1": {"q": [1.0944, 0.2102, -0.0935, -1.7938, -0.3488, 2.1672, 0.5981]},
           "collision": {"margin": 0.01, "srdf": str(ERD / "panda_description/srdf/panda.srdf"), "obstacles": [
               box("table", [0.6, 1.4, 0.04], [0.55, 0.0, 0.0]), box("wall", [0.2263, 0.04, 0.3795], [0.5312, 0.0, 0.2]),
               box("box0", [0.071, 0.0796, 0.052], [0.4935, 0.5012, 0.1]),
               box("box1", [0.0953, 0.0931, 0.0769], [0.799, -0.5943, 0.1])]}}
    monkeypatch.chdir(tmp_path)
    r, s = plan(tmp_path, doc)
    monkeypatch.setattr(planner, "_first_step", lambda problem: None)  # the unit step
    r0, s0 = plan(tmp_path, doc)
    assert r.exit_code == 0 and r0.exit_code == 0, r.stderr + r0.stderr
    assert s["min_clearance"]["certified"] and s0["min_clearance"]["certified"] and s["converged"] and s0["converged"]
    assert s["cost"] == pytest.approx(s0["cost"], rel=1e-4)
    assert s["evaluations"] < 0.75 * s0["evaluations"], (s["evaluations"], s0["evaluations"])
