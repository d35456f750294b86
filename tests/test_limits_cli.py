"""``hoc plan`` with limits through the CLI: the ``limits:`` key and ``--limits``, the summary's
limit keys, infeasible tasks (exit 1, status infeasible, the shortest T), and the exact check."""
from __future__ import annotations

import json
import shutil

import pytest
from typer.testing import CliRunner

from hoc_cli.cli import app
from tests._robots import ROBOTS

TASK = """\
robot: arm.urdf
x0: {q: [0.0, 0.0]}
x1: {q: [1.2, -0.6]}
T: 1.5
N: 16
"""


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    shutil.copy(ROBOTS / "two_link.urdf", tmp_path / "arm.urdf")
    monkeypatch.chdir(tmp_path)
    return tmp_path


def plan(d, text: str, *extra: str):
    (d / "task.yaml").write_text(text)
    r = CliRunner().invoke(app, ["plan", "task.yaml", "--json", "-q", "-o", "out.csv", *extra])
    return r, (json.loads(r.stdout) if r.stdout.strip().startswith("{") else None)


def test_a_velocity_limit_from_the_task_is_enforced_exactly_and_reported_as_active(workdir):
    r, free = plan(workdir, TASK, "--limits", "report")
    assert r.exit_code == 0 and free["limits_mode"] == "report" and free["active_limits"] == []
    r, s = plan(workdir, TASK + "limits: {velocity: {shoulder: 1.2}}\n")
    assert r.exit_code == 0, r.output
    assert s["limits_mode"] == "enforce" and s["converged"] and s["status"] == "converged"
    assert s["limit_violations"] == [] and s["cost"] > free["cost"]
    (active,) = s["active_limits"]
    assert (active["joint"], active["kind"]) == ("shoulder", "velocity") and active["intervals"]
    # the written CSV: q̇ at 100 Hz never exceeds the limit (plus the stated 1e-9 relative tolerance)
    rows = (workdir / "out.csv").read_text().splitlines()
    col = rows[0].split(",").index("dq.shoulder")
    assert max(abs(float(line.split(",")[col])) for line in rows[1:]) <= 1.2 * (1 + 1e-9)
    # the same task with --limits report breaks it and says so
    r, rep = plan(workdir, TASK + "limits: {velocity: {shoulder: 1.2}}\n", "--limits", "report")
    assert r.exit_code == 0 and [(v["joint"], v["kind"]) for v in rep["limit_violations"]] == [("shoulder", "velocity")]


def test_scale_factors_multiply_the_urdf_limits(workdir):
    r, s = plan(workdir, TASK + "limits: {scale: {effort: 0.3}}\n")  # two_link's effort limits: 100, 50 N·m
    assert r.exit_code == 0, r.output
    assert s["limit_violations"] == []
    assert s["max_abs_u"][0] <= 30.0 * (1 + 1e-9) and s["max_abs_u"][1] <= 15.0 * (1 + 1e-9)
    assert any(a["kind"] == "effort" for a in s["active_limits"])


def test_an_infeasible_move_exits_1_names_the_binding_joint_and_the_shortest_duration(workdir):
    r, s = plan(workdir, TASK.replace("T: 1.5", "T: 0.5") + "limits: {velocity: {shoulder: 2.0}}\n")
    assert r.exit_code == 1
    assert s["status"] == "infeasible" and not s["converged"]
    assert "shoulder's velocity limit" in s["message"] and "T >= 0.6 s" in s["message"]  # |Δq|/v = 1.2/2
    assert not (workdir / "out.csv").exists()  # proven before any solve: nothing to write


def test_an_infeasible_move_found_by_the_solve_writes_the_least_violating_plan(workdir):
    """Gravity alone breaks the shoulder's effort limit at x0 and x1, moving states (not rest states the arm holds),
    and with no acceleration limit that is no proof (the arm may start by falling: hoc_cli.constraints.feasibility);
    the solve finds the task infeasible."""
    moving = (TASK.replace("N: 16", "N: 4").replace("x0: {q: [0.0, 0.0]}", "x0: {q: [0.0, 0.0], dq: [0.5, 0.0]}")
              .replace("x1: {q: [1.2, -0.6]}", "x1: {q: [1.2, -0.6], dq: [0.5, 0.0]}"))
    r, s = plan(workdir, moving + "limits: {effort: {shoulder: 1.0e-3}}\n")
    assert r.exit_code == 1
    assert s["status"] == "infeasible" and not s["converged"] and "shoulder effort binds" in s["message"]
    assert (workdir / "out.csv").exists()  # the least-violating plan is written


def test_a_goal_state_beyond_the_velocity_limit_is_an_input_error_when_enforced(workdir):
    r, _ = plan(workdir, TASK.replace("x1: {q: [1.2, -0.6]}", "x1: {q: [1.2, -0.6], dq: [0.0, 12.0]}"))
    assert r.exit_code == 2
    assert "x1.dq.elbow" in r.stderr and "velocity limit 10" in r.stderr and "Traceback" not in r.stderr
