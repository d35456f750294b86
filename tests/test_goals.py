"""Goals beyond a joint state: residual and row derivatives against central differences (cubic and
quintic), end-effector goals checked with Pinocchio's forward kinematics and against plans to
inverse-kinematics solutions, via points met to 1e-12 and never cheaper than the plan without them."""
from __future__ import annotations

import numpy as np
import pytest

from hoc_cli.dynamics import link_poses, link_velocity
from hoc_cli.elements import HermiteMesh
from hoc_cli.goals import (
    FrameResidual,
    GoalPoint,
    GoalProblem,
    Goals,
    GoalTerms,
    JointResidual,
    inverse_kinematics,
    plan_goals,
    quaternion_matrix,
    rotation_angle,
)
from hoc_cli.model import load_robot
from hoc_cli.planner import plan
from hoc_cli.system import LinearOscillator, RobotSystem
from tests._robots import ROBOTS, PinocchioOracle

LBR = load_robot(ROBOTS / "lbr7.urdf")
Q0 = np.array([0.0, 0.6, 0.0, -1.4, 0.0, 0.9, 0.0])
QG = np.array([0.5, 0.4, 0.2, -1.1, 0.1, 1.1, 0.2])
FLANGE = "lbr_flange"


def moving_target(orientation=True, match=True):
    P = link_poses(LBR, QG)[FLANGE]
    return FrameResidual(LBR, FLANGE, P[:3, 3] - [0.05, 0.0, 0.1], orientation=P[:3, :3] if orientation else None,
                         velocity=np.array([0.1, -0.05, 0.3]), acceleration=np.array([0.0, 0.0, -0.5]),
                         match_velocity=match)


def test_frame_residual_derivatives_against_central_differences():
    res = moving_target()
    rng = np.random.default_rng(3)
    q, dq, T = QG + 0.1 * rng.standard_normal(7), rng.standard_normal(7), 0.7
    c, cq, cv, cT = res(q, dq, T)
    assert c.shape == (9,) and cq.shape == cv.shape == (9, 7)
    h = 1e-6
    E = np.eye(7)
    fq = np.stack([(res(q + h * E[j], dq, T)[0] - res(q - h * E[j], dq, T)[0]) / (2 * h) for j in range(7)], axis=1)
    fv = np.stack([(res(q, dq + h * E[j], T)[0] - res(q, dq - h * E[j], T)[0]) / (2 * h) for j in range(7)], axis=1)
    fT = (res(q, dq, T + h)[0] - res(q, dq, T - h)[0]) / (2 * h)
    assert np.allclose(cq, fq, atol=1e-8) and np.allclose(cv, fv, atol=1e-8) and np.allclose(cT, fT, atol=1e-8)


def test_orientation_residual_is_sin_theta_times_the_axis():
    R = quaternion_matrix([0.9, 0.1, -0.3, 0.2])
    axis = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
    th = 0.4
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    Rth = np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K
    assert abs(rotation_angle(Rth @ R, R) - th) < 1e-14
    assert np.allclose(quaternion_matrix([1, 0, 0, 0]), np.eye(3))
    assert np.allclose(quaternion_matrix([2, 0, 0, 0]) @ quaternion_matrix([0.5, 0.5, 0.5, 0.5]).T @
                       quaternion_matrix([0.5, 0.5, 0.5, 0.5]), np.eye(3))


@pytest.mark.parametrize("order", ["cubic", "quintic"])
def test_goal_rows_gradient_and_time_derivative_against_central_differences(order):
    """Ψ = Σ λc + ½ρc² over a link via off the nodes, a joint via off the nodes and a moving link goal."""
    system = RobotSystem(LBR)
    T, N = 0.8, 3
    mesh = HermiteMesh(order, T, N)
    res = moving_target()
    vias = (GoalPoint(0.4, JointResidual(QG - 0.2, np.full(7, 0.1))),
            GoalPoint(0.55, FrameResidual(LBR, FLANGE, np.array([0.5, 0.1, 0.6]), quaternion_matrix([0, 1, 0, 0]))))
    goals = Goals(final=res, vias=vias, q1_guess=QG, dq1_guess=np.full(7, 0.2))
    problem = GoalProblem(system, mesh, Q0, np.zeros(7), goals)
    assert len(problem.points) == 3
    rng = np.random.default_rng(0)
    lam = [rng.standard_normal(p.residual.size) for p in problem.points]
    terms = GoalTerms(mesh, problem.points, lam, rho=3.0)
    x = problem.initial_guess() + 0.05 * rng.standard_normal(problem.layout.size)
    C = problem.coefficients(x)
    _, G = terms.evaluate(C)
    g = problem.layout.pack(G)
    h = 1e-6
    for j in rng.choice(x.size, 25, replace=False):
        e = np.zeros(x.size)
        e[j] = h
        fd = (terms.evaluate(problem.coefficients(x + e), grad=False)[0]
              - terms.evaluate(problem.coefficients(x - e), grad=False)[0]) / (2 * h)
        assert abs(g[j] - fd) < 1e-6 * max(1.0, abs(fd)), j
    # ∂Ψ/∂T with the s-domain coefficients fixed: Σ μ ∂c/∂T (the value's own derivative is Σ μ ∂c/∂T too)
    from hoc_cli.free_time import rescale

    def psi(Tn):
        return GoalTerms(HermiteMesh(order, Tn, N), problem.points, lam, 3.0).evaluate(rescale(C, T, Tn), grad=False)[0]

    dT, _ = terms.time_derivative(C, T)
    fd = (psi(T + h) - psi(T - h)) / (2 * h)
    assert abs(dT - fd) < 1e-6 * max(1.0, abs(fd))


def test_newton_blocks_hold_the_gauss_newton_part_exactly_for_joint_rows():
    """For linear rows Ψ's Hessian is ρ DᵀD: the blocks against central differences of the gradient."""
    system = LinearOscillator(2)
    mesh = HermiteMesh("quintic", 1.0, 2)
    goals = Goals(q1=np.ones(2), dq1=np.zeros(2), vias=(GoalPoint(0.3, JointResidual(np.array([0.2, -0.1]))),))
    problem = GoalProblem(system, mesh, np.zeros(2), np.zeros(2), goals)
    terms = GoalTerms(mesh, problem.points, [np.array([0.5, -1.0])], rho=2.0)
    x = np.random.default_rng(1).standard_normal(problem.layout.size)
    from hoc_cli.banded import BandedSPD

    blocks = terms.newton_blocks(problem.coefficients(x))
    mn = mesh.m * 2
    H = np.zeros(((mesh.N + 1) * mn,) * 2)
    for e in range(mesh.N):
        H[e * mn:e * mn + 2 * mn, e * mn:e * mn + 2 * mn] += blocks[e]
    H = H[np.ix_(problem.layout.free, problem.layout.free)]
    h = 1e-6
    cols = []
    for j in range(x.size):
        e = np.zeros(x.size)
        e[j] = h
        cols.append((problem.layout.pack(terms.evaluate(problem.coefficients(x + e))[1])
                     - problem.layout.pack(terms.evaluate(problem.coefficients(x - e))[1])) / (2 * h))
    assert np.allclose(H, np.stack(cols, axis=1), atol=1e-7)
    assert BandedSPD is not None


@pytest.fixture(scope="module")
def pose_goal_plan():
    P = link_poses(LBR, QG)[FLANGE]
    res = FrameResidual(LBR, FLANGE, P[:3, 3] + [0.0, 0.05, 0.0], orientation=P[:3, :3])
    q1 = inverse_kinematics(res, Q0, 1.0, LBR.lower, LBR.upper)
    result = plan_goals(RobotSystem(LBR), HermiteMesh("quintic", 1.0, 8), Q0, np.zeros(7),
                        Goals(final=res, q1_guess=q1))
    return res, result


def test_end_effector_pose_is_met_by_pinocchio_forward_kinematics(pose_goal_plan):
    res, result = pose_goal_plan
    assert result.converged and result.violation <= 1e-9
    qN = result.mesh.evaluate(result.coeffs, [result.mesh.T])[0]
    pose = PinocchioOracle(LBR).link_pose(qN, FLANGE)
    assert np.max(np.abs(pose[:3, 3] - res.position)) < 1e-9
    assert rotation_angle(pose[:3, :3], res.orientation) < 1e-9
    assert np.max(np.abs(result.coeffs[-1, 1])) == 0.0  # dq: zero by default: at rest at the goal


def test_end_effector_goal_is_no_costlier_than_plans_to_inverse_kinematics_solutions(pose_goal_plan):
    res, result = pose_goal_plan
    system = RobotSystem(LBR)
    rng = np.random.default_rng(7)
    seeds = [Q0, QG] + [QG + 0.3 * rng.standard_normal(7) for _ in range(3)]
    costs = []
    for seed in seeds:
        q1 = inverse_kinematics(res, seed, 1.0, LBR.lower, LBR.upper)
        if np.max(np.abs(res(q1, np.zeros(7), 1.0)[0])) > 1e-10:
            continue
        costs.append(plan(system, HermiteMesh("quintic", 1.0, 8), Q0, np.zeros(7), q1, np.zeros(7)).J)
    assert len(costs) >= 3
    assert result.J <= min(costs) * (1 + 1e-9), (result.J, costs)


@pytest.mark.parametrize("order", ["cubic", "quintic"])
def test_via_points_are_met_and_cost_at_least_the_free_plan(order):
    system = RobotSystem(load_robot(ROBOTS / "two_link.urdf"))
    q0, q1, z = np.array([0.0, 0.0]), np.array([1.0, -0.5]), np.zeros(2)
    mesh = HermiteMesh(order, 1.0, 10)
    free = plan(system, mesh, q0, z, q1, z)
    at_node = GoalPoint(0.3, JointResidual(np.array([0.6, 0.4]), np.array([0.5, 0.0])))  # s·N = 3: pinned
    off_node = GoalPoint(0.67, JointResidual(np.array([1.1, -0.2])))  # s·N = 6.7: an AL row
    result = plan_goals(system, mesh, q0, z, Goals(q1=q1, dq1=z, vias=(at_node, off_node)))
    assert result.converged
    assert len(result.problem.points) == 1
    q, dq, _ = mesh.evaluate_all(result.coeffs, np.array([0.3, 0.67]))
    assert np.array_equal(result.coeffs[3, 0], at_node.residual.q)  # node 3: the coefficients are q, q̇ there
    assert np.array_equal(result.coeffs[3, 1], at_node.residual.dq)
    assert np.max(np.abs(q[0] - at_node.residual.q)) <= 1e-12 and np.max(np.abs(dq[0] - at_node.residual.dq)) <= 1e-12
    assert np.max(np.abs(q[1] - off_node.residual.q)) <= 1e-12
    assert result.J >= free.J


def test_a_link_via_is_met_to_1e_12():
    model = load_robot(ROBOTS / "two_link.urdf")
    system = RobotSystem(model)
    q0, q1, z = np.array([0.0, 0.0]), np.array([1.0, -0.5]), np.zeros(2)
    mesh = HermiteMesh("quintic", 1.0, 10)
    target = link_poses(model, [0.5, 0.3])["tool"][:3, 3]  # x and z reachable (the arm moves in the x-z plane)
    via = GoalPoint(0.45, FrameResidual(model, "tool", target))
    result = plan_goals(system, mesh, q0, z, Goals(q1=q1, dq1=z, vias=(via,)))
    assert result.converged
    q = mesh.evaluate(result.coeffs, np.array([0.45]))[0]
    assert np.max(np.abs(link_poses(model, q)["tool"][:3, 3] - target)) <= 1e-12
    assert result.J >= plan(system, mesh, q0, z, q1, z).J


def test_matched_velocity_at_a_moving_target():
    """The catch at a fixed T: position and linear velocity of the link equal the target's at T."""
    system = RobotSystem(LBR)
    res = moving_target(orientation=False)
    T = 0.9
    q1 = inverse_kinematics(res, QG, T, LBR.lower, LBR.upper)
    result = plan_goals(system, HermiteMesh("quintic", T, 6), Q0, np.zeros(7),
                        Goals(final=res, q1_guess=q1, dq1_guess=np.zeros(7)))
    assert result.converged
    qN, dqN = result.coeffs[-1, 0], result.coeffs[-1, 1]
    p, v = res.target(T)
    assert np.max(np.abs(link_poses(LBR, qN)[FLANGE][:3, 3] - p)) < 1e-9
    assert np.max(np.abs(link_velocity(LBR, qN, dqN, FLANGE)[:3] - v)) < 1e-9


@pytest.fixture(scope="module")
def passing_target():
    """A target passing the arm at 0.25 m/s (through the flange position at QG at t = 0.8 s)."""
    v = np.array([0.0, 0.25, 0.0])
    pc = link_poses(LBR, QG)[FLANGE][:3, 3]
    res = FrameResidual(LBR, FLANGE, pc - 0.8 * v, velocity=v, match_velocity=True)
    q1 = inverse_kinematics(res, QG, 0.8, LBR.lower, LBR.upper)
    return Goals(final=res, q1_guess=q1, dq1_guess=np.zeros(7))


def test_goal_envelope_derivative_against_re_solved_optima(passing_target):
    from hoc_cli.free_time import plan_time_derivative, rescale

    system = RobotSystem(LBR)
    T, h = 0.4, 1e-4
    r = plan_goals(system, HermiteMesh("quintic", T, 4), Q0, np.zeros(7), passing_target)
    d = plan_time_derivative(r, system, goals=r.terms)

    def J(Tn):
        return plan_goals(system, HermiteMesh("quintic", Tn, 4), Q0, np.zeros(7), passing_target,
                          C_init=rescale(r.coeffs, T, Tn), terms=r.terms).J

    fd = (J(T + h) - J(T - h)) / (2 * h)
    assert abs(d - fd) < 1e-6 * abs(fd), (d, fd)


def test_catching_a_moving_target_in_a_free_final_time(passing_target):
    """With gravity the lbr7's covariant J*(T) has an interior minimum at weight 0; the link meets the
    target's position and velocity at the optimal T."""
    from hoc_cli.free_time import minimize_time
    from hoc_cli.goals.time_solver import goal_solver

    system = RobotSystem(LBR)
    ft = minimize_time(goal_solver(system, "quintic", 4, Q0, np.zeros(7), passing_target), 0.2, 1.2, guess=0.5,
                       rtol=1e-10)
    assert ft.bound is None and ft.result.converged
    assert abs(ft.dJ_dT) < 1e-8 * ft.J / ft.T
    qN, dqN = ft.result.coeffs[-1, 0], ft.result.coeffs[-1, 1]
    p, v = passing_target.final.target(ft.T)
    assert np.max(np.abs(PinocchioOracle(LBR).link_pose(qN, FLANGE)[:3, 3] - p)) < 1e-9
    assert np.max(np.abs(link_velocity(LBR, qN, dqN, FLANGE)[:3] - v)) < 1e-9
