"""Issue 12: whatever task and URDF hoc is given, the CLI answers 0, 1 or 2, quickly, and never
changes an input.

Hypothesis mutates the two-link arm's URDF (hostile numbers such as nan, inf, 1e308, 1e400 in
masses, inertias, origins, axes and limits; odd joint names; other joint types; a mimic; a cycle)
and its task (durations, element counts, rates, states, locked joints, joint lists, torques), then
runs ``hoc plan``, ``hoc simulate`` or ``hoc inspect`` through the real CLI with outputs that
include the inputs themselves (directly and through a symbolic link). Each run must exit 0, 1 or
2 without "internal error" or a traceback, finish within 10 s, leave the task and the URDF
byte-for-byte as they were, and leave no temporary file. Kept small (few examples, N <= 4,
--max-iter 3) so that it runs in seconds; HOC_FUZZ_EXAMPLES raises the count.
"""
from __future__ import annotations

import os
import signal
import tempfile
import time
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from hoc_cli.cli import app

ROOT = Path(__file__).resolve().parent.parent
URDF = (ROOT / "robots" / "two_link.urdf").read_text()
TIME_LIMIT_S = 10

NUMBERS = ["nan", "inf", "-inf", "1e308", "-1e308", "1e400", "0", "-1", "1e-320", "", "x", "3.0"]
TRIPLES = ["nan 0 0", "1e308 0 0", "1e400 0 0", "0 0 0", "1 0", "0 0 1", "1e-300 0 0"]
JOINT_NAMES = ["sh,oulder", "", " x", "sh[/]oulder", "[bold]", 'a"b', "ü", "elbow", "tool_joint"]
JOINT_TYPES = ["fixed", "continuous", "prismatic", "floating", "bogus"]
#: (text in the two-link URDF, template for its replacement, values)
URDF_SLOTS = [
    ('<mass value="1.0"/>', '<mass value="{}"/>', NUMBERS),
    ('ixx="0.00045"', 'ixx="{}"', NUMBERS),
    ('<origin xyz="1 0 0" rpy="0 0 0"/>', '<origin xyz="{}" rpy="0 0 0"/>', TRIPLES),
    ('<axis xyz="0 -1 0"/>', '<axis xyz="{}"/>', TRIPLES),
    ('lower="-3.14159"', 'lower="{}"', NUMBERS),
    ('upper="3.14159"', 'upper="{}"', NUMBERS),
    ('effort="100"', 'effort="{}"', NUMBERS),
    ('velocity="10"', 'velocity="{}"', NUMBERS),
    ('<joint name="shoulder"', '<joint name="{}"', JOINT_NAMES),
    ('<joint name="elbow" type="revolute">', '<joint name="elbow" type="{}">', JOINT_TYPES),
    ('effort="50" velocity="10"/>', 'effort="50" velocity="10"/><mimic joint="shoulder" multiplier="{}"/>', NUMBERS),
    ('</robot>', '<joint name="loop" type="fixed"><parent link="{}"/><child link="base"/></joint></robot>',
     ["tool", "base", "upper_arm"]),
]
TASK_SLOTS = {
    "T": ["1.5", "0", "-1", ".nan", ".inf", "1.0e-9", "1.0000000001", "1.0e+6", "'x'", "[]"],
    "N": ["4", "1", "0", "2", "1.5", "100001", "'a'"],
    "output": ["{rate: 100}", "{rate: 5.0e9}", "{rate: 1.0e-3}", "{rate: 0}", "{rate: 1.0e+6}", "{rate: .inf}"],
    "x0": ["{q: [0.0, 0.0]}", "{q: [1.0e+308, 0]}", "{q: [.nan, 0]}", "{q: [0]}", "{q: {shoulder: 0, elbow: 0}}",
           "{q: {nope: 1}}", "{q: []}", "{q: [0, 0], dq: [1.0e+300, 0]}"],
    "x1": ["{q: [1.2, -0.6]}", "{q: [1.0e+300, 0]}", "{q: [0]}", "{q: {elbow: 0, shoulder: 1}}"],
    "locked": [None, "{nope: 1}", "{elbow: 1.0e+300}", "{tool_joint: 0}", "{elbow: 0.5}"],
    "joints": [None, "[shoulder]", "[nope]", "[shoulder, shoulder]", "[tool_joint]", "[elbow, shoulder]"],
    "gravity": [None, "[0, 0, 1.0e+308]", "[0, 0]", "[0, 0, -9.81]"],
    "torque": [None, "zero", "[0, 0]", "[1.0e+308, 1.0e+308]", "[1, 2, 3]", "bogus"],
}
OUTPUTS = ["out.csv", "out.mcap", "t.csv", "torque.csv", "t.yaml", "arm.urdf", "link.csv", "hard.mcap", "-", "x.txt"]


class Hang(BaseException):
    """Raised by SIGALRM: a run took longer than TIME_LIMIT_S (not an Exception: nothing catches it)."""


def _alarm(signum, frame):
    raise Hang()


@st.composite
def urdf_texts(draw) -> str:
    text = URDF
    for old, template, values in draw(st.lists(st.sampled_from(URDF_SLOTS), max_size=3, unique_by=lambda s: s[0])):
        text = text.replace(old, template.format(draw(st.sampled_from(values))), 1)
    return text


@st.composite
def task_texts(draw) -> str:
    chosen = {key: values[0] for key, values in TASK_SLOTS.items()}
    for key in draw(st.lists(st.sampled_from(sorted(TASK_SLOTS)), max_size=3, unique=True)):
        chosen[key] = draw(st.sampled_from(TASK_SLOTS[key]))
    return "robot: arm.urdf\n" + "".join(f"{k}: {v}\n" for k, v in chosen.items() if v is not None)


@st.composite
def commands(draw) -> list[str]:
    kind = draw(st.sampled_from(["plan", "simulate", "inspect"]))
    if kind == "inspect":
        return ["inspect", "arm.urdf"] + draw(st.sampled_from([[], ["--json"]]))
    args = [kind, "t.yaml"]
    for out in draw(st.lists(st.sampled_from(OUTPUTS), max_size=2, unique=True)):
        args += ["-o", out]
    args += draw(st.sampled_from([[], ["--json"], ["-q"]]))
    if kind == "plan":
        args += ["--max-iter", "3"]
    else:
        args += draw(st.sampled_from([[], ["--integrator", "rk"], ["--torque", "torque.csv"]]))
    return args


@settings(max_examples=int(os.environ.get("HOC_FUZZ_EXAMPLES", "40")), deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(urdf=urdf_texts(), task=task_texts(), args=commands())
def test_no_task_or_urdf_gives_an_internal_error_a_hang_or_a_changed_input(urdf, task, args):
    here = os.getcwd()
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        (d / "arm.urdf").write_text(urdf)
        (d / "t.yaml").write_text(task)
        (d / "torque.csv").write_text("t,q.shoulder,q.elbow,dq.shoulder,dq.elbow,ddq.shoulder,ddq.elbow,u.shoulder,u.elbow\n"
                                 "0,0,0,0,0,0,0,0,0\n2,0,0,0,0,0,0,0,0\n")
        os.symlink("t.yaml", d / "link.csv")
        os.link(d / "arm.urdf", d / "hard.mcap")
        names = ("arm.urdf", "t.yaml") + (("torque.csv",) if "--torque" in args else ())
        inputs = {name: (d / name).read_bytes() for name in names}
        previous = signal.signal(signal.SIGALRM, _alarm)
        os.chdir(d)
        start = time.monotonic()
        signal.alarm(TIME_LIMIT_S)
        try:
            r = CliRunner().invoke(app, args)
        except Hang:
            pytest.fail(f"hoc {' '.join(args)} ran over {TIME_LIMIT_S} s\n--- task\n{task}--- urdf\n{urdf}")
        finally:
            signal.alarm(0)
            signal.signal(signal.SIGALRM, previous)
            os.chdir(here)
        elapsed = time.monotonic() - start
        context = f"hoc {' '.join(args)} -> {r.exit_code}\n{r.stderr}\n--- task\n{task}"
        assert not isinstance(r.exception, Hang), context
        assert r.exit_code in (0, 1, 2), context
        assert "internal error" not in r.stderr and "Traceback" not in r.output, context
        assert elapsed < TIME_LIMIT_S, context
        assert {name: (d / name).read_bytes() for name in inputs} == inputs, "an input was changed: " + context
        assert not list(d.glob(".*.tmp")), "a temporary file was left: " + context
