"""``hoc plan`` with goals through the CLI: the task keys (each bad value names its key, exit 2), a link
goal, vias and a free T on the two-link arm, the summary keys, and the shipped catch at a fixed T."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from hoc_cli.cli import app
from hoc_cli.dynamics import link_poses
from hoc_cli.model import load_robot
from tests._robots import ROBOTS

ROOT = Path(__file__).resolve().parents[1]
BASE = """\
robot: arm.urdf
x0: {q: [0.0, 0.0]}
N: 10
"""
JOINT_GOAL = "x1: {q: [1.0, -0.5]}\n"
TOOL = [float(v) for v in link_poses(load_robot(ROBOTS / "two_link.urdf"), [0.8, -0.4])["tool"][:3, 3]]


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    shutil.copy(ROBOTS / "two_link.urdf", tmp_path / "arm.urdf")
    monkeypatch.chdir(tmp_path)
    return tmp_path


def plan(d, text: str, *extra: str):
    (d / "task.yaml").write_text(text)
    r = CliRunner().invoke(app, ["plan", "task.yaml", "--json", "-q", "-o", "out.csv", *extra])
    return r, (json.loads(r.stdout) if r.stdout.strip().startswith("{") else None)


@pytest.mark.parametrize("text, message", [
    (BASE + JOINT_GOAL + "T: {free: true, min: 1.0}\n", "T.max: missing required key"),
    (BASE + JOINT_GOAL + "T: {free: false, min: 1, max: 2}\n", "T.free: expected true"),
    (BASE + JOINT_GOAL + "T: {free: true, min: 2, max: 1}\n", "T.max: expected max >= min"),
    (BASE + JOINT_GOAL + "T: {free: true, min: 1, max: 2, guess: 3}\n", "T.guess: expected a guess within"),
    (BASE + JOINT_GOAL + "T: {free: true, min: 1, max: 2, weight: -1}\n", "T.weight: expected a price of time"),
    (BASE + JOINT_GOAL + "T: {free: true, min: 1, max: 2, speed: 1}\n", "T.speed: unknown key"),
    (BASE + JOINT_GOAL + "T: {free: true, min: 1, max: 2}\nvia: [{t: 0.5, q: [0, 0]}]\n", "via[0].t: T is free"),
    (BASE + JOINT_GOAL + "T: 1.0\nvia: [{t: 1.0, q: [0, 0]}]\n", "via[0].t: expected 0 < t < T"),
    (BASE + JOINT_GOAL + "T: 1.0\nvia: [{s: 0.5}]\n", "via[0]: expected exactly one of 'q'"),
    (BASE + JOINT_GOAL + "T: 1.0\nvia: [{s: 0.5, t: 0.5, q: [0, 0]}]\n", "via[0]: expected exactly one of 't'"),
    (BASE + JOINT_GOAL + "T: 1.0\nvia: [{s: 0.5, q: [0, 0, 0]}]\n", "via[0].q: expected 2 values"),
    (BASE + JOINT_GOAL + "T: 1.0\nvia: [{s: 0.5, link: tool}]\n", "via[0].position: missing required key"),
    (BASE + JOINT_GOAL + "T: 1.0\nvia: [{s: 0.5, link: hand, position: [1, 0, 1]}]\n", "via[0].link: unknown link 'hand'"),
    (BASE + "T: 1.0\nx1: {link: tool}\n", "x1: expected exactly one of 'position'"),
    (BASE + "T: 1.0\nx1: {link: tool, position: [1, 0]}\n", "x1.position: expected a list of 3 numbers"),
    (BASE + "T: 1.0\nx1: {link: tool, position: [1, 0, 1], orientation: [1, 1, 0, 0]}\n",
     "x1.orientation: expected a unit quaternion"),
    (BASE + "T: 1.0\nx1: {link: tool, position: [1, 0, 1], dq: still}\n", "x1.dq: expected one of zero, free"),
    (BASE + "T: 1.0\nx1: {link: tool, target: {position: [1, 0, 1]}, match_velocity: true, dq: zero}\n",
     "x1.dq: match_velocity moves the link"),
    (BASE + "T: 1.0\nx1: {link: tool, target: {velocity: [1, 0, 1]}}\n", "x1.target.position: missing required key"),
    (BASE + "T: 1.0\nx1: {link: hand, position: [1, 0, 1]}\n", "x1.link: unknown link 'hand'"),
])
def test_bad_goal_keys_name_the_key_and_exit_2(workdir, text, message):
    r, _ = plan(workdir, text)
    assert r.exit_code == 2, r.output
    assert message in r.output, r.output


def test_a_link_goal_through_the_cli_reports_the_reached_pose(workdir):
    r, s = plan(workdir, BASE + f"T: 1.0\nx1: {{link: tool, position: {TOOL}}}\n")
    assert r.exit_code == 0, r.output
    assert s["converged"] and s["reached"]["link"] == "tool" and s["reached"]["position_error"] < 1e-9
    assert set(s["final_q"]) == {"shoulder", "elbow"} and s["boundary_error"] == 0.0
    q = np.array([s["final_q"]["shoulder"], s["final_q"]["elbow"]])
    assert np.max(np.abs(link_poses(load_robot(ROBOTS / "two_link.urdf"), q)["tool"][:3, 3] - TOOL)) < 1e-9


def test_vias_and_a_free_time_through_the_cli(workdir):
    text = BASE + JOINT_GOAL + "T: {free: true, min: 0.5, max: 3.0, guess: 1.0, weight: 5.0}\n" \
        + "via: [{s: 0.5, q: {shoulder: 0.6, elbow: 0.1}}, {s: 0.25, link: tool, position: " + str(TOOL) + "}]\n"
    r, s = plan(workdir, text)
    assert r.exit_code == 0, r.output
    assert s["converged"] and s["T_bound"] is None and abs(s["dJ_dT"] + 5.0) < 1e-6 * 5.0
    joint, link = s["vias"]
    assert joint["error"] <= 1e-12 and abs(joint["t"] - 0.5 * s["T"]) < 1e-12
    assert link["position_error"] <= 1e-12
    r, fixed = plan(workdir, text, "-T", "1.0")  # --duration fixes a free T
    assert r.exit_code == 0 and fixed["T"] == 1.0 and "dJ_dT" not in fixed


def test_the_shipped_catch_meets_the_ball_at_a_fixed_T(tmp_path):
    """configs/catch_ball.yaml at T = 0.41905 s (its free optimum, docs/goals.md): a soft catch within the limits."""
    r = CliRunner().invoke(app, ["plan", str(ROOT / "configs" / "catch_ball.yaml"), "--json", "-q", "-T", "0.41905",
                                 "-o", str(tmp_path / "catch.csv")])
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["converged"] and s["limit_violations"] == []
    assert s["reached"]["position_error"] < 1e-9 and s["reached"]["velocity_error"] < 1e-9


def test_a_free_t_task_simulated_with_its_plan_s_torque_csv_runs_to_the_plan_s_t(tmp_path, monkeypatch):
    """The shipped free-T task: the CSV's last sample is the plan's T, and the replay reaches x1 there."""
    monkeypatch.chdir(tmp_path)
    task = ROOT / "configs" / "two_link_free_time.yaml"
    r = CliRunner().invoke(app, ["plan", str(task), "-o", "p.csv", "--json", "-q"])
    assert r.exit_code == 0, r.output
    planned = json.loads(r.stdout)
    T = planned["T"]
    assert abs(T - 1.5) > 0.1  # the optimum is not the guess
    # the search's work, summed over its fixed-T solves (the last one, warm, may take no iteration)
    assert planned["T_iterations"] >= max(planned["iterations"], 1) and planned["T_evaluations"] >= planned["T_solves"] > 1
    r = CliRunner().invoke(app, ["simulate", str(task), "--torque", "p.csv", "--integrator", "rk", "--json", "-q",
                                 "-o", "none", "--check", "1e-3"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["T"] == T and s["final_error"] < 1e-3


def test_a_free_t_task_simulated_with_its_plan_s_mcap_runs_to_the_plan_s_t(tmp_path, monkeypatch):
    """The shipped free-T task replayed with its plan's MCAP as ``--torque``: the plan's T (not the task's guess),
    and the exact Hermite torque brings the arm to x1 (1e-8)."""
    monkeypatch.chdir(tmp_path)
    task = ROOT / "configs" / "two_link_free_time.yaml"
    r = CliRunner().invoke(app, ["plan", str(task), "-o", "p.mcap", "--json", "-q"])
    assert r.exit_code == 0, r.output
    T = json.loads(r.stdout)["T"]
    r = CliRunner().invoke(app, ["simulate", str(task), "--torque", "p.mcap", "--json", "-q", "-o", "none",
                                 "--check", "1e-8"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["T"] == T and s["final_error"] < 1e-8


@pytest.mark.parametrize("config, shows", [("two_link_pose.yaml", "tool: position to"),
                                           ("two_link_free_time.yaml", "dJ_dT"),
                                           ("two_link_via.yaml", "boundary_error")])
def test_the_human_summary_of_a_task_with_goals(tmp_path, monkeypatch, config, shows):
    """The table a terminal shows (here forced by --progress) for every goal kind: it has no J error estimate
    (goals have none) and shows the reached pose or the free T's slope instead."""
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(app, ["plan", str(ROOT / "configs" / config), "--progress", "-o", "p.csv"])
    assert r.exit_code == 0, r.output
    assert "hoc plan" in r.output and shows in r.output and "internal error" not in r.output
