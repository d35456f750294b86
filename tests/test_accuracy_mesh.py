"""Non-uniform meshes (``HermiteMesh.breaks``) and the h-refinement of ``N: auto``.

References: polynomials the elements reproduce exactly, quadrature of known integrals, dense sums
over the samples, central differences, the analytic 1-DOF optima (rest to rest: J* = 6D²/T³; with a
velocity limit: ``velocity_limited_optimum``), the two-link arm refined far (uniform, N = 256) and
``N: auto`` with uniform doubling on the same problem.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from hoc_cli.accuracy import AUTO_SAFETY, correction_indicators, estimate, marked, plan_auto
from hoc_cli.banded import element_blocks
from hoc_cli.constraints import JointLimits
from hoc_cli.constraints.augmented_lagrangian import MARGIN
from hoc_cli.constraints.bounds import KINDS
from hoc_cli.constraints.penalty import LimitRows, LimitTerms
from hoc_cli.elements import HermiteMesh
from hoc_cli.model import load_robot
from hoc_cli.optimize import check_gradient
from hoc_cli.planner import plan, resample
from hoc_cli.problem import ControlProblem
from hoc_cli.system import LinearOscillator, RobotSystem
from tests._robots import ROBOTS
from tests.test_accuracy import GOOD_AUTO, TWO_LINK, _task
from tests.test_limits_enforce import velocity_limited_optimum

NODES = np.array([0.0, 0.07, 0.2, 0.26, 0.5, 0.61, 0.9, 1.1, 1.14, 1.5])  # 9 elements, lengths 0.04 to 0.3 s


@pytest.fixture(scope="module")
def arm():
    return RobotSystem(load_robot(ROBOTS / "two_link.urdf"))


@pytest.mark.parametrize("order", ["cubic", "quintic"])
def test_a_polynomial_of_the_elements_degree_is_reproduced_exactly_on_a_non_uniform_mesh(order):
    mesh = HermiteMesh.from_nodes(order, NODES)
    deg = 3 if order == "cubic" else 5
    c = np.arange(1.0, deg + 2) * (-0.7) ** np.arange(deg + 1)
    poly = np.polynomial.Polynomial(c)
    C = mesh.interpolate(poly, poly.deriv(1), poly.deriv(2))
    t = np.linspace(0.0, 1.5, 301)
    for r in range(3):
        assert np.allclose(mesh.evaluate(C, t, r)[:, 0], poly.deriv(r)(t), rtol=0, atol=1e-11)
    op = mesh.quadrature(6)
    q, dq, ddq = op.apply(C)
    assert np.allclose(q[:, 0], poly(op.t), atol=1e-12) and np.allclose(ddq[:, 0], poly.deriv(2)(op.t), atol=1e-10)
    assert op.integrate(np.cos(op.t)) == pytest.approx(np.sin(1.5), rel=1e-13)


def test_the_quadrature_transpose_and_the_newton_blocks_match_dense_sums_on_a_non_uniform_mesh():
    mesh = HermiteMesh.from_nodes("quintic", NODES)
    op = mesh.quadrature(7)
    rng = np.random.default_rng(1)
    n = 2
    C, D = rng.normal(size=(2, mesh.N + 1, 3, n))
    g = [rng.normal(size=(op.K, n)) for _ in range(3)]
    assert sum(np.sum(a * b) for a, b in zip(g, op.apply(C))) == pytest.approx(np.sum(op.transpose(*g) * C), rel=1e-12)
    S = rng.normal(size=(op.K, 3 * n, 3 * n))
    Hs = S @ np.swapaxes(S, 1, 2)  # per-sample Hessians in (q, q̇, q̈)
    blocks = element_blocks(op, Hs)
    loc = mesh.local_coefficients(D).reshape(mesh.N, -1)
    via_blocks = np.einsum("ei,eij,ej->", loc, blocks, loc)
    X = np.concatenate(op.apply(D), axis=1)  # (K, 3n): q, q̇, q̈ at the samples
    dense = np.einsum("k,ki,kij,kj->", op.w, X, Hs, X)
    assert via_blocks == pytest.approx(dense, rel=1e-12)


@pytest.mark.parametrize("cost", ["covariant", "torque"])
def test_the_gradient_matches_central_differences_on_a_non_uniform_mesh(arm, cost):
    mesh = HermiteMesh.from_nodes("quintic", NODES)
    problem = ControlProblem(arm, mesh, *TWO_LINK, cost=cost)
    x = problem.initial_guess() + 0.05 * np.random.default_rng(2).normal(size=problem.layout.size)
    assert check_gradient(problem.value, x, problem.evaluate(x).grad).max_rel_error < 1e-7


def test_the_limit_terms_gradient_matches_central_differences_on_a_non_uniform_mesh(arm):
    mesh = HermiteMesh.from_nodes("quintic", [0.0, 0.15, 0.6, 1.0])
    problem = ControlProblem(arm, mesh, [0.0, 0.0], [0.0, 0.0], [1.2, -0.6], [0.0, 0.0])
    limits = JointLimits.from_arrays(arm.joint_names, lower=[-0.1, -0.5], upper=[0.9, 0.2], velocity=[1.0, 0.5],
                                     acceleration=[3.0, 2.0], effort=[20.0, 5.0])
    rows = LimitRows.build(mesh, problem.layout.free, 2)
    rng = np.random.default_rng(5)
    lam = [tuple(rng.uniform(0, 1, rows.shape(k, 2)) * (rng.uniform(size=rows.shape(k, 2)) < 0.3) for k in range(len(KINDS)))
           for _ in range(2)]
    terms = LimitTerms(arm, limits, rows, np.ones((len(KINDS), 2), bool), lam[0], lam[1], rho=50.0, margin=MARGIN)
    x = problem.initial_guess() + 0.05 * rng.normal(size=problem.layout.size)
    g = problem.layout.pack(terms.evaluate(problem.coefficients(x)).grad)
    assert np.count_nonzero(g) > 10
    check = check_gradient(lambda z: terms.evaluate(problem.coefficients(z), grad=False).value, x, g)
    assert check.max_rel_error < 1e-6


def test_the_limit_rows_of_a_non_uniform_mesh_bound_the_plan_everywhere():
    from hoc_cli.constraints.extrema import extrema

    mesh = HermiteMesh.from_nodes("quintic", NODES)
    C = np.random.default_rng(3).normal(size=(mesh.N + 1, 3, 1))
    rows = LimitRows.build(mesh, np.ones(C.size, bool), 1)
    loc = mesh.local_coefficients(C)
    t = np.linspace(0.0, 1.5, 3001)
    e, _ = mesh.element_of(t)
    for r in range(3):
        beta = rows.apply(r, loc)[:, :, 0]  # (N, R): Bernstein coefficients enclose the element's values
        v = mesh.evaluate(C, t, r)[:, 0]
        assert np.all(v <= beta.max(axis=1)[e] + 1e-9) and np.all(v >= beta.min(axis=1)[e] - 1e-9)
        ex = extrema(mesh, C, r)
        assert np.all(ex.max[:, 0][e] >= v - 1e-9) and v.max() == pytest.approx(ex.max.max(), rel=1e-3)


def test_splitting_elements_changes_no_value_and_j_stays_the_same_to_rounding(arm):
    result = plan(arm, HermiteMesh("quintic", 1.5, 8), *TWO_LINK, cost="torque")
    fine = result.mesh.split([1, 2, 6])
    assert fine.N == 11 and not fine.uniform
    C = resample(result.mesh, result.coeffs, fine)
    t = np.linspace(0.0, 1.5, 777)
    for r in range(3):
        assert np.allclose(fine.evaluate(C, t, r), result.mesh.evaluate(result.coeffs, t, r), rtol=0, atol=1e-11)
    problem = ControlProblem(arm, fine, *TWO_LINK, cost="torque", G=result.G)
    assert problem.value(problem.layout.pack(C)) == pytest.approx(result.J, rel=1e-13)
    refined = plan(arm, fine, *TWO_LINK, cost="torque", C_init=C, G=result.G)
    assert refined.converged and refined.J <= result.J * (1 + 1e-13)


def test_the_rest_to_rest_optimum_is_exact_on_any_non_uniform_mesh():
    system = LinearOscillator(1, omega=0.0)
    D, T = 0.8, 1.5
    mesh = HermiteMesh.from_nodes("quintic", NODES * (T / 1.5))
    result = plan(system, mesh, [0.0], [0.0], [D], [0.0], tol=1e-13)
    assert result.J == pytest.approx(6 * D**2 / T**3, rel=1e-11)  # ½∫q̈² of the cubic


def test_a_non_uniform_mesh_converges_to_the_same_optimum_as_uniform_ones(arm):
    J_star = plan(arm, HermiteMesh("quintic", 1.5, 256), *TWO_LINK, cost="torque").J
    start = plan(arm, HermiteMesh("quintic", 1.5, 16), *TWO_LINK, cost="torque")
    errors = []
    for k in (1, 2, 4, 8):  # every element of the graded mesh split into k: h_max halves, the order shows
        mesh = HermiteMesh.from_nodes("quintic", NODES)
        for _ in range(k.bit_length() - 1):
            mesh = mesh.split(np.arange(mesh.N))
        r = plan(arm, mesh, *TWO_LINK, cost="torque", C_init=resample(start.mesh, start.coeffs, mesh))
        assert r.converged
        errors.append((r.J - J_star) / J_star)
    assert errors[-1] < 1e-8 and all(e > 0 for e in errors)  # measured 3.4e-3, 1.8e-4, 1.7e-6, 4.8e-9
    assert all(a / b > 2**4 for a, b in zip(errors, errors[1:])), errors


def test_the_estimate_on_a_non_uniform_mesh_uses_the_bisected_mesh_and_brackets_the_true_error(arm):
    J_star = plan(arm, HermiteMesh("quintic", 1.5, 256), *TWO_LINK, cost="torque").J
    mesh = HermiteMesh.from_nodes("quintic", NODES)
    result = plan(arm, mesh, *TWO_LINK, cost="torque", C_init=resample(
        HermiteMesh("quintic", 1.5, 16), plan(arm, HermiteMesh("quintic", 1.5, 16), *TWO_LINK, cost="torque").coeffs,
        mesh))
    err = estimate(arm, result, cost="torque")
    assert err.refined.mesh == mesh.split(np.arange(mesh.N)) and err.basis["factor"] == 2.0
    true = (result.J - J_star) / result.J
    assert true / 2 <= err.relative <= 2 * true, (err.relative, true)
    zeta = correction_indicators(arm, result, err.refined, "torque")
    gain = result.J - err.refined.J
    assert zeta.shape == (mesh.N,) and np.all(zeta >= 0) and 0.5 * gain <= zeta.sum() <= 2 * gain


def test_marking_takes_the_fewest_elements_holding_the_share():
    eta = np.array([0.1, 5.0, 0.2, 3.0, 1.0, 0.7])
    assert marked(eta, 0.5).tolist() == [1]
    assert marked(eta, 0.8).tolist() == [1, 3]
    assert marked(np.zeros(4), 0.8).tolist() == [0, 1, 2, 3]


def test_h_refinement_reaches_the_velocity_limited_optimum_with_fewer_elements_than_doubling():
    system = LinearOscillator(1, omega=0.0)
    limits = JointLimits.from_arrays(system.joint_names, velocity=[1.3])
    J_star = velocity_limited_optimum(1.0, 1.0, 1.3)
    found = {refine: plan_auto(system, "quintic", 1.0, [0.0], [0.0], [1.0], [0.0], limits=limits, accuracy=1e-6,
                               refine=refine) for refine in ("h", "uniform")}
    for refine, f in found.items():
        assert f.reached and 0 <= (f.plan.J - J_star) / J_star <= 1e-6, refine
        Js = [s["J"] for s in f.steps]
        assert all(b <= a * (1 + 1e-10) for a, b in zip(Js, Js[1:])), (refine, Js)
    h, uniform = found["h"], found["uniform"]
    assert not h.plan.mesh.uniform and h.steps[-1]["mesh"] == "nonuniform"
    true = (h.plan.J - J_star) / h.plan.J  # the estimate on the non-uniform mesh (order from the uniform one)
    assert true / 2 <= h.error.relative <= 2 * true, (h.error.relative, true, h.error.basis)
    assert 2 * h.plan.mesh.N <= uniform.plan.mesh.N, (h.plan.mesh.N, uniform.plan.mesh.N)
    hs = h.plan.mesh.hs  # the small elements are where the limit becomes active or inactive, not in the cruise
    t_small = h.plan.mesh.nodes[:-1][hs < hs.max()]
    t1 = 1.5 * (1.0 - 1.0 / 1.3)
    assert np.all(np.minimum(np.abs(t_small - t1), np.abs(t_small - (1.0 - t1))) < 0.2)
    assert h.plan.limits.check.violations() == []


def test_n_auto_keeps_the_last_converged_plan_when_a_finer_mesh_fails_to_converge(monkeypatch):
    import hoc_cli.accuracy as accuracy

    system = LinearOscillator(1, omega=0.0)
    limits = JointLimits.from_arrays(system.joint_names, velocity=[1.3])
    real, meshes = accuracy.plan, []

    class Failed:  # the plan on a split mesh, reported as not converged (as an SQP that gave up would be)
        converged = False

        def __init__(self, plan) -> None:
            self.plan = plan

        def __getattr__(self, name):
            return getattr(self.plan, name)

    def failing_on_split_meshes(system, mesh, *args, **kw):
        meshes.append(mesh)
        result = real(system, mesh, *args, **kw)
        return result if mesh.uniform else Failed(result)

    monkeypatch.setattr(accuracy, "plan", failing_on_split_meshes)
    found = plan_auto(system, "quintic", 1.0, [0.0], [0.0], [1.0], [0.0], limits=limits, accuracy=1e-9)
    assert any(not m.uniform for m in meshes) and not found.reached
    assert found.plan.converged and found.plan.mesh.uniform  # the last converged plan, not the failed one
    assert found.steps[-1]["converged"] is False and found.steps[-2]["N"] == found.plan.mesh.N
    assert found.error.relative is not None and found.error.relative > 1e-9 / AUTO_SAFETY


def test_n_auto_bounds_the_error_by_the_coarser_estimate_when_the_estimate_s_own_solve_fails(monkeypatch):
    import hoc_cli.accuracy as accuracy

    system = LinearOscillator(1, omega=0.0)
    limits = JointLimits.from_arrays(system.joint_names, velocity=[1.3])
    real = accuracy.estimate

    def failing_on_split_meshes(system, result, **kw):  # as when the solve on the bisected mesh stalls
        err = real(system, result, **kw)
        return err if result.mesh.uniform else accuracy.ErrorEstimate(None, {"method": "failed"})

    monkeypatch.setattr(accuracy, "estimate", failing_on_split_meshes)
    found = plan_auto(system, "quintic", 1.0, [0.0], [0.0], [1.0], [0.0], limits=limits, accuracy=1e-6)
    assert not found.plan.mesh.uniform and found.plan.converged
    basis = found.error.basis
    assert basis["method"].startswith("bound from the coarser mesh")
    J, Jc = found.plan.J, basis["J_coarser"]
    assert found.error.relative == pytest.approx((abs(Jc - J) + basis["estimate_coarser"] * abs(Jc)) / J, rel=1e-12)
    J_star = velocity_limited_optimum(1.0, 1.0, 1.3)
    assert (J - J_star) / J <= found.error.relative  # an upper bound of the true error


def test_hoc_plan_n_auto_writes_a_non_uniform_plan_that_init_and_read_plan_accept(tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from hoc_cli.cli import app
    from hoc_cli.io.mcap import read_plan

    p = _task(tmp_path, GOOD_AUTO + "accuracy: 1.0e-6\nlimits:\n  velocity: {shoulder: 1.1}\n")
    monkeypatch.chdir(tmp_path)
    out = CliRunner().invoke(app, ["plan", str(p), "-o", "arm.mcap", "-o", "arm.csv", "--json", "-q"])
    assert out.exit_code == 0, out.output
    s = json.loads(out.stdout)
    assert s["mesh"] == "nonuniform" and len(s["nodes"]) == s["N"] + 1 and s["J_error_estimate"] <= 1e-6 / AUTO_SAFETY
    assert [step["mesh"] for step in s["N_auto"]][0] == "uniform" and s["N_auto"][-1]["mesh"] == "nonuniform"
    stored = read_plan(tmp_path / "arm.mcap")
    assert stored.trajectory.mesh.nodes.tolist() == s["nodes"]
    again = CliRunner().invoke(app, ["plan", str(p), "-N", "32", "--init", "arm.mcap", "-o", "b.csv", "--json", "-q"])
    assert again.exit_code == 0, again.output
    a = json.loads(again.stdout)
    assert a["mesh"] == "uniform" and abs(a["cost"] - s["cost"]) <= 1e-5 * s["cost"]
    sim = CliRunner().invoke(app, ["simulate", "arm.mcap", "-o", "sim.csv", "--json", "-q"])
    assert sim.exit_code == 0, sim.output
    replay = json.loads(sim.stdout)  # on the plan's own non-uniform mesh
    assert replay["N"] == s["N"] and replay["final_error"] < 1e-6


@pytest.mark.parametrize("order", ["quintic", "cubic"])
def test_simulating_the_plans_torque_on_its_non_uniform_mesh_returns_the_plan(arm, order):
    """The collocation replay (its own Newton solves) finds the plan's nodes; NODES ends with an element
    9 times longer than the one before it (the predictor is then the left node's Taylor polynomial)."""
    from hoc_cli.simulate import simulate_hermite
    from hoc_cli.torque import PlannedTorque

    mesh = HermiteMesh.from_nodes(order, NODES)
    result = plan(arm, mesh, *TWO_LINK, cost="torque", tol=1e-12)
    sim = simulate_hermite(arm, np.array(TWO_LINK[0]), np.array(TWO_LINK[1]), PlannedTorque(arm, mesh, result.coeffs),
                           mesh)
    assert sim.mesh == mesh
    assert np.allclose(sim.coeffs[:, :2], result.coeffs[:, :2], rtol=0, atol=1e-9)


def test_equal_node_times_given_explicitly_give_the_uniform_meshs_operators_to_rounding(arm):
    """The non-uniform code path (per-element scaling) against the uniform one on the same geometry."""
    uniform = HermiteMesh("quintic", 1.5, 6)
    given = HermiteMesh.from_nodes("quintic", uniform.nodes)
    assert not given.uniform
    rng = np.random.default_rng(7)
    C = rng.normal(size=(7, 3, 2))
    for a, b in zip(uniform.quadrature(7).apply(C), given.quadrature(7).apply(C)):
        assert np.allclose(a, b, rtol=1e-13, atol=1e-12)
    limits = JointLimits.from_arrays(arm.joint_names, lower=[-0.1, -0.5], upper=[0.9, 0.2], velocity=[1.0, 0.5],
                                     acceleration=[3.0, 2.0], effort=[20.0, 5.0])
    out = []
    for mesh in (uniform, given):
        problem = ControlProblem(arm, mesh, *TWO_LINK, cost="covariant")
        x = problem.layout.pack(C)
        ev = problem.evaluate(x)
        rows = LimitRows.build(mesh, problem.layout.free, 2)
        lam = tuple(np.full(rows.shape(k, 2), 0.1) for k in range(len(KINDS)))
        terms = LimitTerms(arm, limits, rows, np.ones((len(KINDS), 2), bool), lam, lam, rho=50.0, margin=MARGIN)
        pv = terms.evaluate(C)
        out.append((ev.J, ev.grad, element_blocks(problem.op_h, problem.hessian_samples(ev)[1]), pv.value, pv.grad,
                    terms.newton_blocks(C)))
    for a, b in zip(*out):
        assert np.allclose(a, b, rtol=1e-11, atol=1e-9 * np.max(np.abs(a)))
