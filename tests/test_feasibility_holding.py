"""A rest state at an end of the move is one the arm holds: an effort limit below its gravity torque is
infeasible before any solve (exit 1, status infeasible, the joint named), against Pinocchio's g(q)."""
from __future__ import annotations

import json
import shutil

import numpy as np
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


def gravity_torque(q) -> np.ndarray:
    pin = pytest.importorskip("pinocchio")
    model = pin.buildModelFromUrdf(str(ROBOTS / "two_link.urdf"))
    data = model.createData()
    return np.array(pin.computeGeneralizedGravity(model, data, np.array(q, float)))


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    shutil.copy(ROBOTS / "two_link.urdf", tmp_path / "arm.urdf")
    monkeypatch.chdir(tmp_path)
    return tmp_path


def plan(d, text: str):
    (d / "task.yaml").write_text(text)
    r = CliRunner().invoke(app, ["plan", "task.yaml", "--json", "-q", "-o", "out.csv"])
    return r, (json.loads(r.stdout) if r.stdout.strip().startswith("{") else None)


@pytest.mark.parametrize("joint,index", [("shoulder", 0), ("elbow", 1)])
def test_an_effort_limit_below_the_gravity_torque_of_x0_is_infeasible_before_the_solve(workdir, joint, index):
    g = abs(gravity_torque([0.0, 0.0])[index])
    r, s = plan(workdir, TASK + f"limits: {{effort: {{{joint}: {0.9 * g}}}}}\n")
    assert r.exit_code == 1 and s["status"] == "infeasible" and s["binding"] == {"kind": "effort", "joint": joint}
    assert "x0 (t = 0) is a rest state" in s["message"] and f"|u| = {g:.6g}" in s["message"]
    assert not (workdir / "out.csv").exists()


def test_the_end_state_x1_counts_too_and_a_limit_above_both_holds_plans(workdir):
    back = TASK.replace("x0: {q: [0.0, 0.0]}", "x0: {q: [1.2, -0.6]}").replace("x1: {q: [1.2, -0.6]}", "x1: {q: [0.0, 0.0]}")
    g0, g1 = np.abs(gravity_torque([1.2, -0.6])), np.abs(gravity_torque([0.0, 0.0]))
    assert g1[1] > g0[1]  # the elbow works harder at x1: a limit between the two binds at x1 only
    r, s = plan(workdir, back + f"limits: {{effort: {{elbow: {0.5 * (g0[1] + g1[1])}}}}}\n")
    assert r.exit_code == 1 and s["status"] == "infeasible" and "x1 (t = T) is a rest state" in s["message"]
    r, s = plan(workdir, back + f"limits: {{effort: {{elbow: {1.5 * g1[1]}}}}}\n")
    assert "rest state" not in (s or {}).get("message", "") and (workdir / "out.csv").exists()
