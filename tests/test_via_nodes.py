"""Via times as mesh nodes (``hoc_cli.goals.mesh``): the element shares against a brute-force minimum of the
longest element, joint vias off the uniform mesh pinned and met to 1e-12, link vias at a node met to 1e-9,
J never below the plan without the via and J(N) converging at the orders measured here, the free-T
derivative on the scaled non-uniform mesh against central differences of J*(T), refinement keeping the
via nodes, and ``hoc plan`` with the shipped via task."""
from __future__ import annotations

import itertools
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from hoc_cli.cli import app
from hoc_cli.dynamics import link_poses
from hoc_cli.elements import HermiteMesh
from hoc_cli.free_time import minimize_time, plan_time_derivative
from hoc_cli.goals import FrameResidual, GoalPoint, GoalProblem, Goals, JointResidual, plan_goals
from hoc_cli.goals.mesh import node_index, scaled_mesh, via_fractions, via_mesh
from hoc_cli.goals.time_solver import goal_solver
from hoc_cli.model import load_robot
from hoc_cli.optimize import check_gradient
from hoc_cli.planner import plan
from hoc_cli.system import RobotSystem
from tests._robots import ROBOTS

ROOT = Path(__file__).resolve().parents[1]
MODEL = load_robot(ROBOTS / "two_link.urdf")
SYSTEM = RobotSystem(MODEL)
Q0, Q1, Z = np.zeros(2), np.array([1.2, -0.6]), np.zeros(2)
T = 1.5
VIA_Q, VIA_DQ = np.array([0.2, 0.6]), np.array([0.5, -0.3])


def joint_via(dq=VIA_DQ, t: float = 0.7) -> GoalPoint:
    return GoalPoint(t / T, JointResidual(VIA_Q, dq))


@pytest.mark.parametrize("N, fractions", [(5, [0.3]), (6, [0.13, 0.5]), (7, [0.05, 0.61, 0.62]), (4, [0.2, 0.4, 0.9])])
def test_the_shares_minimise_the_longest_element_and_put_each_via_on_a_node(N, fractions):
    """Brute force over every split of N into sub-intervals (at least one element each)."""
    f = via_fractions(N, fractions)
    assert f.shape == (N + 1,) and f[0] == 0.0 and f[-1] == 1.0 and np.all(np.diff(f) > 0)
    for s in fractions:
        assert np.min(np.abs(f - s)) == 0.0  # a node exactly
    lengths = np.diff([0.0, *sorted(fractions), 1.0])
    best = min(max(lengths / np.array(c)) for c in itertools.product(range(1, N + 1), repeat=len(lengths))
               if sum(c) == N)
    assert np.max(np.diff(f)) == pytest.approx(best, rel=1e-12)


def test_vias_on_uniform_nodes_keep_the_uniform_mesh_and_too_few_elements_are_refused():
    assert via_fractions(8, [0.25, 0.5]) is None and via_mesh("quintic", T, 8, [0.25]).uniform
    with pytest.raises(ValueError, match="expected N >= 3"):
        via_fractions(2, [0.3, 0.6])
    mesh = scaled_mesh("cubic", 2.0, 5, via_fractions(5, [0.3]))
    assert not mesh.uniform and mesh.nodes[-1] == 2.0 and node_index(0.3, mesh) is not None


@pytest.mark.parametrize("order", ["cubic", "quintic"])
def test_a_joint_via_off_the_uniform_mesh_is_pinned_and_met_to_1e_12(order):
    """t = 0.7 s with T = 1.5 s, N = 16 (uniform nodes every 0.09375 s): q and q̇ pinned at a node."""
    via = joint_via()
    assert node_index(via.s, HermiteMesh(order, T, 16)) is None
    mesh = via_mesh(order, T, 16, [via.s])
    assert mesh.N == 16 and not mesh.uniform
    result = plan_goals(SYSTEM, mesh, Q0, Z, Goals(q1=Q1, dq1=Z, vias=(via,)))
    assert result.converged and result.problem.points == []  # pinned: no row left
    p = node_index(via.s, mesh)
    assert np.array_equal(result.coeffs[p, 0], VIA_Q) and np.array_equal(result.coeffs[p, 1], VIA_DQ)
    q, dq = (mesh.evaluate(result.coeffs, np.array([0.7]), r)[0] for r in (0, 1))
    assert np.max(np.abs(q - VIA_Q)) <= 1e-12 and np.max(np.abs(dq - VIA_DQ)) <= 1e-12
    assert result.J >= plan(SYSTEM, HermiteMesh(order, T, 16), Q0, Z, Q1, Z).J


@pytest.mark.parametrize("order, dq, Ns, low", [
    ("cubic", None, (8, 16, 32, 64), 3.5),
    ("cubic", VIA_DQ, (8, 16, 32, 64), 3.5),
    ("quintic", None, (8, 16, 32), 7.0),
    ("quintic", VIA_DQ, (8, 16, 32, 64), 0.9),
])
def test_the_cost_converges_as_the_via_mesh_refines(order, dq, Ns, low):
    """Measured orders of J(N) − J(2N): h⁴ cubic, h⁸ quintic with q at the via. With q̇ pinned too, the
    optimum's q̈ jumps at the via (the multiplier of the q̇ row), which a C² quintic cannot follow: J
    converges (from above) at first order only, to the cubic's limit."""
    via = joint_via(dq)
    J = np.array([plan_goals(SYSTEM, via_mesh(order, T, N, [via.s]), Q0, Z, Goals(q1=Q1, dq1=Z, vias=(via,))).J
                  for N in Ns])
    d = np.diff(J)
    orders = np.log2(np.abs(d[:-1] / d[1:]))
    assert np.all(orders >= low) and np.all(orders <= low + 2.5), orders
    if order == "quintic" and dq is not None:
        assert np.all(d < 0)  # from above
        limit = plan_goals(SYSTEM, via_mesh("cubic", T, 64, [via.s]), Q0, Z, Goals(q1=Q1, dq1=Z, vias=(via,))).J
        assert abs(J[-1] + d[-1] - limit) < 0.1 * abs(J[-1] - limit)  # first-order Richardson: 10× closer


def test_a_link_via_at_a_node_is_met_to_1e_9():
    target = link_poses(MODEL, [0.5, 0.3])["tool"][:3, 3]
    via = GoalPoint(0.7 / T, FrameResidual(MODEL, "tool", target))
    mesh = via_mesh("quintic", T, 16, [via.s])
    result = plan_goals(SYSTEM, mesh, Q0, Z, Goals(q1=Q1, dq1=Z, vias=(via,)))
    assert result.converged and len(result.problem.points) == 1  # a row
    p = node_index(via.s, mesh)
    assert mesh.nodes[p] == pytest.approx(0.7, abs=1e-15)
    assert np.max(np.abs(link_poses(MODEL, result.coeffs[p, 0])["tool"][:3, 3] - target)) <= 1e-9
    assert result.J >= plan(SYSTEM, HermiteMesh("quintic", T, 16), Q0, Z, Q1, Z).J


def test_refinement_keeps_the_via_nodes():
    """``split`` bisects: the via node stays a node of every refined mesh and stays pinned."""
    via = joint_via()
    mesh = via_mesh("quintic", T, 8, [via.s])
    for elements in ([0, 3], [node_index(via.s, mesh) - 1, node_index(via.s, mesh)], range(mesh.N)):
        mesh = mesh.split(elements)
        assert node_index(via.s, mesh) is not None
        assert GoalProblem(SYSTEM, mesh, Q0, Z, Goals(q1=Q1, dq1=Z, vias=(via,))).points == []
    result = plan_goals(SYSTEM, mesh, Q0, Z, Goals(q1=Q1, dq1=Z, vias=(via,)))
    q = mesh.evaluate(result.coeffs, np.array([0.7]))[0]
    assert result.converged and np.max(np.abs(q - VIA_Q)) <= 1e-12


def test_free_time_vias_stay_nodes_and_dJ_dT_matches_central_differences():
    """A via at s = 0.4 (not a node of 16 equal elements): every solve of the search is on the mesh scaled
    to its T; at the optimum the via is met to 1e-12 and dJ*/dT (envelope theorem, fixed t-domain q̇ at the
    via) equals the central difference of J*(T) on the scaled meshes."""
    via = GoalPoint(0.4, JointResidual(VIA_Q, VIA_DQ))
    goals = Goals(q1=Q1, dq1=Z, vias=(via,))
    fractions = via_fractions(16, [0.4])
    solver = goal_solver(SYSTEM, "quintic", 16, Q0, Z, goals, fractions=fractions)
    ft = minimize_time(solver, 0.5, 3.0, guess=1.5, weight=20.0)
    assert ft.converged and ft.bound is None
    mesh, C = ft.result.mesh, ft.result.coeffs
    assert np.allclose(mesh.nodes, fractions * ft.T, rtol=0, atol=1e-15)
    q, dq = (mesh.evaluate(C, np.array([0.4 * ft.T]), r)[0] for r in (0, 1))
    assert np.max(np.abs(q - VIA_Q)) <= 1e-12 and np.max(np.abs(dq - VIA_DQ)) <= 1e-12
    Tc, h = 1.2, 1e-4
    J = [plan_goals(SYSTEM, scaled_mesh("quintic", t, 16, fractions), Q0, Z, goals, tol=1e-13).J for t in (Tc - h, Tc + h)]
    at = plan_goals(SYSTEM, scaled_mesh("quintic", Tc, 16, fractions), Q0, Z, goals, tol=1e-13)
    assert plan_time_derivative(at, SYSTEM) == pytest.approx((J[1] - J[0]) / (2 * h), rel=1e-6)


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    shutil.copy(ROBOTS / "two_link.urdf", tmp_path / "arm.urdf")
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_hoc_plan_puts_the_via_time_on_a_node_and_init_from_its_mcap_still_works(workdir):
    """configs/two_link_via.yaml (t = 0.7 s, T = 1.5 s, N = 16): the summary's nodes hold 0.7, the via
    is met exactly; ``--init`` from its MCAP (the non-uniform mesh stored) starts at the optimum."""
    task = ROOT / "configs" / "two_link_via.yaml"
    r = CliRunner().invoke(app, ["plan", str(task), "--json", "-q", "-o", "via.mcap"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["mesh"] == "nonuniform" and s["N"] == 16 and 0.7 in s["nodes"] and len(s["nodes"]) == 17
    assert s["vias"][0]["t"] == pytest.approx(0.7, abs=1e-15) and s["vias"][0]["error"] <= 1e-12
    r = CliRunner().invoke(app, ["plan", str(task), "--json", "-q", "--init", "via.mcap", "-o", "again.csv"])
    assert r.exit_code == 0, r.output
    again = json.loads(r.stdout)
    assert again["cost"] == pytest.approx(s["cost"], rel=1e-10) and again["iterations"] <= 2
    assert again["nodes"] == s["nodes"]


def test_too_few_elements_for_the_vias_is_a_task_error(workdir):
    (workdir / "task.yaml").write_text("robot: arm.urdf\nx0: {q: [0.0, 0.0]}\nx1: {q: [1.0, -0.5]}\nT: 1.0\nN: 2\n"
                                       "via: [{t: 0.3, q: [0.1, 0.1]}, {t: 0.6, q: [0.5, 0.1]}]\n")
    r = CliRunner().invoke(app, ["plan", "task.yaml", "-q", "-o", "out.csv"])
    assert r.exit_code == 2
    assert "N: 2 via times split the duration into 3 intervals" in r.output and "expected N >= 3" in r.output


@pytest.mark.parametrize("order", ["cubic", "quintic"])
def test_goal_rows_on_a_non_uniform_mesh_against_evaluation_and_central_differences(order):
    """Rows off the nodes of a non-uniform mesh (a joint via with q̇ and a link via): q, q̇ at the rows are
    ``mesh.evaluate``'s at s·T, Ψ's gradient and ∂Ψ/∂T (scaled mesh) match central differences."""
    from hoc_cli.free_time import rescale
    from hoc_cli.goals import GoalTerms

    fractions = np.array([0.0, 0.1, 0.35, 0.5, 0.8, 1.0])
    mesh = scaled_mesh(order, 1.2, 5, fractions)
    points = [GoalPoint(0.42, JointResidual(VIA_Q, VIA_DQ)),
              GoalPoint(0.9, FrameResidual(MODEL, "tool", link_poses(MODEL, [0.5, 0.3])["tool"][:3, 3]))]
    problem = GoalProblem(SYSTEM, mesh, Q0, Z, Goals(q1=Q1, dq1=Z, vias=tuple(points)))
    assert len(problem.points) == 2  # off the nodes: rows
    rng = np.random.default_rng(1)
    x = problem.initial_guess() + 0.1 * rng.standard_normal(problem.layout.size)
    C = problem.coefficients(x)
    lam = [rng.standard_normal(p.residual.size) for p in points]
    terms = GoalTerms(mesh, points, lam, rho=2.0)
    for r, p in zip(terms.residuals(C), points):
        t = np.array([p.s * mesh.T])
        assert np.allclose(r[4], mesh.evaluate(C, t)[0], rtol=0, atol=1e-14)
        assert np.allclose(r[5], mesh.evaluate(C, t, 1)[0], rtol=0, atol=1e-13)
    g = problem.layout.pack(terms.evaluate(C)[1])
    check = check_gradient(lambda y: terms.evaluate(problem.coefficients(y), grad=False)[0], x, g)
    assert check.max_rel_error < 1e-6
    h = 1e-6

    def psi(T):
        return GoalTerms(scaled_mesh(order, T, 5, fractions), points, lam, 2.0).evaluate(
            rescale(C, mesh.T, T), grad=False)[0]

    fd = (psi(mesh.T + h) - psi(mesh.T - h)) / (2 * h)
    assert terms.time_derivative(C, mesh.T)[0] == pytest.approx(fd, rel=1e-6, abs=1e-6)
