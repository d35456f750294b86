"""The Hermite collocation integrator, the reference integrator, torque sources and the period.

Reference values and their provenance
-------------------------------------
* Pendulum period τ = (4/ω) K(k), k = sin(q0/2) (complete elliptic integral of the first kind;
  scipy.special.ellipk takes m = k²): with ω = 3.102 s⁻¹ and q0 = π/12, τ = 2.0342381183283895 s
  (scipy 1.17). The paper prints 2.03452 s (ERRATA.md: matches neither form).
* Oscillator q̈ + q = 0, x0 = (0, 1): q = sin t. Damped q̈ + 2ζq̇ + q = 0, x0 = (1, 0):
  q = e^{−ζt}(cos ω_d t + ζ/ω_d sin ω_d t), q̇ = −e^{−ζt} sin(ω_d t)/ω_d, ω_d = √(1 − ζ²).
* Measured nodal orders (this file, oscillator): cubic·gauss 4, cubic·radau 3, cubic·lobatto 2,
  quintic·lobatto 6 (the default: 4-stage Lobatto IIIA collocation), quintic·gauss 6,
  quintic·radau 5. Quintic·gauss is unstable at ωh = 5, quintic·lobatto is not.
"""
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.special import ellipk

from hoc_cli.elements import HermiteMesh, gauss_legendre
from hoc_cli.errors import NumericalError
from hoc_cli.periods import oscillation_period, velocity_zeros
from hoc_cli.reference_integrator import simulate_reference
from hoc_cli.simulate import (
    _Element,
    collocation_points,
    collocation_residual,
    sample,
    simulate_hermite,
)
from hoc_cli.simulation_results import SimulationStatus
from hoc_cli.system import LinearOscillator
from hoc_cli.torque import ConstantTorque, PlannedTorque, SampledTorque, zero_torque
from hoc_cli.verification import convergence_order

ROBOTS = Path(__file__).resolve().parent.parent / "robots"
OMEGA, Q0 = 3.102, math.pi / 12
TAU = 4.0 / OMEGA * ellipk(math.sin(Q0 / 2) ** 2)
TAU_PAPER = 2.03452


# --------------------------------------------------------------------------- analytic systems
class Pendulum:
    """m l² q̈ + m g l sin q = u with g / l = ω² (SI), exact derivatives."""

    joint_names = ("theta",)
    n = 1

    def __init__(self, omega: float = OMEGA, g: float = 9.81, mass: float = 1.0) -> None:
        length = g / omega**2
        self.M, self.k = mass * length**2, mass * g * length

    def inverse_dynamics(self, q, dq, ddq):
        return self.M * np.asarray(ddq) + self.k * np.sin(q)

    def mass_matrix(self, q):
        return np.full((len(q), 1, 1), self.M)

    def forward_dynamics(self, q, dq, u):
        return (np.asarray(u) - self.k * np.sin(q)) / self.M

    def id_derivatives(self, q, dq, ddq):
        K = len(q)
        return self.inverse_dynamics(q, dq, ddq), (self.k * np.cos(q))[:, :, None], np.zeros((K, 1, 1)), self.mass_matrix(q)


class DampedOscillator:
    """q̈ + 2ζ q̇ + q = u (one joint): exercises ∂u/∂q̇."""

    joint_names = ("x",)
    n = 1

    def __init__(self, zeta: float = 0.1) -> None:
        self.zeta = zeta

    def inverse_dynamics(self, q, dq, ddq):
        return np.asarray(ddq) + 2 * self.zeta * np.asarray(dq) + np.asarray(q)

    def mass_matrix(self, q):
        return np.ones((len(q), 1, 1))

    def forward_dynamics(self, q, dq, u):
        return np.asarray(u) - 2 * self.zeta * np.asarray(dq) - np.asarray(q)

    def id_derivatives(self, q, dq, ddq):
        K = len(q)
        return self.inverse_dynamics(q, dq, ddq), np.ones((K, 1, 1)), np.full((K, 1, 1), 2 * self.zeta), np.ones((K, 1, 1))

    def exact(self, t):
        wd = math.sqrt(1 - self.zeta**2)
        decay = np.exp(-self.zeta * t)
        return decay * (np.cos(wd * t) + self.zeta / wd * np.sin(wd * t)), -decay * np.sin(wd * t) / wd


class CoupledVanDerPol:
    """Two van der Pol oscillators coupled through the mass matrix (n = 2), exact derivatives.

    u = M q̈ − μ (1 − q²) ⊙ q̇ + q with M = [[2, ε cos(q₀ − q₁)], [ε cos(q₀ − q₁), 1]]: full
    ∂u/∂q (through M), ∂u/∂q̇ and a non-diagonal M.
    """

    joint_names = ("a", "b")
    n = 2

    def __init__(self, mu: float = 0.7, eps: float = 0.4) -> None:
        self.mu, self.eps = mu, eps

    def mass_matrix(self, q):
        q = np.asarray(q)
        c = self.eps * np.cos(q[:, 0] - q[:, 1])
        M = np.empty((len(q), 2, 2))
        M[:, 0, 0], M[:, 1, 1], M[:, 0, 1], M[:, 1, 0] = 2.0, 1.0, c, c
        return M

    def inverse_dynamics(self, q, dq, ddq):
        q, dq, ddq = map(np.asarray, (q, dq, ddq))
        return np.einsum("kij,kj->ki", self.mass_matrix(q), ddq) - self.mu * (1 - q**2) * dq + q

    def forward_dynamics(self, q, dq, u):
        rhs = np.asarray(u) - self.inverse_dynamics(q, dq, np.zeros_like(np.asarray(q)))
        return np.linalg.solve(self.mass_matrix(q), rhs[..., None])[..., 0]

    def id_derivatives(self, q, dq, ddq):
        q, dq, ddq = map(np.asarray, (q, dq, ddq))
        K = len(q)
        ds = -self.eps * np.sin(q[:, 0] - q[:, 1])  # ∂M01/∂q0 = ds, ∂M01/∂q1 = −ds
        du_dq = np.zeros((K, 2, 2))
        du_dq[:, 0, 0], du_dq[:, 0, 1] = ds * ddq[:, 1], -ds * ddq[:, 1]
        du_dq[:, 1, 0], du_dq[:, 1, 1] = ds * ddq[:, 0], -ds * ddq[:, 0]
        du_dq += np.einsum("ki,ij->kij", 2 * self.mu * q * dq + 1.0, np.eye(2))
        du_ddq = np.einsum("ki,ij->kij", -self.mu * (1 - q**2), np.eye(2))
        return self.inverse_dynamics(q, dq, ddq), du_dq, du_ddq, self.mass_matrix(q)


def robot(name: str, **kwargs):
    path = ROBOTS / name
    from hoc_cli.model import load_robot
    from hoc_cli.system import RobotSystem

    return RobotSystem(load_robot(path, **kwargs))


def nodal_error(result, exact) -> float:
    q, dq = exact(result.mesh.nodes)
    return float(max(np.abs(result.coeffs[:, 0, 0] - q).max(), np.abs(result.coeffs[:, 1, 0] - dq).max()))


# --------------------------------------------------------------------------- collocation points, Jacobian
def test_collocation_points_are_gauss_radau_and_lobatto_nodes_on_the_unit_interval():
    np.testing.assert_allclose(collocation_points("quintic", "gauss"), gauss_legendre(3)[0], atol=1e-15)
    np.testing.assert_allclose(collocation_points("cubic", "radau"), [1 / 3, 1.0], atol=1e-15)
    np.testing.assert_allclose(collocation_points("quintic", "radau"), [(4 - 6**0.5) / 10, (4 + 6**0.5) / 10, 1.0], atol=1e-15)
    np.testing.assert_allclose(collocation_points("quintic", "lobatto"), [(1 - 5**-0.5) / 2, (1 + 5**-0.5) / 2, 1.0], atol=1e-15)
    np.testing.assert_allclose(collocation_points("cubic"), gauss_legendre(2)[0], atol=1e-15)
    with pytest.raises(ValueError, match="gauss"):
        collocation_points("quintic", "chebyshev")


@pytest.mark.parametrize("order", ["cubic", "quintic"])
@pytest.mark.parametrize("make", [Pendulum, DampedOscillator, CoupledVanDerPol, lambda: robot("lbr7.urdf")])
def test_newton_jacobian_matches_central_differences(order, make):
    system = make()
    rng = np.random.default_rng(3)
    mesh = HermiteMesh(order, 1.0, 7)
    el = _Element.build(mesh, collocation_points(order))
    m, n = mesh.m, system.n
    left, right, u = (rng.normal(size=(m, n)) for _ in range(3))
    F, J = collocation_residual(system, el, left, right, u)
    assert F.shape == (m, n) and J.shape == (m, n, m, n)
    eps = 1e-6
    for k in range(m):
        for l in range(n):
            dR = np.zeros((m, n))
            dR[k, l] = eps
            fd = (collocation_residual(system, el, left, right + dR, u)[0]
                  - collocation_residual(system, el, left, right - dR, u)[0]) / (2 * eps)
            np.testing.assert_allclose(J[:, :, k, l], fd, rtol=1e-6, atol=1e-6 * np.abs(J).max())


# --------------------------------------------------------------------------- orders on the oscillator
EXPECTED_NODAL_ORDER = {
    ("cubic", "gauss"): 4, ("cubic", "radau"): 3, ("cubic", "lobatto"): 2,
    ("quintic", "lobatto"): 6, ("quintic", "gauss"): 6, ("quintic", "radau"): 5,
}


@pytest.mark.parametrize("order, points", list(EXPECTED_NODAL_ORDER))
def test_oscillator_nodal_errors_converge_at_the_measured_order_for_each_choice_of_points(order, points):
    Ns = np.array([8, 16, 32, 64])
    errors = [
        nodal_error(simulate_hermite(LinearOscillator(), [0.0], [1.0], zero_torque(1), HermiteMesh(order, 2 * np.pi, N),
                                     points=points), lambda t: (np.sin(t), np.cos(t)))
        for N in Ns
    ]
    measured = convergence_order(2 * np.pi / Ns, np.array(errors))
    assert abs(measured - EXPECTED_NODAL_ORDER[order, points]) < 0.15, (measured, errors)


def test_default_quintic_elements_are_sixth_order_accurate_at_the_nodes_of_sin_t():
    errors = [nodal_error(simulate_hermite(LinearOscillator(), [0.0], [1.0], zero_torque(1),
                                           HermiteMesh("quintic", 2 * np.pi, N)), lambda t: (np.sin(t), np.cos(t)))
              for N in (8, 16, 32, 64)]
    assert errors[-1] < 2e-11
    assert abs(convergence_order(2 * np.pi / np.array([8, 16, 32, 64]), np.array(errors)) - 6) < 0.1


def test_lobatto_quintic_stays_bounded_at_five_radians_per_element_where_gauss_quintic_grows():
    stiff = LinearOscillator(omega=5.0)
    mesh = HermiteMesh("quintic", 400.0, 400)  # ω h = 5
    lobatto = simulate_hermite(stiff, [1.0], [0.0], zero_torque(1), mesh, points="lobatto")
    gauss = simulate_hermite(stiff, [1.0], [0.0], zero_torque(1), mesh, points="gauss")
    assert np.abs(lobatto.coeffs[:, 0, 0]).max() < 1 + 1e-9
    assert np.abs(gauss.coeffs[:, 0, 0]).max() > 1.1


def test_damped_oscillator_exercises_the_velocity_derivative_and_converges_at_order_six():
    system = DampedOscillator(0.1)
    Ns = np.array([10, 20, 40])
    errors = [nodal_error(simulate_hermite(system, [1.0], [0.0], zero_torque(1), HermiteMesh("quintic", 10.0, N)),
                          system.exact) for N in Ns]
    assert abs(convergence_order(10.0 / Ns, np.array(errors)) - 6) < 0.2 and errors[-1] < 5e-9  # measured 2.6e-9


def test_quintic_elements_take_the_first_acceleration_from_the_motion_equation_at_t0():
    system = Pendulum()
    result = simulate_hermite(system, [Q0], [0.3], ConstantTorque([0.7]), HermiteMesh("quintic", 1.0, 4))
    expected = system.forward_dynamics(np.array([[Q0]]), np.array([[0.3]]), np.array([[0.7]]))[0]
    np.testing.assert_array_equal(result.coeffs[0, 2], expected)
    np.testing.assert_array_equal(result.coeffs[0, :2, 0], [Q0, 0.3])


# --------------------------------------------------------------------------- the pendulum
def pendulum_run(order, N, system=None, periods=1.25):
    """Free pendulum from (π/12, 0) over 1.25 τ: turning points τ/2 and τ fall on nodes when 5 | N."""
    system = system or Pendulum()
    mesh = HermiteMesh(order, periods * TAU, N)
    return simulate_hermite(system, [Q0], [0.0], zero_torque(1), mesh)


def test_pendulum_period_matches_the_complete_elliptic_integral_to_1e_10_with_quintic_elements():
    result = pendulum_run("quintic", 60)
    period = oscillation_period(result.mesh, result.coeffs)
    assert abs(period - TAU) / TAU < 1e-10, period
    assert result.status is SimulationStatus.SUCCESS


def test_the_papers_printed_period_is_not_what_its_formula_gives():
    assert TAU == pytest.approx(2.0342381183283895, rel=1e-15)
    assert abs(TAU_PAPER - TAU) > 2e-4  # 2.03452 s misses the elliptic integral in the 4th digit
    period = oscillation_period(*(lambda r: (r.mesh, r.coeffs))(pendulum_run("quintic", 60)))
    assert abs(period - TAU_PAPER) > 2e-4


@pytest.mark.parametrize("order, expected, Ns", [("cubic", 4, (10, 20, 40, 80)), ("quintic", 6, (10, 20, 40, 80))])
def test_pendulum_period_error_converges_at_order_four_cubic_and_six_quintic(order, expected, Ns):
    errors = []
    for N in Ns:
        r = pendulum_run(order, N)
        errors.append(abs(oscillation_period(r.mesh, r.coeffs) - TAU) / TAU)
    measured = convergence_order(1.0 / np.array(Ns), np.array(errors))
    assert abs(measured - expected) < 0.15, (measured, errors)


def test_the_paper_setting_cubic_with_35_elements_gives_the_period_to_about_1e_6_not_machine_precision():
    r = pendulum_run("cubic", 35)
    err = abs(oscillation_period(r.mesh, r.coeffs) - TAU) / TAU
    assert 1e-8 < err < 1e-5, err


def test_pendulum_urdf_period_matches_the_elliptic_integral_with_its_own_omega():
    system = robot("pendulum.urdf")
    _, du_dq, _, M = system.id_derivatives(np.zeros((1, 1)), np.zeros((1, 1)), np.zeros((1, 1)))
    omega = math.sqrt(du_dq[0, 0, 0] / M[0, 0, 0])  # √(g/l) of the model (m g l / m l²)
    assert omega == pytest.approx(OMEGA, rel=1e-5)
    tau = 4.0 / omega * ellipk(math.sin(Q0 / 2) ** 2)
    mesh = HermiteMesh("quintic", 1.25 * tau, 60)
    result = simulate_hermite(system, [Q0], [0.0], zero_torque(1), mesh)
    assert abs(oscillation_period(mesh, result.coeffs) - tau) / tau < 1e-10


def test_hermite_and_reference_integrators_agree_on_the_pendulum():
    result = pendulum_run("quintic", 100, periods=2.0)
    ref = simulate_reference(Pendulum(), [Q0], [0.0], zero_torque(1), 2 * TAU)
    q, dq = ref.state(result.mesh.nodes)
    np.testing.assert_allclose(result.coeffs[:, 0, 0], q[:, 0], atol=1e-11)
    np.testing.assert_allclose(result.coeffs[:, 1, 0], dq[:, 0], atol=5e-10)  # measured 1.1e-10 (h = 0.04 s)


def test_newton_work_on_the_pendulum_is_pinned():
    result = pendulum_run("quintic", 60)
    # measured: 60 Newton steps (one per element), 120 dynamics evaluations; don't allow them to grow
    assert result.max_newton_iterations <= 2
    assert result.newton_iterations <= 70
    assert result.evaluations <= 130


# --------------------------------------------------------------------------- coupled nonlinear system
def test_coupled_van_der_pol_hermite_converges_to_the_reference_at_order_six():
    system = CoupledVanDerPol()
    q0, dq0, T = [1.0, -0.5], [0.0, 0.8], 4.0
    ref = simulate_reference(system, q0, dq0, ConstantTorque([0.3, -0.2]), T)
    qT, dqT = ref.final_state()
    Ns = np.array([20, 40, 80])
    errors = []
    for N in Ns:
        r = simulate_hermite(system, q0, dq0, ConstantTorque([0.3, -0.2]), HermiteMesh("quintic", T, N))
        q, dq = r.final_state()
        errors.append(max(np.abs(q - qT).max(), np.abs(dq - dqT).max()))
    assert abs(convergence_order(T / Ns, np.array(errors)) - 6) < 0.3, errors


# --------------------------------------------------------------------------- replaying a planned torque
# The upright arm is an open-loop unstable system (round-off grows like e^{16 t} when its planned
# torque is replayed): the replay test hangs it from the ceiling, where the motion is stable.
@pytest.mark.parametrize("make", [CoupledVanDerPol, lambda: robot("lbr7.urdf", gravity=(0.0, 0.0, 9.81))])
def test_simulating_the_planned_torque_returns_the_planned_motion(make):
    system = make()
    n = system.n
    rng = np.random.default_rng(5)
    A, w, phase = rng.uniform(0.2, 0.6, n), rng.uniform(1.0, 3.0, n), rng.uniform(0, 2 * np.pi, n)
    mesh = HermiteMesh("quintic", 1.5, 12)
    plan = mesh.interpolate(lambda t: A * np.sin(w * t[:, None] + phase),
                            lambda t: A * w * np.cos(w * t[:, None] + phase),
                            lambda t: -A * w**2 * np.sin(w * t[:, None] + phase))
    torque = PlannedTorque(system, mesh, plan)
    same = simulate_hermite(system, plan[0, 0], plan[0, 1], torque, mesh)
    np.testing.assert_allclose(same.coeffs, plan, rtol=1e-10, atol=1e-10 * np.abs(plan).max())
    finer = simulate_hermite(system, plan[0, 0], plan[0, 1], torque, HermiteMesh("quintic", 1.5, 36))
    q, dq = finer.final_state()
    np.testing.assert_allclose(q, plan[-1, 0], atol=1e-6)


# --------------------------------------------------------------------------- the 7-DOF arm
@pytest.fixture(scope="module")
def arm_runs():
    """lbr7 hanging from a ceiling (gravity +z in the base frame), released with a small swing.

    An upright arm falling freely is chaotic (joint speeds reach 80 rad/s within a second), so the
    energy test uses the stable hanging configuration q = 0 (its potential minimum).
    """
    system = robot("lbr7.urdf", gravity=(0.0, 0.0, 9.81))
    q0 = 0.3 * np.array([0.2, 0.4, -0.3, -0.5, 0.3, 0.5, -0.2])
    dq0 = 0.3 * np.array([0.2, -0.2, 0.3, 0.2, -0.3, 0.3, 0.4])
    hermite = simulate_hermite(system, q0, dq0, zero_torque(7), HermiteMesh("quintic", 2.0, 200))
    ref = simulate_reference(system, q0, dq0, zero_torque(7), 2.0)
    return system, hermite, ref


def potential_by_line_integral(system, q, G=24):
    """V(q) − V(0) = ∫₀¹ g(λq)·q dλ with g(q) = ID(q, 0, 0) = ∂V/∂q, by G-point Gauss-Legendre. (K,)."""
    s, w = gauss_legendre(G)
    K, n = q.shape
    points = (s[None, :, None] * q[:, None, :]).reshape(K * G, n)
    g = system.inverse_dynamics(points, np.zeros_like(points), np.zeros_like(points)).reshape(K, G, n)
    return np.einsum("g,kgn,kn->k", w, g, q)


def potential_by_forward_kinematics(path, joints, q, gravity):
    """V(q) = −Σ m_i g·c_i(q) from yourdfpy's forward kinematics (independent of hoc's model). (K,)."""
    import yourdfpy

    urdf = yourdfpy.URDF.load(str(path), load_meshes=False, build_scene_graph=True, load_collision_meshes=False,
                              build_collision_scene_graph=False)
    out = []
    for qk in q:
        urdf.update_cfg(dict(zip(joints, qk)))
        v = 0.0
        for name, link in urdf.link_map.items():
            if link.inertial is None or not link.inertial.mass:
                continue
            T = urdf.get_transform(name, urdf.base_link)
            com = T[:3, :3] @ link.inertial.origin[:3, 3] + T[:3, 3]
            v -= link.inertial.mass * np.dot(gravity, com)
        out.append(v)
    return np.array(out)


def test_the_line_integral_potential_agrees_with_forward_kinematics_of_the_urdf():
    system = robot("lbr7.urdf", gravity=(0.0, 0.0, 9.81))
    q = np.vstack([np.zeros(7), np.random.default_rng(1).normal(size=(4, 7))])
    fk = potential_by_forward_kinematics(ROBOTS / "lbr7.urdf", system.joint_names, q, np.array([0.0, 0.0, 9.81]))
    np.testing.assert_allclose(potential_by_line_integral(system, q), fk - fk[0], atol=1e-11)


def test_torque_free_arm_conserves_total_energy_to_1e_9_relative_over_two_seconds(arm_runs):
    system, hermite, _ = arm_runs
    q, dq = hermite.coeffs[:, 0], hermite.coeffs[:, 1]
    kinetic = 0.5 * np.einsum("ki,kij,kj->k", dq, system.mass_matrix(q), dq)
    energy = kinetic + potential_by_line_integral(system, q)  # V(0) = 0 is the minimum
    drift = np.abs(energy - energy[0]).max() / energy[0]
    assert drift < 1e-9, drift  # measured 1.4e-11 with N = 200
    assert kinetic.max() > 0.5 * energy[0]  # the energy really moves between forms


def test_torque_free_arm_hermite_and_reference_agree_to_1e_8_at_the_final_time(arm_runs):
    _, hermite, ref = arm_runs
    q, dq = hermite.final_state()
    qr, dqr = ref.final_state()
    assert np.abs(q - qr).max() < 1e-8 and np.abs(dq - dqr).max() < 1e-8  # measured 2e-10, 7e-10
    qs, dqs = hermite.state(np.linspace(0, 2, 41))
    qrs, _ = ref.state(np.linspace(0, 2, 41))
    assert np.abs(qs - qrs).max() < 1e-7  # between nodes too (interior order 5)


# --------------------------------------------------------------------------- torque sources
def test_constant_and_zero_torques_have_one_row_per_time():
    np.testing.assert_array_equal(zero_torque(3)(np.array([0.0, 1.0])), np.zeros((2, 3)))
    np.testing.assert_array_equal(ConstantTorque([1.0, -2.0])(np.array([0.5])), [[1.0, -2.0]])
    with pytest.raises(ValueError, match="finite"):
        ConstantTorque([np.nan])


def test_sampled_torque_reproduces_cubics_with_the_spline_and_lines_with_linear_interpolation():
    t = np.linspace(0.0, 2.0, 21)
    cubic = lambda x: np.stack([1 + x - 2 * x**2 + 0.5 * x**3, -x], axis=1)
    tt = np.linspace(0.0, 2.0, 97)
    np.testing.assert_allclose(SampledTorque(t, cubic(t))(tt), cubic(tt), atol=1e-12)
    line = lambda x: np.stack([3 - x, 2 * x], axis=1)
    np.testing.assert_allclose(SampledTorque(t, line(t), kind="linear")(tt), line(tt), atol=1e-13)
    np.testing.assert_allclose(SampledTorque(t, line(t))(np.array([-1.0, 5.0])), line(np.array([0.0, 2.0])))
    np.testing.assert_allclose(SampledTorque(t[:3], line(t[:3]))(np.array([0.05])), line(np.array([0.05])))
    with pytest.raises(ValueError, match="increasing"):
        SampledTorque(np.array([0.0, 0.0]), np.zeros((2, 1)))


def test_a_sampled_planned_torque_at_100_hz_replays_the_plan_to_1e_6():
    system = CoupledVanDerPol()
    mesh = HermiteMesh("quintic", 1.0, 10)
    plan = mesh.interpolate(lambda t: np.stack([np.sin(2 * t), np.cos(t)], 1),
                            lambda t: np.stack([2 * np.cos(2 * t), -np.sin(t)], 1),
                            lambda t: np.stack([-4 * np.sin(2 * t), -np.cos(t)], 1))
    t = np.linspace(0.0, 1.0, 101)
    sampled = SampledTorque(t, PlannedTorque(system, mesh, plan)(t))
    r = simulate_hermite(system, plan[0, 0], plan[0, 1], sampled, HermiteMesh("quintic", 1.0, 40))
    np.testing.assert_allclose(r.final_state()[0], plan[-1, 0], atol=1e-6)


# --------------------------------------------------------------------------- turning points, sampling
def test_velocity_zeros_of_an_interpolated_cosine_are_at_multiples_of_pi():
    mesh = HermiteMesh("quintic", 10.0, 40)
    C = mesh.interpolate(np.cos, lambda t: -np.sin(t), lambda t: -np.cos(t))
    tz = velocity_zeros(mesh, C)
    np.testing.assert_allclose(tz, np.pi * np.arange(4), atol=1e-7)  # t = 0 is a root on a node, found once


def test_a_period_needs_three_turning_points():
    mesh = HermiteMesh("quintic", 2.0, 8)
    C = mesh.interpolate(np.cos, lambda t: -np.sin(t), lambda t: -np.cos(t))
    with pytest.raises(NumericalError, match="turning points"):
        oscillation_period(mesh, C)


def test_sampling_a_result_gives_a_trajectory_with_the_applied_torque():
    system = Pendulum()
    torque = ConstantTorque([0.2])
    mesh = HermiteMesh("quintic", 1.0, 10)
    hermite = simulate_hermite(system, [Q0], [0.0], torque, mesh)
    ref = simulate_reference(system, [Q0], [0.0], torque, 1.0)
    t = np.linspace(0.0, 1.0, 11)
    a, b = sample(hermite, system, torque, t, ("theta",)), sample(ref, system, torque, t, ("theta",))
    assert a.coeffs is hermite.coeffs and b.coeffs is None
    np.testing.assert_array_equal(a.u, np.full((11, 1), 0.2))
    for field in ("q", "dq", "ddq"):
        np.testing.assert_allclose(getattr(a, field), getattr(b, field), atol=1e-7)


# --------------------------------------------------------------------------- failures
def test_a_motion_that_blows_up_raises_a_numerical_error_naming_the_element():
    class Explosive(DampedOscillator):  # q̈ = q³: blows up at t = 1/q0 ... for q0 = 2, at 0.5·√2 s
        def inverse_dynamics(self, q, dq, ddq):
            return np.asarray(ddq) - np.asarray(q) ** 3

        def forward_dynamics(self, q, dq, u):
            return np.asarray(u) + np.asarray(q) ** 3

        def id_derivatives(self, q, dq, ddq):
            K = len(q)
            return self.inverse_dynamics(q, dq, ddq), (-3 * np.asarray(q) ** 2)[:, :, None], np.zeros((K, 1, 1)), np.ones((K, 1, 1))

    with pytest.raises(NumericalError, match=r"element \d+ \(t = "):
        simulate_hermite(Explosive(), [2.0], [2.0 ** 2 / math.sqrt(2)], zero_torque(1), HermiteMesh("quintic", 2.0, 20))


def test_a_non_finite_torque_history_is_reported_with_its_element():
    torque = lambda t: np.where(np.asarray(t)[:, None] > 0.55, np.nan, 0.0)
    with pytest.raises(NumericalError, match=r"element 5 \(t = 0.5"):
        simulate_hermite(Pendulum(), [Q0], [0.0], torque, HermiteMesh("quintic", 1.0, 10))


def test_inconsistent_states_and_points_are_rejected():
    with pytest.raises(ValueError, match="disagree"):
        simulate_hermite(Pendulum(), [Q0, 0.0], [0.0], zero_torque(1), HermiteMesh("quintic", 1.0, 4))
    with pytest.raises(ValueError, match="collocation points"):
        simulate_hermite(Pendulum(), [Q0], [0.0], zero_torque(1), HermiteMesh("quintic", 1.0, 4), points=np.array([0.0, 0.5, 1.0]))
