"""``hoc simulate --check``: the miss beside what the replay's own errors explain through the dynamics'
sensitivity (hoc_cli.replay_sensitivity). The linearisation agrees with finite differences of the
replay itself; a correct plan on a sensitive third-party robot (example-robot-data's xArm7, with a
via) passes although its open-loop miss is far above the tolerance; the same plan's torque history
perturbed by 1e-6 relative fails; the JSON reports the miss, the explained bound and the amplification."""
from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from _robots import ERD, ROBOTS
from typer.testing import CliRunner

from hoc_cli import simulate as sim
from hoc_cli.cli import app
from hoc_cli.elements import HermiteMesh
from hoc_cli.model import load_robot
from hoc_cli.replay_sensitivity import collocation_residuals, replay_sensitivity, representation_error
from hoc_cli.system import RobotSystem
from hoc_cli.torque import PlannedTorque, SampledTorque

XARM = ERD / "xarm_description" / "urdf" / "xarm7.urdf"


def swing(system, T=1.6, N=16, uniform=True):
    """A smooth two-link swing as Hermite coefficients and its exact torque (on N equal elements, or on
    a graded mesh as ``N: auto`` makes)."""
    mesh = HermiteMesh("quintic", T, N) if uniform else HermiteMesh.from_nodes("quintic", T * np.linspace(0, 1, N + 1) ** 1.5)
    w = np.pi / T
    amp = np.array([1.1, -0.7])
    C = mesh.interpolate(lambda t: np.outer(np.sin(w * t) ** 2, amp), lambda t: np.outer(w * np.sin(2 * w * t), amp),
                         lambda t: np.outer(2 * w * w * np.cos(2 * w * t), amp))
    return mesh, C, PlannedTorque(system, mesh, C)


@pytest.mark.parametrize("uniform", [True, False], ids=["uniform", "graded"])
def test_the_replays_state_transition_matrix_agrees_with_finite_differences_of_the_replay(uniform):
    system = RobotSystem(load_robot(ROBOTS / "two_link.urdf"))
    mesh, C, torque = swing(system, uniform=uniform)
    x0 = np.concatenate([C[0, 0], C[0, 1]])
    base = sim.simulate_hermite(system, C[0, 0], C[0, 1], torque, mesh)
    sens = replay_sensitivity(system, mesh, base.coeffs, base.points, torque)
    assert sens.transition.shape == (4, 4) and sens.amplification >= 1.0
    rng = np.random.default_rng(3)
    for _ in range(3):
        d = 1e-7 * rng.standard_normal(4)
        x = x0 + d
        r = sim.simulate_hermite(system, x[:2], x[2:], torque, mesh)
        moved = np.concatenate([r.coeffs[-1, 0] - base.coeffs[-1, 0], r.coeffs[-1, 1] - base.coeffs[-1, 1]])
        np.testing.assert_allclose(moved, sens.transition @ d, rtol=1e-4, atol=1e-6 * np.abs(moved).max())
        assert np.abs(moved).max() <= sens.state_gain[0] * np.abs(d).max() * (1 + 1e-6)


def test_a_replays_residuals_sit_at_the_rounding_level_and_a_sampled_torques_error_is_estimated():
    system = RobotSystem(load_robot(ROBOTS / "two_link.urdf"))
    mesh, C, torque = swing(system)
    r = sim.simulate_hermite(system, C[0, 0], C[0, 1], torque, mesh)
    sens = replay_sensitivity(system, mesh, r.coeffs, r.points, torque)
    residual = collocation_residuals(system, mesh, r.coeffs, r.points, torque)
    assert residual.shape == (mesh.N,) and np.all(residual <= 100 * sens.rounding)
    assert np.all(representation_error(torque, mesh, r.points) == 0.0)
    t = np.linspace(0.0, mesh.T, 161)
    sampled = SampledTorque(t, torque(t))
    estimate = representation_error(sampled, mesh, r.points)
    s = sim.collocation_points(mesh.order)
    tc = mesh.time_of(np.repeat(np.arange(mesh.N), 3), np.tile(s, mesh.N))
    actual = np.abs(sampled(tc) - torque(tc)).reshape(mesh.N, -1).max(axis=1)
    assert np.all(estimate >= actual)  # the estimate covers the spline's true error in every element


@pytest.fixture(scope="module")
def xarm_plan(tmp_path_factory):
    if not XARM.is_file():
        pytest.skip("example-robot-data's xarm7 is not installed")
    d = tmp_path_factory.mktemp("xarm")
    task = d / "xarm_via.yaml"
    task.write_text(f"""robot: {XARM}
x0: {{q: [0.0, 0.3, 0.0, 1.0, 0.0, 0.5, 0.0]}}
x1: {{q: [1.0, -0.2, 0.5, 1.8, -0.4, 1.2, 0.8]}}
via: [{{t: 0.8, q: [0.6, 0.4, 0.3, 1.5, 0.2, 0.9, 0.3]}}]
T: 2.0
N: 24
output: {{rate: 50}}
""")
    r = CliRunner().invoke(app, ["plan", str(task), "-o", str(d / "plan.mcap"), "-o", str(d / "plan.csv"), "-q"])
    assert r.exit_code == 0, r.output
    return d / "plan.mcap"


def simulate_json(plan, *extra):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = CliRunner().invoke(app, ["simulate", str(plan), "-o", "none", "--check", "1e-8", "--json", *extra])
    return r, json.loads(r.stdout)


def test_a_correct_plan_on_a_sensitive_third_party_robot_passes_the_ci_check(xarm_plan):
    r, doc = simulate_json(xarm_plan)
    assert r.exit_code == 0, r.output
    check = doc["check"]
    assert check["miss"] == doc["final_error"] > 1e-8  # open loop, the replay misses x1 by more than tol …
    assert check["amplification"] > 1e6                 # … because the dynamics amplify its rounding this much,
    assert check["miss"] <= check["explained"] < 0.1    # and that explains the miss
    assert check["bound"] == pytest.approx(1e-8 + check["explained"]) and check["resolved"] and check["passed"]
    assert set(check["explained_parts"]) == {"rounding", "torque_representation", "newton"}
    assert check["linearised_about"] == "plan"


def test_the_same_plans_torque_perturbed_by_1e_6_relative_fails_the_check(xarm_plan, monkeypatch):
    exact = PlannedTorque.__call__
    signs = np.array([1.0, -1.0, 1.0, 1.0, -1.0, 1.0, -1.0])
    monkeypatch.setattr(PlannedTorque, "__call__", lambda self, t: exact(self, t) * (1.0 + 1e-6 * signs))
    r, doc = simulate_json(xarm_plan)
    assert r.exit_code == 1
    check = doc["check"]
    assert not check["passed"] and check["miss"] > 100 * check["bound"]
    assert "check failed" in r.stderr


def test_a_sampled_torque_the_replay_cannot_resolve_fails_saying_so(xarm_plan):
    """The plan's 50 Hz CSV torque: its interpolation error, amplified 1e10 times, is beyond what an
    open-loop replay can resolve; the check fails and says why instead of passing on a vacuous bound."""
    task, csv = xarm_plan.with_name("xarm_via.yaml"), xarm_plan.with_suffix(".csv")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = CliRunner().invoke(app, ["simulate", str(task), "--torque", str(csv), "-o", "none", "--check", "1e-8", "--json"])
    assert r.exit_code == 1
    check = json.loads(r.stdout)["check"]
    assert check["resolved"] is False and check["passed"] is False
    assert check["explained_parts"]["torque_representation"] > check["explained_parts"]["rounding"]
    assert "cannot resolve x1" in r.stderr
