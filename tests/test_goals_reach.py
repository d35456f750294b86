"""An unreachable link goal is infeasible before any solve: the reach bound of a chain (never exceeded
by forward kinematics, attained by the stretched lbr7) and ``hoc plan``'s exit 1 naming the key."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from hoc_cli.cli import app
from hoc_cli.dynamics import link_poses
from hoc_cli.goals.residuals import reach
from hoc_cli.model import load_robot
from tests._robots import ROBOTS

ROOT = Path(__file__).resolve().parents[1]
LBR = load_robot(ROBOTS / "lbr7.urdf")


def test_reach_bounds_forward_kinematics_and_is_attained_stretched():
    o, r = reach(LBR, "lbr_flange")
    q = np.random.default_rng(3).uniform(LBR.lower, LBR.upper, size=(2000, LBR.n))
    d = np.linalg.norm(link_poses(LBR, q)["lbr_flange"][:, :3, 3] - o, axis=1)
    assert d.max() <= r
    straight = np.linalg.norm(link_poses(LBR, np.zeros(LBR.n))["lbr_flange"][:3, 3] - o)
    assert abs(straight - r) <= 1e-12  # the lbr7 at q = 0 stands straight: every joint origin on one line


def test_an_unreachable_catch_is_infeasible_exit_1(tmp_path):
    text = (ROOT / "configs" / "catch_ball.yaml").read_text()
    text = text.replace("position: [0.6725, -0.0375, 0.1246]", "position: [2.6725, -0.0375, 0.1246]")
    text = text.replace("../robots/lbr7.urdf", str(ROBOTS / "lbr7.urdf"))
    task = tmp_path / "far.yaml"
    task.write_text(text)
    r = CliRunner().invoke(app, ["plan", str(task), "--json", "-q"])
    assert r.exit_code == 1
    assert "x1: infeasible" in r.output and "beyond the arm's reach" in r.output
