"""The IPOPT reference with joint limits (benchmarks/ipopt_limits.py) against an analytic constrained optimum.

Skipped without casadi (a benchmark-only dependency: ``pip install -e '.[bench]'``).

The analytic case: one prismatic joint carrying a mass m, no gravity, rest to rest from 0 to D in
T, covariant cost J = ∫ ½ u² / m dt = ∫ ½ m q̈² dt, velocity limit v < 3D/(2T) (the unconstrained
minimum-jerk-like cubic peaks at 3D/(2T)). The problem is convex. Pontryagin with a first-order
state constraint: on free arcs q̈ is linear in t; at the junctions q̈ = 0 (q̈ continuous). So q̇
rises as v (2s − s²), s = t/τ, on [0, τ], stays at v on [τ, T − τ], falls symmetrically. The
distance gives v (T − 2τ/3) = D, so τ = 3 (T − D/v) / 2, and

    J* = 2 · ½ m ∫₀^τ (2v/τ (1 − t/τ))² dt = 4 m v² / (3 τ).
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

ca = pytest.importorskip("casadi")

from hoc_cli.model import load_robot  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import ipopt_limits as il  # noqa: E402

URDF = """<robot name="slider">
  <link name="base"/>
  <link name="cart"><inertial><origin xyz="0 0 0"/><mass value="{m}"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>
  <joint name="slide" type="prismatic"><parent link="base"/><child link="cart"/><axis xyz="1 0 0"/>
    <limit lower="-5" upper="5" velocity="{v}" effort="100"/></joint>
</robot>
"""
M, D, T = 2.0, 1.0, 1.0


def slider(tmp_path, v: float):
    path = tmp_path / "slider.urdf"
    path.write_text(URDF.format(m=M, v=v))
    return load_robot(path, gravity=(0.0, 0.0, 0.0))


def J_star(v: float) -> tuple[float, float]:
    tau = 1.5 * (T - D / v)
    return 4 * M * v**2 / (3 * tau), tau


def q_star(t: np.ndarray, v: float) -> np.ndarray:
    """The analytic optimum's position (rest to rest, velocity limit v active on [τ, T − τ])."""
    _, tau = J_star(v)
    s = np.clip(t, 0.0, tau) / tau
    rise = v * tau * (s**2 - s**3 / 3)
    cruise = v * np.clip(t - tau, 0.0, T - 2 * tau)
    s = np.clip(t - (T - tau), 0.0, tau) / tau
    fall = v * tau * (s - s**3 / 3)  # the mirror image: q̇ = v (1 − s²)
    return rise + cruise + fall


def solve(model, K: int, limits, d: int = 3, scheme: str = "radau"):
    z = np.zeros(1)
    c = il.LimitedCollocation(model, T, z, z, np.array([D]), z, K, d, limits=limits, scheme=scheme)
    return c.solve()


def test_junctions_on_mesh_nodes_give_the_analytic_optimum_to_rounding(tmp_path):
    """v = 1.2: τ = 0.25 and T − τ = 0.75 are interval ends for K = 4, 8; the optimum is piecewise
    cubic, so degree-3 collocation represents it exactly (J to 1e-9; q(t) between the nodes to 2e-7)."""
    model = slider(tmp_path, 1.2)
    J, tau = J_star(1.2)
    assert tau == pytest.approx(0.25)
    for K in (4, 8):
        r = solve(model, K, il.Limits.from_model(model))
        assert r.success, r.status
        assert abs(r.J - J) <= 1e-9 * J, (K, r.J, J)
        assert np.abs(r.dq).max() <= 1.2 * (1 + 1e-12)
        t = np.linspace(0.0, T, 401)
        q, dq = r.interpolate(t)
        # 1e-7, not rounding: at a junction the multiplier vanishes and the interior point's iterate
        # sits ~√μ off the bound (q̇ = v − 1e-6 there, measured), a first-order error in q, second in J
        np.testing.assert_allclose(q[:, 0], q_star(t, 1.2), atol=2e-7)
        (a,) = [a for a in r.active if a["kind"] == "velocity"]
        assert a["side"] == "upper" and a["intervals"][0][0] == pytest.approx(0.25, abs=1e-6)
        assert a["intervals"][-1][1] == pytest.approx(0.75, abs=1e-6)


@pytest.mark.parametrize("scheme", ["radau", "gauss"])
def test_junctions_between_nodes_converge_to_the_analytic_optimum(tmp_path, scheme):
    """v = 1.3: τ ≈ 0.346 lies inside an interval for every K below. Measured (d = 3, K = 8 … 128):
    the relative error follows K⁻³ with a factor that depends on where the junction falls in its
    interval (Radau −1.5e-4, −1.3e-5, −3.9e-7, −1.0e-7 at K = 8, 16, 32, 64; Gauss changes sign),
    always within 0.2 K⁻³. Radau's J stays below J*: the limit holds at the nodes only."""
    model = slider(tmp_path, 1.3)
    J, _ = J_star(1.3)
    errs = []
    for K in (8, 16, 32, 64):
        r = solve(model, K, il.Limits.from_model(model), scheme=scheme)
        assert r.success, r.status
        assert np.abs(r.dq).max() <= 1.3 * (1 + 1e-12)
        assert r.max_violation <= 1e-10
        errs.append((r.J - J) / J)
        assert abs(errs[-1]) <= 0.2 * K**-3.0, (K, errs)
        if scheme == "radau":
            assert errs[-1] < 0, errs
    assert abs(errs[-1]) < abs(errs[0]) / 300, errs


def test_loose_limits_change_nothing_and_time_to_accuracy_is_recorded(tmp_path):
    """v = 2 > 3D/(2T): the unconstrained optimum q = D (3s² − 2s³)… is feasible; the limited and the
    unlimited transcriptions agree to 1e-12 and no limit is active. J* = 6 m D² / T³ (the cubic)."""
    model = slider(tmp_path, 2.0)
    free = solve(model, 8, None)
    lim = solve(model, 8, il.Limits.from_model(model))
    assert abs(free.J - 6 * M * D**2 / T**3) <= 1e-10 * free.J
    assert abs(lim.J - free.J) <= 1e-12 * free.J
    assert lim.active == []
    assert 0 < lim.t_to_tol <= lim.t_to_tol_stay <= lim.wall
    assert 0 <= lim.it_to_tol <= lim.iterations
    assert lim.history.shape == (lim.iterations + 1, 3)


def test_urdf_limits_follow_the_none_rules():
    """Zero or negative velocity/effort and lower >= upper mean no limit; continuous joints have none."""
    class Model:
        n = 3
        lower = np.array([-1.0, 0.0, -np.inf])
        upper = np.array([1.0, 0.0, np.inf])
        velocity_limit = np.array([2.0, 0.0, -1.0])
        effort_limit = np.array([np.inf, 5.0, 0.0])

    lim = il.Limits.from_model(Model, acceleration=[3.0, 0.0, 4.0], scale={"velocity": 0.5})
    np.testing.assert_array_equal(lim.lower, [-1.0, -np.inf, -np.inf])
    np.testing.assert_array_equal(lim.upper, [1.0, np.inf, np.inf])
    np.testing.assert_array_equal(lim.velocity, [1.0, np.inf, np.inf])
    np.testing.assert_array_equal(lim.acceleration, [3.0, np.inf, 4.0])
    np.testing.assert_array_equal(lim.effort, [np.inf, 5.0, np.inf])
