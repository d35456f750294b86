"""Issue 24: usage errors as one line, inputs that are not regular files, goals and limits checked before
any solve, provably infeasible tasks refused at once, summaries that tell the truth.

Every case runs the real CLI (typer's CliRunner) on the two-link arm (robots/two_link.urdf) with a
small N; each class is checked on several members, not only the issue's example.
"""
from __future__ import annotations

import os
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
    (["plan", "task.yaml", "--order"], ("--order", "requires an argument")),
    (["nosuch"], ("no such command", "nosuch")),
])
def test_usage_errors_are_one_line(workdir, args, needles):
    before = sorted(os.listdir(workdir))
    one_error_line(invoke(args), *needles)
    assert sorted(os.listdir(workdir)) == before


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
])
def test_vias_that_contradict_each_other_or_the_boundary_exit_2(workdir, vias, needles):
    one_error_line(_plan_text(workdir, VIA_BASE + f"via: {vias}\n"), "t.yaml", *needles)


def test_vias_that_repeat_each_other_are_not_a_contradiction(workdir):
    r = _plan_text(workdir, VIA_BASE + "via: [{t: 0.5, q: [0.3, 0.1]}, {s: 0.3333333333333333, q: [0.3, 0.1]}]\n",
                   "--check-gradient")
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
