"""Issue 24: usage errors as one line, inputs that are not regular files, goals and limits checked before
any solve, provably infeasible tasks refused at once, summaries that tell the truth.

Every case runs the real CLI (typer's CliRunner) on the two-link arm (robots/two_link.urdf) with a
small N; each class is checked on several members, not only the issue's example.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from hoc_cli.cli import app

ROOT = Path(__file__).resolve().parent.parent
ROBOTS = ROOT / "robots"

TASK = """\
robot: arm.urdf
x0: {q: [0.0, 0.0]}
x1: {q: [1.2, -0.6]}
T: 1.5
N: 4
"""


@pytest.fixture
def workdir(tmp_path, monkeypatch) -> Path:
    shutil.copy(ROBOTS / "two_link.urdf", tmp_path / "arm.urdf")
    (tmp_path / "task.yaml").write_text(TASK)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def invoke(args: list) -> object:
    return CliRunner().invoke(app, [str(a) for a in args])


def one_error_line(r, *needles: str, code: int = 2) -> str:
    """Exit ``code``, exactly one ``hoc: error:`` line on stderr holding every needle, no usage block."""
    assert r.exit_code == code, (r.exit_code, r.stderr, r.exception)
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("hoc: error: "), r.stderr
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    assert "Usage:" not in r.output and "Traceback" not in r.output
    return lines[0]


# --------------------------------------------------------------------------- §4 usage errors: one line
@pytest.mark.parametrize("args, needles", [
    (["plan", "task.yaml", "--starts", "0"], ("--starts", "expected an integer >= 1")),
    (["plan", "task.yaml", "--seed", "-1"], ("--seed", "expected an integer >= 0")),
    (["plan", "task.yaml", "-N", "abc"], ("--elements", "expected an integer")),
    (["plan", "task.yaml", "--tol", "small"], ("--tol", "expected a number")),
    (["simulate", "task.yaml", "--check", "x"], ("--check", "expected a number")),
    (["batch", "spec.yaml", "--workers", "0"], ("--workers", "expected an integer >= 1")),
    (["plan", "task.yaml", "--bogus"], ("--bogus", "no such option")),
    (["inspect", "arm.urdf", "--quiet"], ("--quiet", "no such option")),
    (["plan"], ("TASK.yaml", "missing argument")),
    (["inspect"], ("ROBOT.urdf", "missing argument")),
    (["plan", "task.yaml", "other.yaml"], ("unexpected extra argument", "other.yaml")),
    (["plan", "task.yaml", "--order"], ("--order", "requires an argument", "see hoc plan --help")),
    (["plan", "task.yaml", "--json=3"], ("--json", "does not take a value", "see hoc plan --help")),
    (["nosuch"], ("no such command", "nosuch")),
])
def test_usage_errors_are_one_line(workdir, args, needles):
    before = sorted(os.listdir(workdir))
    one_error_line(invoke(args), *needles)
    assert sorted(os.listdir(workdir)) == before


def test_a_usage_error_in_a_real_process_is_one_line_and_exit_2(workdir):
    import subprocess
    import sys

    hoc = [sys.executable, "-c", "from hoc_cli.cli import app; app()"]
    r = subprocess.run(hoc + ["plan", "task.yaml", "--starts", "0"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr == "hoc: error: --starts: expected an integer >= 1 (see hoc plan --help)\n"


def test_help_still_shows_the_usage(workdir):
    r = invoke(["plan", "--help"])
    assert r.exit_code == 0 and "Usage:" in r.output and "--starts" in r.output
    r = invoke([])
    assert "Usage:" in r.output and "plan" in r.output


def test_numpy_numbers_show_as_numbers():
    from hoc_cli.io.task.checks import show

    assert show(np.float64(1.49)) == "1.49"
    assert show([np.float64(1.49), np.int64(3)]) == "[1.49, 3]"
    assert show({"T": np.float32(0.5)}) == "{'T': 0.5}"


# --------------------------------------------------------------------------- §2 inputs that are not regular files
def _fifo(d: Path) -> Path:
    path = d / "pipe.yaml"
    os.mkfifo(path)
    return path


@pytest.mark.skipif(not hasattr(os, "mkfifo") or not Path("/dev/zero").exists(), reason="POSIX only")
@pytest.mark.parametrize("make, args, needles", [
    (None, ["plan", "/dev/zero"], ("/dev/zero", "character device", "task YAML")),
    (_fifo, ["plan", "{p}"], ("pipe.yaml", "FIFO", "task YAML")),
    (None, ["plan", "."], ("is a directory", "task YAML")),
    (None, ["plan", "task.yaml", "--init", "/dev/zero"], ("--init", "character device")),
    (_fifo, ["plan", "task.yaml", "--init", "{p}"], ("--init", "FIFO")),
    (None, ["simulate", "/dev/zero"], ("/dev/zero", "character device")),
    (_fifo, ["simulate", "{p}"], ("FIFO",)),
    (None, ["simulate", "task.yaml", "--torque", "/dev/zero"], ("--torque", "character device")),
    (None, ["batch", "/dev/zero"], ("/dev/zero", "character device")),
    (_fifo, ["batch", "{p}"], ("FIFO",)),
    (None, ["plot", "/dev/zero", "-o", "fig.png"], ("/dev/zero", "character device")),
    (_fifo, ["plot", "{p}", "-o", "fig.png"], ("FIFO",)),
    (None, ["inspect", "/dev/zero"], ("character device", "URDF")),
    (_fifo, ["new", "{p}"], ("FIFO", "URDF")),
    (None, ["new", "/dev/zero"], ("character device", "URDF")),
])
def test_inputs_that_are_not_regular_files_are_refused_at_once(workdir, make, args, needles):
    p = make(workdir) if make else None
    args = [a.replace("{p}", str(p)) if isinstance(a, str) else a for a in args]
    start = time.perf_counter()
    one_error_line(invoke(args), *needles)
    assert time.perf_counter() - start < 10  # nothing was opened (a FIFO would block, /dev/zero never end)


@pytest.mark.skipif(not hasattr(os, "mkfifo") or not Path("/dev/zero").exists(), reason="POSIX only")
@pytest.mark.parametrize("robot, needle", [("/dev/zero", "character device"), ("pipe.yaml", "FIFO"),
                                           (".", "is a directory"), ("missing.urdf", "URDF file not found")])
def test_a_robot_that_is_not_a_regular_file(workdir, robot, needle):
    _fifo(workdir)
    (workdir / "t.yaml").write_text(TASK.replace("arm.urdf", robot))
    one_error_line(invoke(["plan", "t.yaml", "-o", "none"]), "t.yaml: robot:", needle)


# --------------------------------------------------------------------------- §1 goals and limits checked before any solve
def _plan_text(workdir: Path, text: str, *args: str):
    (workdir / "t.yaml").write_text(text)
    return invoke(["plan", "t.yaml", *(() if "--check-gradient" in args else ("-o", "none")), *args])


VIA_BASE = TASK.replace("N: 4", "N: 6")


@pytest.mark.parametrize("vias, needles", [
    ("[{t: 0.5, q: [0.3, 0.1]}, {t: 0.5, q: [1.5, 0.1]}]", ("via[1]", "via[0]", "same instant", "shoulder")),
    ("[{t: 0.5, q: [0.3, 0.1]}, {s: 0.3333333333333333, q: [0.3, 0.9]}]", ("via[1]", "via[0]", "same instant", "elbow")),
    ("[{t: 0.5, q: [0.3, 0.1]}, {t: 0.5000000001, q: [1.5, 0.1]}]", ("via[1]", "same instant")),
    ("[{t: 0.5, q: [0.3, 0.1], dq: [0, 0]}, {t: 0.5, q: [0.3, 0.1], dq: [1, 0]}]", ("via[1]", "different dq")),
    ("[{t: 0.7, link: tool, position: [1, 0, 1]}, {t: 0.7, link: tool, position: [1, 0, 0.5]}]",
     ("via[1]", "different positions of tool")),
    ("[{t: 1.0e-12, q: [1.5, 0.1]}]", ("via[0]", "x0", "different q")),
    ("[{s: 0.9999999999999, q: [1.5, 0.1]}]", ("via[0]", "x1", "different q")),
    ("[{t: 1.0e-12, q: [0.0, 0.0]}]", ("via[0]", "instant of x0")),
    ("[{t: 0.5, q: [0.0, 0.0]}, {t: 0.5, link: tool, position: [1.0, 0.0, 1.0]}]",
     ("via[1]", "same instant", "tool at [2.0, 0.0, 0.0] m")),
    ("[{t: 0.5, link: tool, position: [2.0, 0.0, 0.0], orientation: [0.7071067811865476, 0, 0, 0.7071067811865476]}, "
     "{s: 0.3333333333333333, q: [0.0, 0.0]}]", ("via[1]", "same instant", "orientation 1.57 rad")),
])
def test_vias_that_contradict_each_other_or_the_boundary_exit_2(workdir, vias, needles):
    one_error_line(_plan_text(workdir, VIA_BASE + f"via: {vias}\n"), "t.yaml", *needles)


@pytest.mark.parametrize("vias", ["[{t: 0.5, q: [0.3, 0.1]}, {s: 0.3333333333333333, q: [0.3, 0.1]}]",
                                  "[{t: 0.5, q: [0.0, 0.0]}, {t: 0.5, link: tool, position: [2.0, 0.0, 0.0]}]"])
def test_vias_that_agree_at_one_instant_are_not_a_contradiction(workdir, vias):
    r = _plan_text(workdir, VIA_BASE + f"via: {vias}\n", "--check-gradient")
    assert r.exit_code == 0, r.stderr


@pytest.mark.parametrize("extra, needles", [
    ("via: [{t: 0.5, q: [0.3, 3.5]}]\n", ("via[0].q.elbow", "position limits [-3.14159, 3.14159]")),
    ("via: [{t: 0.5, q: {shoulder: -4.0, elbow: 0.0}}]\n", ("via[0].q.shoulder", "position limits")),
    ("via: [{t: 0.5, q: [0.3, 0.5], dq: [20, 0]}]\n", ("via[0].dq.shoulder", "velocity limit 10")),
    ("via: [{t: 0.5, q: [2.5, 0.5]}]\nlimits: {position: {shoulder: [-0.1, 2.0]}}\n",
     ("via[0].q.shoulder", "[-0.1, 2]")),
    ("joints: [elbow]\nlocked: {shoulder: 4.0}\n", ("locked.shoulder", "[-3.14159, 3.14159]")),
])
def test_vias_and_locked_values_outside_the_limits_exit_2_when_enforced(workdir, extra, needles):
    text = VIA_BASE + extra
    if "joints: [elbow]" in extra:
        text = text.replace("[0.0, 0.0]", "[0.0]").replace("[1.2, -0.6]", "[-0.6]")
    one_error_line(_plan_text(workdir, text), "t.yaml", *needles)
    r = _plan_text(workdir, text, "--limits", "report", "--check-gradient")  # reported, not refused
    assert r.exit_code == 0, r.stderr


@pytest.mark.parametrize("old, new, key", [
    ("x1: {q: [1.2, -0.6]}", "x1: {q: [1.0e+300, -0.6]}", "x1.q[0]"),
    ("x0: {q: [0.0, 0.0]}", "x0: {q: [0.0, 0.0], dq: {shoulder: 0.0, elbow: -2.0e+7}}", "x0.dq.elbow"),
    ("N: 6", "N: 6\nvia: [{t: 0.5, q: [0.3, 1.0e+300]}]", "via[0].q[1]"),
    ("N: 6", "N: 6\nvia: [{t: 0.5, link: tool, position: [1.0e+300, 0, 0]}]", "via[0].position[0]"),
    ("x1: {q: [1.2, -0.6]}", "x1: {link: tool, position: [0.5, 0.0, 1.0e+7]}", "x1.position[2]"),
    ("x1: {q: [1.2, -0.6]}", "x1: {link: tool, target: {position: [1, 0, 0], velocity: [0, 0, -1.0e+300]}, "
     "match_velocity: true}", "x1.target.velocity[2]"),
    ("N: 6", "N: 6\ngravity: [0.0, 0.0, -1.0e+308]", "gravity[2]"),
    ("N: 6", "N: 6\njoints: [shoulder]\nlocked: {elbow: 1.0e+9}", "locked.elbow"),
])
def test_values_of_no_physical_size_exit_2(workdir, old, new, key):
    text = VIA_BASE.replace(old, new)
    if "joints: [shoulder]" in new:
        text = text.replace("[0.0, 0.0]", "[0.0]").replace("[1.2, -0.6]", "[1.2]")
    one_error_line(_plan_text(workdir, text), f"t.yaml: {key}:", "physical size")


@pytest.mark.parametrize("text, key, needles", [
    (VIA_BASE.replace("x1: {q: [1.2, -0.6]}", "x1: {link: base, position: [1.0, 0.0, 0.5]}"), "x1.link",
     ("'base'", "shoulder, elbow")),
    (VIA_BASE.replace("x0: {q: [0.0, 0.0]}", "joints: [elbow]\nx0: {q: [0.0]}")
     .replace("x1: {q: [1.2, -0.6]}", "x1: {link: upper_arm, position: [1.0, 0.0, 0.0]}"), "x1.link",
     ("'upper_arm'", "elbow", "locked joints: shoulder")),
    (VIA_BASE.replace("x0: {q: [0.0, 0.0]}", "joints: [elbow]\nx0: {q: [0.0]}").replace("[1.2, -0.6]", "[1.0]")
     + "via: [{t: 0.5, link: upper_arm, position: [1.0, 0.0, 0.0]}]\n", "via[0].link", ("'upper_arm'", "elbow")),
])
def test_a_link_goal_that_no_task_joint_moves_exits_2(workdir, text, key, needles):
    one_error_line(_plan_text(workdir, text), f"t.yaml: {key}:", "not moved by any task joint", *needles)


@pytest.mark.parametrize("joints, goal, key, needles", [
    ("joints: [elbow]\n", "x1: {link: forearm, position: [1.0, 0.0, 0.5]}", "x1.position",
     ("position of link 'forearm'", "stays at [1.0, 0.0, 0.0] m")),  # the elbow turns the forearm about its origin
    ("", "x1: {link: upper_arm, position: [0.5, 0.0, 0.5]}", "x1.position", ("'upper_arm'", "[0.0, 0.0, 0.0]")),
    ("joints: [elbow]\n", "x1: {q: [0.5]}\nvia: [{t: 0.5, link: forearm, position: [0.0, 0.0, 1.0]}]",
     "via[0].position", ("'forearm'",)),
])
def test_a_link_position_no_task_joint_moves_exits_2(workdir, joints, goal, key, needles):
    text = joints + VIA_BASE.replace("x1: {q: [1.2, -0.6]}", goal)
    if joints:
        text = text.replace("x0: {q: [0.0, 0.0]}", "x0: {q: [0.0]}")
    one_error_line(_plan_text(workdir, text), f"t.yaml: {key}:", "not moved by any task joint", *needles)


def test_a_goal_at_the_position_no_task_joint_moves_is_kept(workdir):
    """The forearm's origin stays at (1, 0, 0) m when only the elbow moves; its orientation is the goal."""
    text = ("joints: [elbow]\n" + VIA_BASE.replace("x0: {q: [0.0, 0.0]}", "x0: {q: [0.0]}")
            .replace("x1: {q: [1.2, -0.6]}", "x1: {link: forearm, position: [1.0, 0.0, 0.0], "
                     "orientation: [0.9238795325112867, 0, -0.3826834323650898, 0]}"))
    r = _plan_text(workdir, text, "--json")
    assert r.exit_code == 0, r.stderr
    assert json.loads(r.stdout)["final_q"]["elbow"] == pytest.approx(np.pi / 4, abs=1e-8)


# --------------------------------------------------------------------------- §1 provably infeasible: exit 1 at once
def _lp_shortest_time(d, v0, v1, a, v=np.inf, K=400):
    """Independent reference: the shortest T for which piecewise-constant accelerations |u| <= a on K
    steps take (0, v0) to (d, v1) with the step-end rates within ±v, by bisection on LP feasibility.
    """
    from scipy.optimize import linprog

    def feasible(T):
        h = T / K
        # rate after step k: v0 + h Σ_{j<=k} u_j; position at T: v0 T + h² Σ_j (K - j - ½) u_j
        pos = h * h * (K - np.arange(K) - 0.5)
        A_eq = np.vstack([pos, np.full(K, h)])
        b_eq = [d - v0 * T, v1 - v0]
        A_ub = b_ub = None
        if np.isfinite(v):
            L = np.tril(np.ones((K, K))) * h
            A_ub, b_ub = np.vstack([L, -L]), np.concatenate([np.full(K, v - v0), np.full(K, v + v0)])
        r = linprog(np.zeros(K), A_ub=A_ub, b_ub=b_ub, A_eq=A_eq, b_eq=b_eq, bounds=[(-a, a)] * K, method="highs")
        return r.status == 0

    lo, hi = 0.0, 50.0
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if feasible(mid) else (mid, hi)
    return hi


@pytest.mark.parametrize("d, v0, v1, a", [(1.0, 0.0, 0.0, 2.0), (1.0, 1.0, 0.0, 2.0), (-0.5, 1.0, -1.0, 3.0),
                                          (0.2, -1.0, 2.0, 1.5), (2.0, 0.5, 0.5, 1.0)])
def test_the_acceleration_bound_is_the_double_integrators_shortest_time(d, v0, v1, a):
    from hoc_cli.constraints.feasibility import double_integrator_time

    t = double_integrator_time(np.array([d]), np.array([v0]), np.array([v1]), np.array([a]))[0]
    ref = _lp_shortest_time(d, v0, v1, a)
    assert t <= ref * (1 + 1e-6) and t == pytest.approx(ref, rel=2e-2)  # a lower bound, and tight


@pytest.mark.parametrize("d, v, a", [(1.0, 0.5, 2.0), (1.0, 5.0, 2.0), (3.0, 1.0, 1.0)])
def test_the_rest_to_rest_bound_with_velocity_and_acceleration_limits(d, v, a):
    from hoc_cli.constraints.feasibility import rest_to_rest_time

    t = rest_to_rest_time(np.array([d]), np.array([v]), np.array([a]))[0]
    ref = _lp_shortest_time(d, 0.0, 0.0, a, v=v, K=150)
    assert t <= ref * (1 + 1e-6) and t == pytest.approx(ref, rel=2e-2)


def _two_link():
    from hoc_cli.model import load_robot
    from hoc_cli.system import RobotSystem

    model = load_robot(ROBOTS / "two_link.urdf")
    return model, RobotSystem(model)


def test_the_potential_energy_difference_matches_the_two_link_arms_closed_form():
    from hoc_cli.constraints.feasibility import potential_difference

    _, system = _two_link()
    q0, q1 = np.array([0.0, 0.0]), np.array([1.2, -0.6])

    def V(q):  # 1 kg links of 1 m, centres of mass at mid-length; a positive angle lifts the arm
        return 9.81 * (0.5 * np.sin(q[0]) + np.sin(q[0]) + 0.5 * np.sin(q[0] + q[1]))

    assert potential_difference(system, q0, q1) == pytest.approx(V(q1) - V(q0), rel=1e-12)


def test_an_effort_limit_at_a_pinned_state_is_infeasible_only_within_acceleration_limits():
    from hoc_cli.constraints import JointLimits
    from hoc_cli.constraints.feasibility import Pinned, instant_bound

    model, system = _two_link()
    rest = Pinned(0.0, np.zeros(2), np.zeros(2), "x0")
    gravity = system.inverse_dynamics(np.zeros((1, 2)), np.zeros((1, 2)), np.zeros((1, 2)))[0]
    assert gravity == pytest.approx([19.62, 4.905])  # m g l/2 + m g 3l/2 at the shoulder, m g l/2 at the elbow

    def limits(effort, acceleration):
        return JointLimits.from_arrays(model.joint_names, effort=effort, acceleration=acceleration)

    tiny = [1e-9, 1e-9]  # q̈ ≈ 0: u ≈ gravity
    assert instant_bound(system, limits([19.0, 100.0], tiny), rest).joint == "shoulder"
    assert instant_bound(system, limits([100.0, 4.8], tiny), rest).joint == "elbow"
    assert instant_bound(system, limits([19.7, 5.0], tiny), rest) is None
    assert instant_bound(system, limits([1e-3, 1e-3], None), rest) is None  # the arm may start by falling
    # with room to accelerate the torques can be lowered: shoulder 1 N·m needs q̈ the limits allow, or not
    assert instant_bound(system, limits([1.0, 50.0], [1.0, 1.0]), rest) is not None
    assert instant_bound(system, limits([1.0, 50.0], [100.0, 100.0]), rest) is None


@pytest.mark.parametrize("text, args, needles", [
    (TASK, ["-T", "1.0e-6"], ("T:", "0.12 s", "shoulder's velocity limit")),
    (TASK.replace("T: 1.5", "T: 1.0e-6"), [], ("T:", "0.12 s")),
    (TASK, ["-T", "0.11"], ("T:", "shorter than 0.12 s")),
    (TASK + "limits: {velocity: {elbow: 0.1}}\n", [], ("T:", "6 s", "elbow's velocity limit")),
    (TASK + "limits: {acceleration: {shoulder: 1.0}, velocity: {shoulder: 1.0}}\n", [],
     ("T:", "2.2 s", "shoulder's velocity and acceleration limits")),
    (TASK.replace("N: 4", "N: 6") + "via: [{t: 0.01, q: [0.5, 0.0]}]\n", [], ("T:", "between x0 (t = 0) and via[0]",)),
    (TASK.replace("T: 1.5", "T: {free: true, min: 0.01, max: 0.1}"), [], ("T.max:", "T.max = 0.1 s", "0.12 s")),
    (TASK + "limits: {acceleration: {shoulder: 1.0, elbow: 1.0}, effort: {shoulder: 1.0}}\n", [],
     ("limits:", "at x0", "shoulder needs |u| >=", "no duration T helps")),
    ("robot: pend.urdf\nx0: {q: [0.0]}\nx1: {q: [1.0], dq: [0.5]}\nT: 1.0\nN: 4\nlimits: {effort: {pivot: 1.0e-3}}\n",
     [], ("T:", "energy", "effort and velocity limits")),
    ("robot: pend.urdf\nx0: {q: [0.0]}\nx1: {q: [1.0]}\nT: 1.0\nN: 4\nlimits: {effort: {pivot: 1.0e-3}}\n", [],
     ("limits:", "x1 (t = T) is a rest state the arm holds", "pivot |u| =", "no duration T helps")),
])
def test_provably_infeasible_tasks_exit_1_at_once(workdir, text, args, needles):
    shutil.copy(ROBOTS / "pendulum.urdf", workdir / "pend.urdf")
    (workdir / "t.yaml").write_text(text)
    before = sorted(os.listdir(workdir))
    start = time.perf_counter()
    r = invoke(["plan", "t.yaml", *args])
    assert time.perf_counter() - start < 5
    line = one_error_line(r, "t.yaml", "infeasible", *needles, code=1)
    assert "hoc: error: t.yaml: " + needles[0] in line
    assert sorted(os.listdir(workdir)) == before  # nothing written
    r = invoke(["plan", "t.yaml", *args, "--json", "-o", "none"])
    summary = json.loads(r.stdout)
    assert r.exit_code == 1 and summary["status"] == "infeasible" and summary["converged"] is False
    assert "infeasible" in summary["message"]


def test_limits_in_report_mode_are_never_a_proof(workdir):
    r = invoke(["plan", "task.yaml", "-T", "0.05", "--limits", "report", "--check-gradient"])
    assert r.exit_code == 0, r.stderr


def test_the_duration_bound_is_claimed_only_below_it():
    """Shoulder at a constant 10 rad/s (its limit) covers 1.2 rad in exactly 0.12 s: T = 0.12 s is feasible."""
    from hoc_cli.constraints import JointLimits
    from hoc_cli.constraints.feasibility import Pinned, infeasibility

    model, system = _two_link()
    limits = JointLimits.from_model(model)
    pinned = [Pinned(0.0, np.array([0.0, 0.0]), np.array([10.0, 0.0]), "x0"),
              Pinned(1.0, np.array([1.2, -0.6]), np.array([10.0, 0.0]), "x1")]
    assert infeasibility(system, limits, pinned, 0.12) is None
    bound = infeasibility(system, limits, pinned, 0.119)
    assert bound is not None and bound.T_min == pytest.approx(0.12) and bound.joint == "shoulder"


# --------------------------------------------------------------------------- §5 messages that tell the truth
@pytest.mark.parametrize("outputs, said", [(["-o", "none"], "best iterate was not written (-o none)"),
                                           (["-o", "out.csv"], "best iterate was written")])
def test_a_run_that_did_not_converge_says_whether_it_wrote_anything(workdir, outputs, said):
    r = invoke(["plan", "task.yaml", "--max-iter", "1", "--limits", "report", *outputs])
    assert r.exit_code == 1 and said in r.stderr and ("was written" in r.stderr) == ("out.csv" in outputs)
    assert (workdir / "out.csv").exists() == ("out.csv" in outputs)


def test_a_cold_free_time_plan_does_not_call_itself_a_warm_replan(workdir):
    (workdir / "t.yaml").write_text(TASK.replace("T: 1.5", "T: {free: true, min: 0.5, max: 3.0, weight: 20}")
                                    + "via: [{s: 0.5, q: [0.8, 0.2]}]\n")
    r = invoke(["plan", "t.yaml", "-o", "none", "--json"])
    s = json.loads(r.stdout)
    assert r.exit_code == 0 and s["converged"] and "warm" not in s["message"] and "warm_start" not in s
    assert s["message"].startswith("Newton steps in x and T from the plan at the guess")


class _Result:
    def __init__(self, violation):
        self.violation = violation


@pytest.mark.parametrize("violation, summary, expected", [
    (0.0, {"status": "converged", "message": "the stopping test held", "vias": [{"t": 0.5, "error": 0.0}]}, {}),
    (0.0, {"status": "converged", "message": "the stopping test held", "vias": [{"t": 0.5, "error": 0.0},
                                                                              {"t": 0.5, "error": 1.2}]},
     {"status": "goal_missed", "message": "goal missed by 1.2 (via[1])", "converged": False}),
    (3e-4, {"status": "converged", "message": "the stopping test held",
            "reached": {"link": "tool", "position_error": 3e-4}},
     {"status": "goal_missed", "message": "goal missed by 0.0003 (x1)", "converged": False}),
    (2e-2, {"status": "max_iter", "message": "the maximum number of iterations was reached",
            "reached": {"link": "tool", "position_error": 2e-2, "orientation_error": 1e-3}},
     {"message": "goal missed by 0.02 (x1); the maximum number of iterations was reached", "converged": False}),
])
def test_a_missed_goal_is_reported_as_missed_not_as_a_stopping_test(violation, summary, expected):
    from hoc_cli.report.goals import goal_miss

    assert goal_miss(_Result(violation), summary) == expected


def test_the_readmes_task_file_example_plans_as_printed(tmp_path, monkeypatch):
    """The first YAML block under '## Task file' in README.md, byte for byte, beside robots/two_link.urdf."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    section = readme[readme.index("## Task file"):]
    block = re.search(r"```yaml\n(.*?)```", section, re.S).group(1)
    assert block.startswith("robot: ../robots/two_link.urdf")
    (tmp_path / "robots").mkdir()
    shutil.copy(ROBOTS / "two_link.urdf", tmp_path / "robots" / "two_link.urdf")
    (tmp_path / "configs").mkdir()
    (tmp_path / "configs" / "task.yaml").write_text(block, encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    r = invoke(["plan", "configs/task.yaml", "--json"])
    assert r.exit_code == 0, r.stderr
    s = json.loads(r.stdout)
    assert s["converged"] and s["N"] == 16 and s["limits_mode"] == "enforce"
    assert (tmp_path / "task.mcap").exists() and (tmp_path / "task.csv").exists()


def test_a_limited_plan_reports_its_reduced_gradient(workdir):
    """The SQP's plan with the shoulder's velocity limit active: the cost gradient alone is large there; the
    reported grad_norm is what is left after the active rows' gradients (a replan's idea, goals/replan.py)."""
    from hoc_cli.model import load_robot
    from hoc_cli.problem import ControlProblem
    from hoc_cli.system import RobotSystem

    (workdir / "t.yaml").write_text(TASK.replace("N: 4", "N: 16") + "limits: {velocity: {shoulder: 1.2}}\n")
    r = invoke(["plan", "t.yaml", "-o", "none", "--json"])
    s = json.loads(r.stdout)
    assert r.exit_code == 0 and s["converged"] and s["active_limits"]
    # the plain cost gradient at the same plan, computed here from the plan's coefficients
    invoke(["plan", "t.yaml", "-o", "p.mcap", "-q"])
    from hoc_cli.io.mcap import read_plan

    tr = read_plan(workdir / "p.mcap").trajectory
    problem = ControlProblem(RobotSystem(load_robot(workdir / "arm.urdf")), tr.mesh, np.zeros(2), np.zeros(2),
                             np.array([1.2, -0.6]), np.zeros(2), G=s["gauss_points"])
    g = problem.evaluate(problem.layout.pack(np.asarray(tr.coeffs))).grad
    assert np.max(np.abs(g)) > 1.0
    assert 0 < s["grad_norm"] <= 1e-6 * np.max(np.abs(g))


def test_wall_time_is_the_whole_solve_of_starts_and_auto(workdir):
    r = invoke(["plan", "task.yaml", "-o", "none", "--json", "--starts", "3"])
    s = json.loads(r.stdout)
    assert r.exit_code == 0 and s["wall_time_s"] > s["plan_solve_wall_time_s"] > 0
    (workdir / "auto.yaml").write_text(TASK.replace("N: 4\n", "accuracy: 1.0e-12\n"))
    r = invoke(["plan", "auto.yaml", "-o", "none", "--json"])
    s = json.loads(r.stdout)
    assert r.exit_code == 0 and len(s["N_auto"]) > 1 and s["wall_time_s"] > s["plan_solve_wall_time_s"] > 0


@pytest.mark.parametrize("text, args, key", [
    (TASK.replace("T: 1.5", "T: 1.0e-12"), [], "T"),
    (TASK, ["-T", "1e-10"], "--duration"),
    (TASK.replace("T: 1.5", "T: {free: true, min: 1.0e-15, max: 2.0}"), [], "T.min"),
])
def test_a_duration_of_no_physical_size_exits_2(workdir, text, args, key):
    (workdir / "t.yaml").write_text(text)
    one_error_line(invoke(["plan", "t.yaml", "-o", "none", "--limits", "report", *args]), f"t.yaml: {key}:",
                   "at least 1e-09 s")


def test_a_task_file_far_larger_than_any_task_is_refused_before_it_is_read(workdir):
    with open(workdir / "big.yaml", "wb") as fh:
        fh.truncate(17 << 20)  # sparse: 17 MiB of zeros
    one_error_line(invoke(["plan", "big.yaml", "-o", "none"]), "big.yaml", "17 MiB", "at most 16 MiB")


def test_a_link_via_the_limits_keep_out_of_reach_is_reported_as_a_missed_goal(workdir):
    """The tool straight up needs the shoulder at π/2; its position limit is ±0.3 rad (enforced)."""
    (workdir / "t.yaml").write_text(TASK.replace("[1.2, -0.6]", "[0.2, 0.0]")
                                    + "via: [{t: 0.75, link: tool, position: [0.0, 0.0, 2.0]}]\n"
                                    + "limits: {position: {shoulder: [-0.3, 0.3], elbow: [-0.3, 0.3]}}\n")
    r = invoke(["plan", "t.yaml", "-o", "none", "--json", "--max-iter", "30"])
    s = json.loads(r.stdout)
    assert r.exit_code == 1 and not s["converged"]
    assert s["message"].startswith(f"goal missed by {s['vias'][0]['position_error']:.3g} (via[0])")
    assert "goal missed by" in r.stderr and "(via[0])" in r.stderr


@pytest.mark.skipif(not hasattr(os, "mkfifo") or not Path("/dev/zero").exists(), reason="POSIX only")
@pytest.mark.parametrize("section, needles", [
    ("collision: {srdf: /dev/zero}", ("collision.srdf:", "character device")),
    ("collision: {scene: pipe.yaml}", ("collision.scene:", "FIFO")),
])
def test_files_a_task_names_that_are_not_regular_files(workdir, section, needles):
    _fifo(workdir)
    (workdir / "t.yaml").write_text(TASK + section + "\n")
    start = time.perf_counter()
    one_error_line(invoke(["plan", "t.yaml", "-o", "none"]), "t.yaml", *needles)
    assert time.perf_counter() - start < 10
