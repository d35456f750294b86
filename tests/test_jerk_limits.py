"""Jerk limits (``limits: {jerk: …}``): enforced exactly on quintic elements, checked on the written plan,
J monotone in the limit, an infeasible limit reported with the shortest T, refused on cubic elements."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from typer.testing import CliRunner

from hoc_cli.cli import app
from hoc_cli.constraints import JointLimits, shortest_duration
from tests._robots import ROBOTS

TASK = """\
robot: arm.urdf
x0: {q: [0.0, 0.0]}
x1: {q: [1.2, -0.6]}
T: 1.5
N: 16
order: quintic
output: {rate: 1000}
"""


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    shutil.copy(ROBOTS / "two_link.urdf", tmp_path / "arm.urdf")
    monkeypatch.chdir(tmp_path)
    return tmp_path


def plan(d, text: str, *extra: str, out: str = "none"):
    (d / "task.yaml").write_text(text)
    r = CliRunner().invoke(app, ["plan", "task.yaml", "--json", "-q", "-o", out, *extra])
    return r, (json.loads(r.stdout) if r.stdout.strip().startswith("{") else None)


def written_jerk(path) -> np.ndarray:
    """|Δq̈/Δt| between consecutive 1 kHz samples of a written plan, (K−1, n).

    By the mean-value theorem each difference quotient equals the jerk at some instant of its
    interval, so its maximum is a lower bound on max |q⃛| that needs no element arithmetic.
    """
    from hoc_cli.io.mcap import read_plan

    tr = read_plan(path).trajectory
    return np.abs(np.diff(tr.ddq, axis=0) / np.diff(tr.t)[:, None])


def test_a_jerk_limit_holds_on_1khz_samples_of_the_written_plan_and_binds(workdir):
    r, free = plan(workdir, TASK, "--limits", "report", out="free.mcap")
    assert r.exit_code == 0, r.output
    unlimited = written_jerk(workdir / "free.mcap").max(axis=0)
    assert unlimited.min() > 40.0  # without the limit both joints exceed it: the test below can fail
    r, s = plan(workdir, TASK + "limits: {jerk: {shoulder: 40.0, elbow: 40.0}}\n", out="plan.mcap")
    assert r.exit_code == 0, r.output
    assert s["status"] == "converged" and s["limit_violations"] == []
    assert s["cost"] > free["cost"]
    assert any(a["kind"] == "jerk" and a["intervals"] for a in s["active_limits"])
    j = written_jerk(workdir / "plan.mcap")
    assert j.max() <= 40.0 * (1 + 1e-9) + 1e-6  # 1e-6: the rounding of q̈ differences over 1 ms
    assert j.max() >= 0.98 * 40.0  # the limit is reached, not merely respected


def test_the_cost_does_not_decrease_as_the_jerk_limit_tightens(workdir):
    costs = []
    for j in (None, 120.0, 60.0, 30.0, 15.0):
        extra = "" if j is None else f"limits: {{jerk: {{shoulder: {j}, elbow: {j}}}}}\n"
        r, s = plan(workdir, TASK + extra)
        assert r.exit_code == 0 and s["converged"], r.output
        costs.append(s["cost"])
    assert all(b >= a * (1 - 1e-10) for a, b in zip(costs, costs[1:])), costs
    assert costs[-1] > costs[0] * 1.01  # 15 rad/s³ binds hard


def test_a_jerk_scale_factor_multiplies_the_jerk_limit(workdir):
    _, direct = plan(workdir, TASK + "limits: {jerk: {shoulder: 30.0, elbow: 30.0}}\n")
    _, scaled = plan(workdir, TASK + "limits: {jerk: {shoulder: 60.0, elbow: 60.0}, scale: {jerk: 0.5}}\n")
    assert scaled["cost"] == pytest.approx(direct["cost"], rel=1e-9)


def test_a_jerk_limit_too_tight_for_T_exits_1_infeasible_with_the_shortest_duration(workdir):
    # shoulder: 1.2 rad rest to rest at |q⃛| <= 40 needs T >= ∛(12·1.2/40) = 0.7114 s
    r, s = plan(workdir, TASK.replace("T: 1.5", "T: 0.6") + "limits: {jerk: {shoulder: 40.0, elbow: 40.0}}\n")
    assert r.exit_code == 1
    assert s["status"] == "infeasible" and not s["converged"]  # proven before any solve (constraints/feasibility.py)
    assert "shoulder's jerk limit" in s["message"] and "0.711379" in s["message"]
    assert s["binding"] == {"kind": "jerk", "joint": "shoulder"} and s["T_min"] == pytest.approx(0.711379, rel=1e-6)


def test_the_shortest_duration_under_a_jerk_limit_is_attained_by_a_linear_acceleration_ramp():
    # q̈(t) = j (T/2 − t) on [0, T]: q̇(0) = q̇(T) = 0, |q⃛| = j, and Δq = j T³/12 (the bound is tight)
    j, T = 7.0, 1.3
    t = np.linspace(0.0, T, 200001)
    dq = j * (T * t / 2 - t**2 / 2)
    dist = float(np.sum((dq[1:] + dq[:-1]) / 2 * np.diff(t)))  # trapezoid: independent of the formula
    limits = JointLimits.from_arrays(("a",), jerk=[j])
    bound = shortest_duration(limits, [0.0], [0.0], [dist], [0.0])
    assert bound is not None and bound[1:] == ("a", "jerk")
    assert bound[0] == pytest.approx(T, rel=1e-9)


def test_a_jerk_limit_on_cubic_elements_is_refused_naming_the_key(workdir):
    r, _ = plan(workdir, TASK.replace("order: quintic", "order: cubic") + "limits: {jerk: {elbow: 40.0}}\n")
    assert r.exit_code == 2
    assert "limits.jerk.elbow" in r.stderr and "quintic" in r.stderr and "Traceback" not in r.output
    r, _ = plan(workdir, TASK + "limits: {jerk: {elbow: 40.0}}\n", "--order", "cubic")
    assert r.exit_code == 2 and "limits.jerk.elbow" in r.stderr


@pytest.mark.parametrize("bad", ["0.0", "-3", "nan", "'fast'"])
def test_a_non_positive_or_non_numeric_jerk_limit_is_an_input_error(workdir, bad):
    r, _ = plan(workdir, TASK + f"limits: {{jerk: {{elbow: {bad}}}}}\n")
    assert r.exit_code == 2 and "limits.jerk.elbow" in r.stderr


def test_a_free_time_plan_with_a_jerk_limit_is_optimal_in_T(workdir):
    text = (TASK.replace("T: 1.5", "T: {free: true, min: 0.5, max: 3.0, guess: 1.2, weight: 80.0}")
            .replace("N: 16", "N: 8") + "limits: {jerk: {shoulder: 30.0, elbow: 30.0}}\n")
    r, s = plan(workdir, text)
    assert r.exit_code == 0 and s["converged"], r.output
    assert s["limit_violations"] == [] and any(a["kind"] == "jerk" for a in s["active_limits"])
    T = s["T"]
    assert 0.6 < T < 2.9  # an interior optimum in T (min 0.5, max 3)
    # J + w·T at T* is no larger than fixed-T plans with the same limit a little to either side
    fixed = TASK.replace("N: 16", "N: 8") + "limits: {jerk: {shoulder: 30.0, elbow: 30.0}}\n"
    total = s["cost"] + 80.0 * T
    for dT in (-0.02, 0.02):
        _, f = plan(workdir, fixed.replace("T: 1.5", f"T: {T + dT!r}"))
        assert f["converged"] and f["limit_violations"] == []
        assert f["cost"] + 80.0 * (T + dT) >= total - 1e-7 * total


def test_hoc_plot_adds_a_jerk_panel_with_the_tasks_jerk_limit(workdir):
    pytest.importorskip("matplotlib")
    from matplotlib.figure import Figure

    from hoc_cli.commands.plot import read_for_plot
    from hoc_cli.plotting import _draw_normalised, _draw_per_joint

    r, _ = plan(workdir, TASK + "limits: {jerk: {shoulder: 80.0, elbow: 80.0}, scale: {jerk: 0.5}}\n", out="plan.mcap")
    assert r.exit_code == 0, r.output
    traj, limits = read_for_plot(workdir / "plan.mcap")
    assert limits["elbow"].jerk == 40.0 and limits["elbow"].velocity is not None
    fig = _draw_per_joint(Figure, [("plan", traj)], list(traj.joints), limits)
    axes = np.array(fig.axes).reshape(2, 4)
    for ax in axes[:, 3]:
        drawn = [line for line in ax.lines if len(line.get_xdata()) > 2]
        peak = max(np.abs(line.get_ydata()).max() for line in drawn)
        limits_drawn = sorted(float(line.get_ydata()[0]) for line in ax.lines if len(line.get_xdata()) == 2)
        assert limits_drawn and set(limits_drawn) <= {-40.0, 40.0} and peak <= 40.0 * (1 + 1e-9)  # a far side: named
    assert len(_draw_normalised(Figure, [("plan", traj)], list(traj.joints), limits).axes) == 4
    r, _ = plan(workdir, TASK, out="free.mcap")  # no jerk limit: the three panels of q, q̇, u
    traj, limits = read_for_plot(workdir / "free.mcap")
    assert len(_draw_per_joint(Figure, [("plan", traj)], list(traj.joints), limits).axes) == 6
