"""Issue 12 (reliability, second pass): one regression test per reproduced failure.

No output ever replaces an input; hostile URDF values are refused with the URDF, the joint or link
and the attribute named; summaries are valid JSON and checked before anything is written; CSV
columns and MCAP time stamps are checked before the solve; output-file failures are named (exit 2
for a usage problem, 1 for an I/O failure) and leave nothing behind; ``-q`` silences warnings,
which otherwise reach standard error terminal or not; messages blame the task key, the joint that
closes a cycle, and a plan's attachment rather than a scratch file.

Everything runs through the real CLI (typer's CliRunner, not a terminal) on the two-link arm.
The signal tests (SIGHUP, SIGTERM while outputs are being written) are in tests/test_signals.py.
"""
from __future__ import annotations

import errno
import io
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from hoc_cli.cli import app

ROOT = Path(__file__).resolve().parent.parent
URDF = (ROOT / "robots" / "two_link.urdf").read_text()
TASK = """\
robot: arm.urdf
x0: {q: [0.0, 0.0]}
x1: {q: [1.2, -0.6]}
T: 1.5
N: 4
"""
ELBOW_LIMIT = '<limit lower="-3.14159" upper="3.14159" effort="50" velocity="10"/>'
SHOULDER_LIMIT = '<limit lower="-3.14159" upper="3.14159" effort="100" velocity="10"/>'


def snapshot(d: Path) -> dict[str, bytes | None]:
    return {str(p.relative_to(d)): (None if p.is_dir() else p.read_bytes()) for p in sorted(d.rglob("*"))
            if not p.is_symlink() or p.exists()}


def invoke(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


@pytest.fixture
def d(tmp_path, monkeypatch) -> Path:
    (tmp_path / "arm.urdf").write_text(URDF)
    (tmp_path / "t.yaml").write_text(TASK)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def urdf_with(d: Path, old: str, new: str, name: str = "arm.urdf") -> Path:
    assert old in URDF
    (d / name).write_text(URDF.replace(old, new, 1))
    return d / name


def refused(d: Path, *args, needles: tuple[str, ...], code: int = 2) -> str:
    """Exit ``code`` with one ``hoc: error:`` line holding every needle; no file created or changed."""
    before = snapshot(d)
    r = invoke(*args)
    assert r.exit_code == code, (r.exit_code, r.stderr, r.exception)
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("hoc: error: "), r.stderr
    assert "internal error" not in lines[0]
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    assert snapshot(d) == before, "a file was created or changed"
    return lines[0]


def no_temporary_files(d: Path) -> bool:
    return not [p for p in d.rglob(".*.tmp")]


# --------------------------------------------------------------------------- 1. simulate's own names
def test_item1_simulate_with_the_plans_csv_as_torque_never_overwrites_the_plan(d):
    assert invoke("plan", "t.yaml", "-q").exit_code == 0  # writes t.mcap and t.csv
    (d / "s.yaml").write_text(TASK)
    shutil.copy(d / "t.csv", d / "s.csv")
    shutil.copy(d / "t.mcap", d / "s.mcap")
    plan = {name: (d / name).read_bytes() for name in ("s.csv", "s.mcap")}
    r = invoke("simulate", "s.yaml", "--torque", "s.csv", "-N", "32", "-q")
    assert r.exit_code == 0, r.stderr
    assert {name: (d / name).read_bytes() for name in plan} == plan
    assert (d / "s-sim.csv").is_file() and (d / "s-sim.mcap").is_file()


def test_item1_simulate_help_says_where_the_default_outputs_go():
    text = " ".join(CliRunner().invoke(app, ["simulate", "--help"]).stdout.split())
    assert "<source stem>-sim.mcap and <source stem>-sim.csv" in text


# --------------------------------------------------------------------------- 2. an output is never an input
def test_item2_simulate_writing_over_its_own_mcap_source_is_refused(d):
    assert invoke("plan", "t.yaml", "-q", "-o", "p.mcap").exit_code == 0
    refused(d, "simulate", "p.mcap", "-o", "p.mcap", needles=("p.mcap: --output", "same file as the simulation source"))


def test_item2_a_symlink_to_the_task_as_output_is_refused(d):
    os.symlink("t.yaml", d / "l.csv")
    refused(d, "plan", "t.yaml", "-o", "l.csv", needles=("l.csv", "same file as the task 't.yaml'"))


def test_item2_a_hard_link_to_the_task_as_output_is_refused(d):
    os.link(d / "t.yaml", d / "h.csv")
    refused(d, "plan", "t.yaml", "-o", "h.csv", needles=("h.csv", "same file as the task"))


def test_item2_a_task_named_like_its_default_csv_is_not_overwritten(d):
    shutil.copy(d / "t.yaml", d / "task.csv")
    refused(d, "plan", "task.csv", needles=("task.csv: --output", "same file as the task 'task.csv'"))


def test_item2_an_output_that_is_the_urdf_is_refused(d):
    (d / "robot.mcap").write_text(URDF)
    (d / "t.yaml").write_text(TASK.replace("arm.urdf", "robot.mcap"))
    refused(d, "plan", "t.yaml", "-o", "robot.mcap", needles=("robot.mcap: --output", "same file as the URDF"))


def test_item2_outputs_that_are_the_warm_start_or_the_torque_file_are_refused(d):
    assert invoke("plan", "t.yaml", "-q").exit_code == 0
    refused(d, "plan", "t.yaml", "--init", "t.mcap", needles=("t.mcap: --output", "same file as --init 't.mcap'"))
    (d / "s.yaml").write_text(TASK)
    refused(d, "simulate", "s.yaml", "--torque", "t.csv", "-o", "t.csv",
            needles=("t.csv: --output", "same file as --torque 't.csv'"))


# --------------------------------------------------------------------------- 6. non-finite URDF values
@pytest.mark.parametrize("old,new,needles", [
    ('lower="-3.14159" upper="3.14159" effort="100"', 'lower="nan" upper="3.14159" effort="100"',
     ("joint 'shoulder'", "<limit lower> is nan")),
    ('lower="-3.14159" upper="3.14159" effort="50"', 'lower="-3.14159" upper="inf" effort="50"',
     ("joint 'elbow'", "<limit upper> is inf")),
    ('effort="50" velocity="10"', 'effort="-inf" velocity="10"', ("joint 'elbow'", "<limit effort> is -inf")),
    ('<mass value="1.0"/>', '<mass value="1e308"/>', ("link 'upper_arm'", "<mass value>", "beyond")),
    ('ixx="0.00045"', 'ixx="1e400"', ("link 'upper_arm'", "<inertia> is not finite")),
    (ELBOW_LIMIT, ELBOW_LIMIT + '<mimic joint="shoulder" multiplier="inf"/>', ("joint 'elbow'", "<mimic multiplier> is inf")),
    (ELBOW_LIMIT, ELBOW_LIMIT + '<mimic joint="elbow"/>', ("joint 'elbow'", "<mimic joint> names the joint itself")),
], ids=["nan lower", "inf upper", "-inf effort", "mass 1e308", "inertia overflows to inf", "mimic multiplier inf",
        "self mimic"])
def test_item6_non_finite_urdf_values_are_exit_2_for_plan_and_inspect_naming_urdf_joint_and_attribute(d, old, new, needles):
    urdf_with(d, old, new)
    task = TASK if "mimic" not in new else TASK.replace("[0.0, 0.0]", "[0.0]").replace("[1.2, -0.6]", "[1.2]")
    (d / "t.yaml").write_text(task)
    refused(d, "plan", "t.yaml", "-o", "out.csv", needles=("arm.urdf: ",) + needles)
    refused(d, "inspect", "arm.urdf", "--json", needles=("arm.urdf: ",) + needles)
    refused(d, "inspect", "arm.urdf", needles=("arm.urdf: ",) + needles)


def test_item6_every_mass_at_1e308_would_overflow_the_total_and_is_refused(d):
    (d / "arm.urdf").write_text(URDF.replace('<mass value="1.0"/>', '<mass value="1e308"/>'))
    refused(d, "inspect", "arm.urdf", "--json", needles=("arm.urdf: link 'upper_arm'", "<mass value>"))


def test_item6_a_locked_prismatic_joint_placed_beyond_overflow_is_refused_naming_the_joint(d):
    slider = URDF.replace('<joint name="elbow" type="revolute">', '<joint name="elbow" type="prismatic">')
    (d / "arm.urdf").write_text(slider)
    (d / "t.yaml").write_text("locked: {elbow: 1.0e+200}\n" + TASK.replace("[0.0, 0.0]", "[0.0]").replace(
        "[1.2, -0.6]", "[1.2]") + "joints: [shoulder]\n")
    # refused as a value of no physical size (|x| > 1e6) before the URDF's overflow check sees it
    refused(d, "plan", "t.yaml", "-o", "out.csv", needles=("t.yaml: locked.elbow", "physical size"))


# --------------------------------------------------------------------------- 7. infinite limits are null
def _strict_json(text: str):
    def refuse(constant):
        raise AssertionError(f"invalid JSON constant {constant}")
    return json.loads(text, parse_constant=refuse)


def test_item7_a_one_sided_limit_is_null_in_the_json_summary_and_in_the_mcap(d):
    urdf_with(d, 'lower="-3.14159" upper="3.14159" effort="100"', 'lower="0.5" effort="100"')
    r = invoke("plan", "t.yaml", "--json", "-o", "p.mcap", "--limits", "report")
    assert r.exit_code == 0, r.stderr
    summary = _strict_json(r.stdout)
    shoulder = [v for v in summary["limit_violations"] if v["joint"] == "shoulder" and v["kind"] == "position"]
    assert shoulder and shoulder[0]["limit"] == [0.5, None]
    from hoc_cli.io.mcap import read_plan

    stored = _strict_json(read_plan(d / "p.mcap").metadata["summary"])
    assert stored["limit_violations"] == summary["limit_violations"]


def test_item7_the_summary_is_validated_before_any_output_is_written(d, monkeypatch):
    from hoc_cli.commands import plan as plan_cmd

    real = plan_cmd.summarise
    monkeypatch.setattr(plan_cmd, "summarise", lambda *a, **k: real(*a, **k) | {"bad": object()})
    (d / "out.csv").write_bytes(b"KEEP\n")
    before = snapshot(d)
    r = invoke("plan", "t.yaml", "-o", "out.csv", "-o", "out.mcap")
    assert r.exit_code == 1 and "internal error" in r.stderr  # a bug, but caught before writing
    assert snapshot(d) == before and no_temporary_files(d)


# --------------------------------------------------------------------------- 8. joint names
@pytest.fixture
def no_solve(monkeypatch):
    """Fail the test if the optimiser is reached: the check must come before the solve."""
    from hoc_cli import planner

    def refuse(*args, **kwargs):
        raise AssertionError("the solve started before the check")
    monkeypatch.setattr(planner, "plan", refuse)  # hoc_cli.solve imports it from there when it plans


@pytest.mark.parametrize("name,why", [("sh,oulder", "contains ','"), ("", "it is empty"), (" shoulder", "white space")])
def test_item8_a_joint_name_that_cannot_be_a_csv_column_is_refused_before_the_solve(d, no_solve, name, why):
    urdf_with(d, '<joint name="shoulder"', f'<joint name="{name}"')
    refused(d, "plan", "t.yaml", "-o", "out.csv", needles=("out.csv: --output", f"joint name {name!r}", why))


def test_item8_such_a_joint_name_is_fine_with_mcap_output_only(d):
    urdf_with(d, '<joint name="shoulder"', '<joint name="sh,oulder"')
    assert invoke("plan", "t.yaml", "-q", "-o", "out.mcap").exit_code == 0


def test_item8_rich_markup_in_joint_names_and_paths_is_printed_literally(d):
    urdf_with(d, '<joint name="shoulder"', '<joint name="sh[/]oulder"')
    (d / "a[/b]").mkdir(parents=True)  # "a[" holding "b]"
    shutil.copy(d / "arm.urdf", d / "a[/b]" / "arm.urdf")
    shutil.copy(d / "t.yaml", d / "a[/b]" / "t.yaml")
    r = invoke("plan", "a[/b]/t.yaml", "--progress", "-o", "a[/b]/o.csv")
    assert r.exit_code == 0, r.stderr
    assert "sh[/]oulder" in r.stderr and "a[/b]/o.csv" in r.stderr
    r = invoke("inspect", "a[/b]/arm.urdf")
    assert r.exit_code == 0 and "sh[/]oulder" in r.stderr and "a[/b]/arm.urdf" in r.stderr


# --------------------------------------------------------------------------- 9. the output rate
def test_item9_samples_closer_than_a_nanosecond_are_refused_before_the_solve_for_mcap(d, no_solve):
    (d / "t.yaml").write_text(TASK.replace("T: 1.5", "T: 1.0e-4") + "output: {rate: 5.0e9}\n")
    refused(d, "plan", "t.yaml", "-o", "out.mcap", needles=("t.yaml: output.rate", "5e+09 Hz", "nanosecond"))
    (d / "t.yaml").write_text(TASK.replace("T: 1.5", "T: 1.0000000001"))
    refused(d, "plan", "t.yaml", "-o", "out.mcap", needles=("t.yaml: output.rate", "within 1 ns"))


def test_item9_the_total_number_of_samples_is_bounded_up_front(d, no_solve):
    (d / "t.yaml").write_text(TASK + "output: {rate: 5.0e9}\n")
    refused(d, "plan", "t.yaml", "-o", "out.mcap", needles=("t.yaml: output.rate", "more than 1000000 output samples"))


# --------------------------------------------------------------------------- 10. output-file failures
def test_item10_a_250_character_output_name_works_though_its_temporary_name_would_not_fit(d):
    name = "a" * 246 + ".csv"
    r = invoke("plan", "t.yaml", "-q", "-o", name)
    assert r.exit_code == 0, r.stderr
    assert (d / name).is_file() and no_temporary_files(d)


def test_item10_an_output_name_longer_than_the_file_system_allows_is_exit_2(d):
    refused(d, "plan", "t.yaml", "-o", "a" * 300 + ".csv", needles=("--output", "file name is 304 bytes"))


def test_item10_a_dangling_symlink_into_a_missing_directory_or_a_link_loop_is_exit_2(d):
    os.symlink("nowhere/x.csv", d / "dangling.csv")
    refused(d, "plan", "t.yaml", "-o", "dangling.csv", needles=("dangling.csv: --output", "'nowhere/x.csv'",
                                                                   "directory does not exist"))
    os.symlink("loop2.csv", d / "loop1.csv")
    os.symlink("loop1.csv", d / "loop2.csv")
    refused(d, "plan", "t.yaml", "-o", "loop1.csv", needles=("loop1.csv: --output", "symbolic link loop"))


def test_item10_a_dangling_symlink_to_a_new_file_is_written_through(d):
    os.symlink("target.csv", d / "link.csv")
    assert invoke("plan", "t.yaml", "-q", "-o", "link.csv").exit_code == 0
    assert (d / "link.csv").is_symlink() and (d / "target.csv").read_text().startswith("t,q.shoulder")


@pytest.mark.parametrize("command", ["simulate", "plan"])
def test_item10_a_full_disk_is_exit_1_naming_the_file_and_leaves_everything_as_it_was(d, monkeypatch, command):
    (d / "t.yaml").write_text(TASK + "torque: zero\n")
    (d / "out.csv").write_bytes(b"KEEP: an earlier CSV\n")
    (d / "out.mcap").write_bytes(b"KEEP: an earlier MCAP\n")
    real_fsync, calls = os.fsync, []

    def full(fd):
        calls.append(fd)
        if len(calls) == 2:  # the first output is complete, the second hits a full disk
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real_fsync(fd)
    monkeypatch.setattr(os, "fsync", full)
    refused(d, command, "t.yaml", "-N", "32", "-o", "out.csv", "-o", "out.mcap", code=1,
                needles=("out.mcap: --output", "No space left on device", "the disk is full"))
    assert len(calls) == 2 and no_temporary_files(d)


def test_item10_a_full_disk_while_creating_the_temporary_file_is_exit_1(d, monkeypatch):
    import tempfile

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(tempfile, "mkstemp", full)
    refused(d, "plan", "t.yaml", "-o", "out.csv", code=1, needles=("out.csv: --output", "No space left"))


# --------------------------------------------------------------------------- 13. -q and warnings
def test_item13_quiet_silences_the_mimic_warning(d):
    urdf_with(d, ELBOW_LIMIT, ELBOW_LIMIT + '<mimic joint="shoulder"/>')
    (d / "t.yaml").write_text(TASK.replace("[0.0, 0.0]", "[0.0]").replace("[1.2, -0.6]", "[1.2]"))
    loud = invoke("plan", "t.yaml", "-o", "out.csv")
    assert loud.exit_code == 0 and "hoc: warning: " in loud.stderr and "mimics task joint" in loud.stderr
    quiet = invoke("plan", "t.yaml", "-o", "out.csv", "-q")
    assert quiet.exit_code == 0 and quiet.stderr == ""


def test_item13_limit_violations_and_not_converged_reach_stderr_when_it_is_not_a_terminal(d):
    urdf_with(d, 'effort="50"', 'effort="0.5"')  # below the elbow's gravity torque: enforced, infeasible at once
    r = invoke("plan", "t.yaml", "-o", "out.csv", "--max-iter", "1", "--limits", "report")
    assert r.exit_code == 1
    assert "hoc: warning: joint 'elbow' exceeds its effort limit 0.5: worst " in r.stderr
    assert "hoc: not converged" in r.stderr
    assert invoke("plan", "t.yaml", "-o", "out.csv", "--max-iter", "1", "--limits", "report", "-q").stderr == ""
    (d / "s.yaml").write_text(TASK + "torque: [0.0, 2.0]\n")
    r = invoke("simulate", "s.yaml", "-N", "32", "-o", "sim.csv")
    assert r.exit_code == 0 and "hoc: warning: joint 'elbow' exceeds its effort limit" in r.stderr
    assert invoke("simulate", "s.yaml", "-N", "32", "-o", "sim.csv", "-q").stderr == ""


# --------------------------------------------------------------------------- 14. blame the right thing
def test_item14_an_unknown_locked_joint_is_blamed_on_the_task_key(d):
    (d / "t.yaml").write_text("locked: {nope: 1}\n" + TASK)
    line = refused(d, "plan", "t.yaml", "-o", "out.csv", needles=("hoc: error: t.yaml: locked.nope: ", "arm.urdf"))
    assert not line.startswith("hoc: error: arm.urdf")
    (d / "t.yaml").write_text("joints: [shoulder, nope]\n" + TASK.replace("[1.2, -0.6]", "[1.2, 0.1]"))
    refused(d, "plan", "t.yaml", "-o", "out.csv", needles=("hoc: error: t.yaml: joints[1]: joint 'nope'",))


def test_item14_a_cycle_is_blamed_on_the_joint_that_closes_it(d):
    urdf_with(d, "</robot>", '<joint name="loop" type="fixed"><parent link="tool"/><child link="base"/></joint></robot>')
    refused(d, "plan", "t.yaml", "-o", "out.csv", needles=("arm.urdf: joint 'loop'", "form a cycle"))
    # a separate loop beside a proper root: also the joint that closes it
    urdf_with(d, "</robot>", '<link name="x"/><link name="y"/><joint name="xy" type="fixed"><parent link="x"/>'
              '<child link="y"/></joint><joint name="yx" type="fixed"><parent link="y"/><child link="x"/></joint></robot>')
    refused(d, "inspect", "arm.urdf", needles=("arm.urdf: joint 'yx'", "['xy', 'yx'] form a cycle"))


@pytest.mark.parametrize("bad,needles", [
    ("<robot name='r'><link", ("malformed XML",)),
    (URDF.replace('lower="-3.14159" upper="3.14159" effort="50"', 'lower="nan" upper="3.14159" effort="50"'),
     ("joint 'elbow'", "<limit lower> is nan")),
], ids=["malformed XML", "nan limit"])
def test_item14_a_bad_urdf_attachment_is_named_as_the_plans_attachment(d, bad, needles):
    from hoc_cli.io.mcap import write_mcap
    from hoc_cli.trajectory import Trajectory

    t = np.linspace(0.0, 1.5, 4)
    zeros = np.zeros((4, 2))
    traj = Trajectory(joints=("shoulder", "elbow"), t=t, q=zeros, dq=zeros, ddq=zeros, u=zeros)
    buf = io.BytesIO()
    write_mcap(buf, traj, urdf_text=bad, task_text=TASK)
    (d / "PLAN.mcap").write_bytes(buf.getvalue())
    line = refused(d, "simulate", "PLAN.mcap", needles=("hoc: error: PLAN.mcap: attachment robot.urdf: ",) + needles)
    assert "hoc-simulate-" not in line  # not the scratch copy
