"""Bad input gets one clear line and exit 2; numerical failures exit 1; nothing is touched; runs repeat.

Every malformed input below goes through the real CLI (typer's CliRunner) in a directory where
``out.csv`` and ``out.mcap`` already hold known bytes and are the requested outputs. Each case
checks: exit code 2; exactly one line on standard error, ``hoc: error: …``, naming the file and
the key or joint and what was expected; no traceback; no file created, none changed. With
``--debug`` the same input re-raises the ``HocError`` (typer then prints its traceback).

Malformed task files already covered by tests/test_task.py (empty file, YAML syntax, a list at the
top level, missing robot/x1, unknown keys, T ≤ 0, N < 1, NaN/inf, unknown order/cost/method, wrong
lengths...) and URDF errors covered through the Python API by tests/test_model.py are not repeated
here as task texts; URDF errors are repeated here through ``hoc plan`` and ``hoc inspect``.
"""
from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
from typer.testing import CliRunner

from hoc_cli.cli import app
from hoc_cli.errors import HocError
from hoc_cli.io.csv import write_csv
from hoc_cli.trajectory import Trajectory

ROOT = Path(__file__).resolve().parent.parent
ROBOTS = ROOT / "robots"
KEEP = {"out.csv": b"KEEP: an earlier CSV\n", "out.mcap": b"KEEP: an earlier MCAP\n"}

TASK = """\
robot: arm.urdf
x0: {q: [0.0, 0.0]}
x1: {q: [1.2, -0.6]}
T: 1.5
N: 4
"""
SIM_TASK = """\
robot: arm.urdf
x0: {q: [0.1, 0.2]}
T: 1.0
N: 4
"""


# --------------------------------------------------------------------------- helpers
def snapshot(d: Path) -> dict[str, bytes | None]:
    """Every path under ``d`` with its bytes (None for a directory)."""
    return {str(p.relative_to(d)): (None if p.is_dir() else p.read_bytes()) for p in sorted(d.rglob("*"))}


@pytest.fixture
def workdir(tmp_path, monkeypatch) -> Path:
    shutil.copy(ROBOTS / "two_link.urdf", tmp_path / "arm.urdf")
    (tmp_path / "task.yaml").write_text(TASK)
    (tmp_path / "sim.yaml").write_text(SIM_TASK)
    for name, data in KEEP.items():
        (tmp_path / name).write_bytes(data)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def invoke(args: list[str]):
    return CliRunner().invoke(app, [str(a) for a in args])


def assert_rejected(d: Path, args: list[str], needles: tuple[str, ...]) -> str:
    """Exit 2, one line naming what is wrong, no traceback, nothing created or changed; --debug re-raises."""
    before = snapshot(d)
    r = invoke(args)
    assert r.exit_code == 2, (r.exit_code, r.stderr, r.exception)
    lines = r.stderr.splitlines()
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith("hoc: error: "), lines[0]
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    assert "Traceback" not in r.output and r.stdout == ""
    assert snapshot(d) == before, "a file was created or changed"
    r = invoke(args + ["--debug"])
    assert isinstance(r.exception, HocError), (r.exception, r.stderr)  # re-raised: typer prints the traceback
    assert snapshot(d) == before
    return lines[0]


def write_task(d: Path, text: str, name: str = "task.yaml") -> Path:
    (d / name).write_text(text)
    return d / name


def plan_args(task: str = "task.yaml", *extra: str) -> list[str]:
    return ["plan", task, "-o", "out.csv", "-o", "out.mcap", *extra]


# --------------------------------------------------------------------------- task files
def _task(text: str) -> Callable[[Path], list[str]]:
    def setup(d: Path) -> list[str]:
        write_task(d, text)
        return plan_args()
    return setup


def _bytes_task(d: Path) -> list[str]:
    (d / "task.yaml").write_bytes(b"robot: \xff\xfe arm.urdf\n")
    return plan_args()


def _directory_task(d: Path) -> list[str]:
    (d / "dir.yaml").mkdir()
    return plan_args("dir.yaml")


def _override(*extra: str) -> Callable[[Path], list[str]]:
    return lambda d: plan_args("task.yaml", *extra)


def _with(old: str, new: str) -> str:
    assert old in TASK
    return TASK.replace(old, new)


TASK_CASES = [
    ("task file that is not UTF-8 text", _bytes_task, ("task.yaml", "UTF-8")),
    ("task path that is a directory", _directory_task, ("dir.yaml", "is a directory")),
    ("top level is a plain string", _task("just some words\n"), ("task.yaml", "expected a mapping", "str")),
    ("missing T", _task(_with("T: 1.5\n", "")), ("task.yaml", "T: missing required key")),
    ("N neither an integer nor auto", _task(_with("N: 4\n", "N: many\n")), ("task.yaml", "N: expected an integer")),
    ("missing x0", _task(_with("x0: {q: [0.0, 0.0]}\n", "")), ("task.yaml", "x0: missing required key")),
    ("unknown key inside x0", _task(_with("{q: [0.0, 0.0]}", "{q: [0.0, 0.0], ddq: [0, 0]}")),
     ("task.yaml", "x0.ddq: unknown key 'ddq'", "expected one of: q, dq")),
    ("unknown key inside output", _task(TASK + "output: {hz: 10}\n"), ("task.yaml", "output.hz: unknown key")),
    ("x0.q is a string", _task(_with("[0.0, 0.0]", "zero")), ("task.yaml", "x0.q: expected a list of numbers")),
    ("x0.q is an empty list", _task(_with("[0.0, 0.0]", "[]")), ("task.yaml", "x0.q: expected 2 values")),
    ("x0.q mapping misses a joint", _task(_with("[0.0, 0.0]", "{shoulder: 0.0}")),
     ("task.yaml", "x0.q: missing value for joint(s) elbow")),
    ("x0.q mapping with a number as key", _task(_with("[0.0, 0.0]", "{1: 0.0}")),
     ("task.yaml", "x0.q: expected joint names")),
    ("x1.dq of the wrong length", _task(_with("[1.2, -0.6]}", "[1.2, -0.6], dq: [0.0]}")),
     ("task.yaml", "x1.dq: expected 2 values")),
    ("joints is not a list", _task("joints: shoulder\n" + TASK), ("task.yaml", "joints: expected a non-empty list")),
    ("a task joint the URDF does not have", _task("joints: [shoulder, wrist]\n" + TASK),
     ("arm.urdf", "joint 'wrist'", "no such joint", "shoulder")),
    ("a locked joint the URDF does not have", _task("locked: {wrist: 0.0}\n" + TASK),
     ("task.yaml", "locked.wrist", "cannot be locked", "arm.urdf")),
    ("T is infinite", _task(_with("T: 1.5", "T: .inf")), ("task.yaml", "T: expected a duration T > 0")),
    ("T is a boolean", _task(_with("T: 1.5", "T: true")), ("task.yaml", "T: expected a duration T > 0")),
    ("T beyond the range of a double", _task(_with("T: 1.5", "T: 1" + "0" * 400)), ("task.yaml", "T: expected a duration")),
    ("N negative", _task(_with("N: 4", "N: -3")), ("task.yaml", "N: expected an integer >= 1")),
    ("N is a word", _task(_with("N: 4", "N: many")), ("task.yaml", "N: expected an integer >= 1")),
    ("order is a number", _task(TASK + "order: 5\n"), ("task.yaml", "order: expected one of quintic, cubic")),
    ("solver is a list", _task(TASK + "solver: [pr-cg]\n"), ("task.yaml", "solver: expected a mapping")),
    ("solver.tol is zero", _task(TASK + "solver: {tol: 0}\n"), ("task.yaml", "solver.tol: expected a tolerance > 0")),
    ("solver.max_iter is zero", _task(TASK + "solver: {max_iter: 0}\n"),
     ("task.yaml", "solver.max_iter: expected an integer >= 1")),
    ("gravity holds NaN", _task(TASK + "gravity: [0, 0, .nan]\n"), ("task.yaml", "gravity[2]: expected a finite number")),
    ("robot is a number", _task(_with("robot: arm.urdf", "robot: 42")), ("task.yaml", "robot: expected a path")),
    ("robot path too long to look up", _task(_with("robot: arm.urdf", "robot: " + "x" * 5000 + ".urdf")),
     ("task.yaml", "robot: URDF file not found")),
    ("--order override unknown", _override("--order", "septic"), ("task.yaml", "--order: expected one of quintic, cubic")),
    ("--duration override negative", _override("--duration", "-1"), ("task.yaml", "--duration: expected a duration > 0")),
    ("--tol override zero", _override("--tol", "0"), ("task.yaml", "--tol: expected a tolerance > 0")),
    ("--max-iter override zero", _override("--max-iter", "0"), ("task.yaml", "--max-iter: expected an integer >= 1")),
    ("--cost override unknown", _override("--cost", "energy"), ("task.yaml", "--cost: expected one of covariant, torque")),
    ("--method override unknown", _override("--method", "bfgs"), ("task.yaml", "--method: expected one of pr-cg")),
]


@pytest.mark.parametrize("setup,needles", [c[1:] for c in TASK_CASES], ids=[c[0] for c in TASK_CASES])
def test_a_malformed_task_exits_2_with_one_line_and_touches_nothing(workdir, setup, needles):
    assert_rejected(workdir, setup(workdir), needles)


def test_a_start_state_outside_the_urdf_limits_is_an_input_error_when_enforced_and_a_warning_when_reported(workdir):
    write_task(workdir, _with("x0: {q: [0.0, 0.0]}", "x0: {q: [3.5, 0.0]}"))
    r = invoke(plan_args())
    assert r.exit_code == 2
    (line,) = r.stderr.splitlines()
    for needle in ("task.yaml", "x0.q.shoulder", "3.5", "outside its position limits", "3.14159", "--limits report"):
        assert needle in line
    assert (workdir / "out.csv").read_bytes() == KEEP["out.csv"]  # nothing was written
    r = invoke(plan_args("task.yaml", "--limits", "report"))
    assert r.exit_code == 0, r.stderr
    lines = r.stderr.splitlines()
    assert len(lines) == 2 and all(line.startswith("hoc: warning: ") for line in lines), r.stderr
    for needle in ("task.yaml", "x0.q.shoulder = 3.5", "outside the URDF limits", "3.14159"):
        assert needle in lines[0]
    # and, after the outputs are written, the limit the plan breaks (it starts beyond it)
    assert "joint 'shoulder' exceeds its position limit [-3.142, 3.142]: worst " in lines[1]
    assert (workdir / "out.csv").read_bytes() != KEEP["out.csv"]  # the plan was written
    assert invoke(plan_args("task.yaml", "-q", "--limits", "report")).stderr == ""  # --quiet: nothing but errors


# --------------------------------------------------------------------------- URDFs through plan and inspect
def _link(name: str, mass: str = "1", ixx: str = "0.01") -> str:
    return (f'<link name="{name}"><inertial><origin xyz="0 0 0.1"/><mass value="{mass}"/><inertia ixx="{ixx}" '
            'ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>')


def _joint(name: str, parent: str, child: str, kind: str = "revolute", axis: str = "0 1 0", origin: str = "0 0 0.2") -> str:
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{origin}"/><axis xyz="{axis}"/><limit lower="-3" upper="3" effort="9" velocity="9"/></joint>')


def _robot(*elements: str) -> str:
    return '<?xml version="1.0"?>\n<robot name="bad">' + "".join(elements) + "</robot>"


GOOD_PAIR = (_link("base"), _link("l1"), _link("l2"), _joint("j1", "base", "l1"))
URDF_CASES = [
    ("URDF file missing", None, ("bad.urdf", "file not found")),
    ("malformed XML", "<robot name='x'><link name='a'></robot>", ("bad.urdf", "malformed XML")),
    ("root element is not robot", "<sdf><model/></sdf>", ("bad.urdf", "root element is <sdf>, expected <robot>")),
    ("floating joint", _robot(*GOOD_PAIR, _joint("free", "l1", "l2", kind="floating")),
     ("bad.urdf", "joint 'free'", "floating joints are not supported")),
    ("planar joint", _robot(*GOOD_PAIR, _joint("slide", "l1", "l2", kind="planar")),
     ("bad.urdf", "joint 'slide'", "planar joints are not supported")),
    ("several root links", _robot(*GOOD_PAIR, _link("stray")),
     ("bad.urdf", "several root links", "link 'l2'")),
    ("a cycle of joints", _robot(*GOOD_PAIR, _joint("j2", "l1", "l2"), _joint("j3", "l2", "l1")),
     ("bad.urdf", "joint 'j3'", "closed loop")),
    ("negative mass", _robot(_link("base"), _link("l1", mass="-2"), _joint("j1", "base", "l1")),
     ("bad.urdf", "link 'l1'", "mass -2.0 kg is negative")),
    ("inertia not positive definite", _robot(_link("base"), _link("l1", ixx="-0.5"), _joint("j1", "base", "l1")),
     ("bad.urdf", "link 'l1'", "not positive (semi)definite")),
    ("a joint naming an undefined link", _robot(_link("base"), _joint("j1", "base", "ghost")),
     ("bad.urdf", "joint 'j1'", "child link 'ghost' is not defined")),
    ("a zero joint axis", _robot(_link("base"), _link("l1"), _joint("j1", "base", "l1", axis="0 0 0")),
     ("bad.urdf", "joint 'j1'", "not a non-zero vector")),
    ("a non-finite joint origin", _robot(_link("base"), _link("l1"), _joint("j1", "base", "l1", origin="0 inf 0")),
     ("bad.urdf", "joint 'j1'", "origin is not finite")),
    ("a mass that is not a number", _robot(_link("base"), _link("l1", mass="heavy"), _joint("j1", "base", "l1")),
     ("bad.urdf", "not a valid URDF")),
]
MASSLESS = _robot(_link("base"), _link("l1"), '<link name="empty"/>', _joint("j1", "base", "l1"),
                  _joint("j2", "l1", "empty"))


def _bad_urdf(d: Path, text: str | None) -> None:
    if text is not None:
        (d / "bad.urdf").write_text(text)


@pytest.mark.parametrize("text,needles", [c[1:] for c in URDF_CASES], ids=[c[0] for c in URDF_CASES])
def test_a_bad_urdf_makes_plan_exit_2_naming_the_urdf_and_the_joint_or_link(workdir, text, needles):
    _bad_urdf(workdir, text)
    write_task(workdir, "robot: bad.urdf\nx0: {q: [0.0]}\nx1: {q: [1.0]}\nT: 1.0\nN: 4\n")
    needles = tuple(n for n in needles if n != "bad.urdf" or text is not None)  # missing: the task names it
    line = assert_rejected(workdir, plan_args(), needles)
    assert "bad.urdf" in line


@pytest.mark.parametrize("text,needles", [c[1:] for c in URDF_CASES], ids=[c[0] for c in URDF_CASES])
def test_a_bad_urdf_makes_inspect_exit_2_naming_the_urdf_and_the_joint_or_link(workdir, text, needles):
    _bad_urdf(workdir, text)
    assert_rejected(workdir, ["inspect", "bad.urdf"], needles)
    assert_rejected(workdir, ["inspect", "bad.urdf", "--json"], needles)


def test_a_movable_joint_with_a_massless_subtree_is_exit_2_for_plan_and_a_warning_for_inspect(workdir):
    (workdir / "bad.urdf").write_text(MASSLESS)
    write_task(workdir, "robot: bad.urdf\nx0: {q: [0.0, 0.0]}\nx1: {q: [1.0, 0.0]}\nT: 1.0\nN: 4\n")
    assert_rejected(workdir, plan_args(), ("bad.urdf", "joint 'j2'", "singular mass matrix"))
    r = invoke(["inspect", "bad.urdf", "--json"])
    assert r.exit_code == 0
    doc = json.loads(r.stdout)
    assert doc["plannable"] is False and "joint 'j2'" in doc["problem"]


# --------------------------------------------------------------------------- output paths
def _outputs(command: str, *outs: str) -> Callable[[Path], list[str]]:
    def setup(d: Path) -> list[str]:
        (d / "sub.csv").mkdir(exist_ok=True)
        args = [command, "task.yaml" if command == "plan" else "sim.yaml"]
        for o in outs:
            args += ["-o", o]
        return args
    return setup


OUTPUT_CASES = []
for _cmd in ("plan", "simulate"):
    OUTPUT_CASES += [
        (f"{_cmd}: output inside a missing directory", _outputs(_cmd, "out.csv", "nodir/x.mcap"),
         ("nodir/x.mcap", "--output", "directory 'nodir' does not exist")),
        (f"{_cmd}: output whose parent is a regular file", _outputs(_cmd, "out.csv", "task.yaml/x.csv"),
         ("task.yaml/x.csv", "--output", "'task.yaml' is not a directory")),
        (f"{_cmd}: output that is a directory", _outputs(_cmd, "sub.csv"), ("sub.csv", "--output", "is a directory")),
        (f"{_cmd}: output without an extension", _outputs(_cmd, "out.csv", "result"),
         ("result", "--output", "unknown output extension '(none)'", ".csv or .mcap")),
        (f"{_cmd}: output with an unknown extension", _outputs(_cmd, "out.json"),
         ("out.json", "--output", "unknown output extension '.json'")),
    ]


@pytest.mark.parametrize("setup,needles", [c[1:] for c in OUTPUT_CASES], ids=[c[0] for c in OUTPUT_CASES])
def test_a_bad_output_path_exits_2_before_any_work(workdir, setup, needles):
    if "simulate" in setup(workdir)[0]:
        write_task(workdir, SIM_TASK + "torque: zero\n", "sim.yaml")
    assert_rejected(workdir, setup(workdir), needles)


def test_an_output_in_a_read_only_directory_exits_2(workdir, monkeypatch):
    """Root may write anywhere, so the permission answer is simulated: os.access says no for the directory."""
    locked = workdir / "locked"
    locked.mkdir()
    real_access = os.access

    def access(path, mode, *args, **kwargs):
        if mode & os.W_OK and os.path.realpath(path) == os.path.realpath(locked):
            return False
        return real_access(path, mode, *args, **kwargs)

    monkeypatch.setattr(os, "access", access)
    assert_rejected(workdir, ["plan", "task.yaml", "-o", "locked/x.csv"], ("locked/x.csv", "--output", "not writable"))


# --------------------------------------------------------------------------- torque and plan files
def _two_link_trajectory(T: float = 1.0, joints=("shoulder", "elbow"), K: int = 11) -> Trajectory:
    t = np.linspace(0.0, T, K)
    q = np.stack([0.1 * t, -0.2 * t], axis=1)
    return Trajectory(joints=tuple(joints), t=t, q=q, dq=q, ddq=q, u=np.ones_like(q))


def _csv_text(traj: Trajectory) -> str:
    buf = io.StringIO()
    write_csv(buf, traj)
    return buf.getvalue()


def _hoc_mcap(traj: Trajectory) -> bytes:
    from hoc_cli.io.mcap import write_mcap

    buf = io.BytesIO()
    write_mcap(buf, traj, urdf_text=(ROBOTS / "two_link.urdf").read_text(), task_text=SIM_TASK)
    return buf.getvalue()


def _foreign_mcap() -> bytes:
    """A valid MCAP file that hoc did not write (no 'hoc' metadata, no attachments)."""
    from mcap.writer import Writer

    buf = io.BytesIO()
    w = Writer(buf)
    w.start()
    schema = w.register_schema("x", "jsonschema", b"{}")
    channel = w.register_channel("/x", "json", schema)
    w.add_message(channel, 0, b"{}", 0)
    w.finish()
    return buf.getvalue()


GOOD_CSV = _csv_text(_two_link_trajectory())
GOOD_LINES = GOOD_CSV.splitlines(keepends=True)


def _torque(name: str, content: str | bytes | Callable[[], str | bytes] | None) -> Callable[[Path], list[str]]:
    def setup(d: Path) -> list[str]:
        data = content() if callable(content) else content
        if isinstance(data, str):
            (d / name).write_text(data)
        elif data is not None:
            (d / name).write_bytes(data)
        return ["simulate", "sim.yaml", "--torque", name, "-o", "out.csv", "-o", "out.mcap"]
    return setup


TORQUE_CASES = [
    ("torque CSV missing", _torque("gone.csv", None), ("gone.csv", "file not found")),
    ("torque CSV of binary garbage", _torque("t.csv", b"\x00\xff\xfe\x89garbage"), ("t.csv", "not a text file")),
    ("torque CSV of prose", _torque("t.csv", "hello, world\n"), ("t.csv", "header starts with 'hello'")),
    ("torque CSV empty", _torque("t.csv", ""), ("t.csv", "empty file")),
    ("torque CSV with a header only", _torque("t.csv", GOOD_LINES[0]), ("t.csv", "no data rows")),
    ("torque CSV row with a missing column", _torque("t.csv", "".join(GOOD_LINES[:3]) + "0.5,1,2\n"),
     ("t.csv", "line 4 has 3 values, expected 9")),
    ("torque CSV with a NaN", _torque("t.csv", "".join(GOOD_LINES[:2]) + GOOD_LINES[2].replace("1.0\n", "nan\n")),
     ("t.csv", "line 3, column u.elbow", "not a finite number")),
    ("torque CSV with a word for a number", _torque("t.csv", "".join(GOOD_LINES[:2]) + "x" + GOOD_LINES[2][3:]),
     ("t.csv", "line 3", "is not a number")),
    ("torque CSV with time going back", _torque("t.csv", GOOD_LINES[0] + GOOD_LINES[2] + GOOD_LINES[1]),
     ("t.csv", "t must increase strictly")),
    ("torque CSV with a single sample", _torque("t.csv", "".join(GOOD_LINES[:2])), ("t.csv", "at least 2 samples")),
    ("torque CSV for other joints", _torque("t.csv", lambda: _csv_text(_two_link_trajectory(joints=("shoulder", "wrist")))),
     ("t.csv", "torque columns name joints shoulder, wrist", "the task's joints are shoulder, elbow")),
    ("torque CSV shorter than T", _torque("t.csv", lambda: _csv_text(_two_link_trajectory(T=0.5))),
     ("t.csv", "cover t = 0 … 0.5 s", "needs 0 … 1 s")),
    ("torque file with an unknown extension", _torque("t.txt", GOOD_CSV),
     ("t.txt", "--torque", "unknown torque file extension '.txt'")),
    ("torque MCAP of garbage", _torque("t.mcap", b"not an mcap at all"), ("t.mcap", "not an MCAP file")),
    ("torque MCAP that hoc did not write", _torque("t.mcap", _foreign_mcap), ("t.mcap", "not a hoc plan")),
    ("torque MCAP truncated", _torque("t.mcap", lambda: _hoc_mcap(_two_link_trajectory())[:700]), ("t.mcap", "MCAP")),
    ("torque MCAP for other joints", _torque("t.mcap", lambda: _hoc_mcap(_two_link_trajectory(joints=("a", "b")))),
     ("t.mcap", "torque columns name joints a, b")),
    ("torque MCAP shorter than T", _torque("t.mcap", lambda: _hoc_mcap(_two_link_trajectory(T=0.25))),
     ("t.mcap", "cover t = 0 … 0.25 s")),
]


@pytest.mark.parametrize("setup,needles", [c[1:] for c in TORQUE_CASES], ids=[c[0] for c in TORQUE_CASES])
def test_a_bad_torque_file_makes_simulate_exit_2_naming_the_file(workdir, setup, needles):
    assert_rejected(workdir, setup(workdir), needles)


def test_a_garbage_mcap_source_or_warm_start_exits_2_naming_the_file(workdir):
    (workdir / "junk.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 40)
    assert_rejected(workdir, ["simulate", "junk.mcap", "-o", "out.csv"], ("junk.mcap", "MCAP"))
    assert_rejected(workdir, plan_args("task.yaml", "--init", "junk.mcap"), ("junk.mcap", "MCAP"))
    assert_rejected(workdir, plan_args("task.yaml", "--init", "absent.mcap"), ("absent.mcap", "file not found"))


def test_debug_shows_a_traceback_and_its_absence_shows_one_line(workdir):
    """Through a real process: what a user sees on the terminal, with and without --debug."""
    hoc = [sys.executable, "-c", "from hoc_cli.cli import app; app()"]
    write_task(workdir, _with("N: 4", "N: 0"))
    plain = subprocess.run(hoc + plan_args(), capture_output=True, text=True, timeout=60)
    debug = subprocess.run(hoc + plan_args("task.yaml", "--debug"), capture_output=True, text=True, timeout=60)
    assert plain.returncode == 2 and plain.stderr == "hoc: error: task.yaml: N: expected an integer >= 1 and <= 100000, got 0\n"
    assert debug.returncode != 0 and "Traceback" in debug.stderr and "TaskError" in debug.stderr
    assert snapshot(workdir)["out.csv"] == KEEP["out.csv"]


# --------------------------------------------------------------------------- numerical failures: exit 1
def _overflowing_dynamics(monkeypatch, after: int = 0) -> None:
    """Torques scaled to 1e200 (their squares overflow) from the ``after``-th dynamics evaluation on."""
    from hoc_cli.system import RobotSystem

    calls = {"n": 0}

    def scaled(real):
        def run(self, q, dq, ddq):
            calls["n"] += 1
            out = real(self, q, dq, ddq)
            if calls["n"] <= after:
                return out
            return 1e200 * out if isinstance(out, np.ndarray) else tuple(1e200 * np.asarray(x) for x in out)
        return run

    for name in ("inverse_dynamics", "covariant_gradient_terms", "id_derivatives"):
        monkeypatch.setattr(RobotSystem, name, scaled(getattr(RobotSystem, name)))


def test_a_cost_that_overflows_during_the_solve_exits_1_with_one_line_and_writes_nothing(workdir, monkeypatch):
    """Task values that overflow the cost are refused as input (gravity beyond any physical size: exit 2,
    tests/test_reliability_inputs.py); an overflow during the solve (torques scaled to 1e200 after the
    start's evaluation here) exits 1."""
    _overflowing_dynamics(monkeypatch, after=1)
    before = snapshot(workdir)
    r = invoke(plan_args("task.yaml", "--limits", "report"))  # enforced, the scaled torques prove it infeasible
    assert r.exit_code == 1
    assert r.stderr == "hoc: error: the cost is not finite (NaN or inf) along the trajectory\n"  # no RuntimeWarning
    assert snapshot(workdir) == before


def test_a_cost_not_finite_where_the_solve_starts_exits_2(workdir, monkeypatch):
    _overflowing_dynamics(monkeypatch)
    before = snapshot(workdir)
    r = invoke(plan_args("task.yaml", "--limits", "report"))
    assert r.exit_code == 2
    assert r.stderr.startswith("hoc: error: task.yaml: the covariant cost is not finite at the start of the solve")
    assert r.stderr.count("\n") == 1 and snapshot(workdir) == before


def test_a_singular_mass_matrix_along_the_path_exits_1_with_one_line(workdir, monkeypatch):
    """No valid URDF has M(q) singular at the planner's samples (load_robot rejects a massless subtree),
    so the mass matrix the dynamics returns is zeroed here."""
    from hoc_cli.system import RobotSystem

    real = RobotSystem.id_derivatives

    def singular(self, q, dq, ddq):
        u, Jq, Jv, M = real(self, q, dq, ddq)
        return u, Jq, Jv, np.zeros_like(M)

    monkeypatch.setattr(RobotSystem, "id_derivatives", singular)
    monkeypatch.setattr(RobotSystem, "mass_matrix", lambda self, q: np.zeros((len(q), self.n, self.n)))

    def not_positive_definite(self, q, dq, ddq):
        raise np.linalg.LinAlgError("Matrix is not positive definite")

    monkeypatch.setattr(RobotSystem, "covariant_gradient_terms", not_positive_definite)
    before = snapshot(workdir)
    r = invoke(plan_args())
    assert r.exit_code == 1
    assert r.stderr == "hoc: error: the mass matrix is singular or not positive definite along the trajectory\n"
    assert snapshot(workdir) == before


def test_a_path_through_a_singular_configuration_stops_with_exit_1_and_one_line(workdir):
    """Link 2 is a point mass that sits on joint 1's axis when q2 = π: M(q) is singular all along a
    path that keeps q2 = π (its Cholesky factorisation succeeds only through rounding, with a pivot
    of ~1e-17 of M's scale). The run says the mass matrix is singular, exits 1 and writes nothing."""
    (workdir / "point.urdf").write_text(_robot(
        '<link name="base"/><link name="l1"/>',
        '<link name="l2"><inertial><origin xyz="0.5 0 0"/><mass value="1"/>'
        '<inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial></link>',
        '<joint name="a" type="continuous"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/></joint>',
        '<joint name="b" type="continuous"><parent link="l1"/><child link="l2"/><origin xyz="0.5 0 0"/>'
        '<axis xyz="0 0 1"/></joint>'))
    write_task(workdir, "robot: point.urdf\nx0: {q: [0.0, 3.141592653589793]}\nx1: {q: [1.0, 3.141592653589793]}\n"
                        "T: 1.0\nN: 4\n")
    before = snapshot(workdir)
    r = invoke(plan_args("task.yaml", "--json"))
    assert r.exit_code == 1
    assert r.stderr == "hoc: error: the mass matrix is singular or not positive definite along the trajectory\n"
    assert snapshot(workdir) == before


# --------------------------------------------------------------------------- all outputs or none
def test_an_interrupt_while_writing_the_second_output_leaves_the_first_unchanged_too(workdir, monkeypatch):
    import hoc_cli.io.mcap as mcap_io

    def interrupted(fh, *args, **kwargs):
        fh.write(b"half an MCAP")
        raise KeyboardInterrupt

    monkeypatch.setattr(mcap_io, "write_mcap", interrupted)
    before = snapshot(workdir)
    r = invoke(plan_args())  # writes out.csv first, then out.mcap
    assert r.exit_code == 130
    assert r.stderr == "hoc: error: interrupted; no output was changed\n"
    assert snapshot(workdir) == before  # out.csv too: outputs are renamed into place together, at the end
    write_task(workdir, SIM_TASK + "torque: zero\n", "sim.yaml")
    before = snapshot(workdir)
    r = invoke(["simulate", "sim.yaml", "-o", "out.csv", "-o", "out.mcap"])
    assert r.exit_code == 130 and snapshot(workdir) == before


# --------------------------------------------------------------------------- reproducibility
def test_simulate_gives_byte_identical_csv_and_mcap_for_the_same_inputs(workdir):
    write_task(workdir, SIM_TASK + "torque: [0.5, -0.25]\n", "sim.yaml")
    for run in ("a", "b"):
        r = invoke(["simulate", "sim.yaml", "-o", f"{run}.csv", "-o", f"{run}.mcap", "-q"])
        assert r.exit_code == 0, r.stderr
    assert (workdir / "a.csv").read_bytes() == (workdir / "b.csv").read_bytes()
    assert (workdir / "a.mcap").read_bytes() == (workdir / "b.mcap").read_bytes()


def test_replaying_a_plan_gives_byte_identical_outputs_with_either_integrator(workdir):
    assert invoke(["plan", "task.yaml", "-o", "plan.mcap", "-q"]).exit_code == 0
    for method in ("hermite", "rk"):
        for run in ("a", "b"):
            args = ["simulate", "plan.mcap", "--integrator", method, "-o", f"{method}-{run}.csv", "-o", f"{method}-{run}.mcap", "-q"]
            assert invoke(args).exit_code == 0
        for ext in ("csv", "mcap"):
            assert (workdir / f"{method}-a.{ext}").read_bytes() == (workdir / f"{method}-b.{ext}").read_bytes()
