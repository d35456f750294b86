"""The ``limits:`` task section: defaults, overrides by joint, scale factors, and every way it can be wrong."""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from hoc_cli.cli import app
from hoc_cli.errors import TaskError
from hoc_cli.io.task import LimitScale, LimitsSpec, apply_overrides, load_task, resolve

ROOT = Path(__file__).resolve().parent.parent
TASK = """\
robot: arm.urdf
x0: {q: [0.0, 0.0]}
x1: {q: [1.2, -0.6]}
T: 1.5
N: 4
"""
JOINTS = ("shoulder", "elbow")  # robots/two_link.urdf


@pytest.fixture
def workdir(tmp_path, monkeypatch) -> Path:
    (tmp_path / "arm.urdf").write_text((ROOT / "robots" / "two_link.urdf").read_text())
    monkeypatch.chdir(tmp_path)
    return tmp_path


def load(d: Path, extra: str, base: str = TASK):
    (d / "task.yaml").write_text(base + extra)
    return load_task(d / "task.yaml")


def test_without_a_limits_key_the_urdf_limits_are_enforced_unscaled(workdir):
    spec = load(workdir, "").limits
    assert spec == LimitsSpec() and spec.mode == "enforce"
    assert spec.scale == LimitScale(1.0, 1.0, 1.0) and not spec.named()
    assert load(workdir, "limits:\n").limits == LimitsSpec()  # an empty section is the default too


def test_a_full_limits_section_is_read_into_read_only_mappings(workdir):
    spec = load(workdir, """\
limits:
  mode: report
  position: {shoulder: [-1.0, 1.5]}
  velocity: {elbow: 2.5, shoulder: 1}
  acceleration: {elbow: 10.0}
  effort: {shoulder: 50}
  scale: {velocity: 0.9, effort: 1}
""").limits
    assert spec.mode == "report"
    assert dict(spec.position) == {"shoulder": (-1.0, 1.5)}
    assert dict(spec.velocity) == {"elbow": 2.5, "shoulder": 1.0} and isinstance(spec.velocity["shoulder"], float)
    assert dict(spec.acceleration) == {"elbow": 10.0} and dict(spec.effort) == {"shoulder": 50.0}
    assert spec.scale == LimitScale(velocity=0.9, acceleration=1.0, effort=1.0)
    assert spec.named() == [("position", "shoulder"), ("velocity", "elbow"), ("velocity", "shoulder"),
                            ("acceleration", "elbow"), ("effort", "shoulder")]
    with pytest.raises(TypeError):
        spec.velocity["elbow"] = 1.0  # type: ignore[index]
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.mode = "enforce"  # type: ignore[misc]


def test_resolve_puts_the_overrides_in_the_models_joint_order_with_nan_where_none_is_given(workdir):
    task = load(workdir, "limits: {position: {elbow: [-2, 2]}, velocity: {elbow: 3.0}, effort: {shoulder: 7}}\n")
    lim = resolve(task, JOINTS).limits
    assert lim.mode == "enforce"
    np.testing.assert_array_equal(lim.lower, [math.nan, -2.0])
    np.testing.assert_array_equal(lim.upper, [math.nan, 2.0])
    np.testing.assert_array_equal(lim.velocity, [math.nan, 3.0])
    np.testing.assert_array_equal(lim.acceleration, [math.nan, math.nan])
    np.testing.assert_array_equal(lim.effort, [7.0, math.nan])
    lim = resolve(task, JOINTS[::-1]).limits  # another joint order
    np.testing.assert_array_equal(lim.velocity, [3.0, math.nan])


def test_a_joint_not_in_the_task_is_named_with_the_task_joints_at_resolve_time(workdir):
    task = load(workdir, "limits: {velocity: {wrist: 1.0}}\n")  # no joints: key, so the URDF decides
    with pytest.raises(TaskError, match=r"limits\.velocity\.wrist: joint 'wrist' is not a task joint "
                                        r"\(task joints: shoulder, elbow\)"):
        resolve(task, JOINTS)


def test_a_joint_not_in_the_task_is_named_at_load_time_when_joints_are_given(workdir):
    with pytest.raises(TaskError, match=r"limits\.effort\.elbow: joint 'elbow' is locked, not a task joint "
                                        r"\(task joints: shoulder\)"):
        load(workdir, "limits: {effort: {elbow: 1.0}}\n",
             base=TASK.replace("x0: {q: [0.0, 0.0]}", "joints: [shoulder]\nlocked: {elbow: 0.1}\nx0: {q: [0.0]}"))


# (description, limits: text, what the one-line error must contain)
INVALID = [
    ("mode unknown", "{mode: strict}", "limits.mode: expected one of enforce, report, got 'strict'"),
    ("mode not a string", "{mode: 1}", "limits.mode: expected one of enforce, report"),
    ("not a mapping", "[velocity]", "limits: expected a mapping with keys mode, position"),
    ("unknown key", "{speed: {elbow: 1}}", "limits.speed: unknown key 'speed'"),
    ("unknown joint", "{velocity: {wrist: 1.0}}", ("limits.velocity.wrist: joint 'wrist' is not a task joint "
                                                   "(task joints: shoulder, elbow)")),
    ("velocity zero", "{velocity: {elbow: 0}}", "limits.velocity.elbow: expected a finite velocity limit > 0"),
    ("velocity negative", "{velocity: {elbow: -1}}", "limits.velocity.elbow: expected a finite velocity limit > 0"),
    ("velocity infinite", "{velocity: {elbow: .inf}}", "limits.velocity.elbow: expected a finite velocity limit"),
    ("velocity NaN", "{velocity: {elbow: .nan}}", "limits.velocity.elbow: expected a finite velocity limit"),
    ("velocity a word", "{velocity: {elbow: fast}}", "limits.velocity.elbow: expected a finite velocity limit"),
    ("velocity a list", "{velocity: [1, 2]}", "limits.velocity: expected a mapping joint -> limit"),
    ("acceleration zero", "{acceleration: {elbow: 0.0}}", ("limits.acceleration.elbow: expected a finite "
                                                          "acceleration limit > 0")),
    ("effort negative", "{effort: {shoulder: -5}}", "limits.effort.shoulder: expected a finite effort limit > 0"),
    ("effort a boolean", "{effort: {shoulder: true}}", "limits.effort.shoulder: expected a finite effort limit"),
    ("position one number", "{position: {elbow: 1.0}}", "limits.position.elbow: expected a range [lower, upper]"),
    ("position three numbers", "{position: {elbow: [1, 2, 3]}}", "limits.position.elbow: expected a range"),
    ("position reversed", "{position: {elbow: [1.0, -1.0]}}", ("limits.position.elbow: expected a range [lower, "
                                                              "upper] of finite numbers with lower < upper")),
    ("position empty", "{position: {elbow: [1.0, 1.0]}}", "limits.position.elbow: expected a range"),
    ("position infinite", "{position: {elbow: [-.inf, 1.0]}}", "limits.position.elbow[0]: expected a finite number"),
    ("position NaN", "{position: {elbow: [0, .nan]}}", "limits.position.elbow[1]: expected a finite number"),
    ("position joint not a name", "{position: {1: [0, 1]}}", "limits.position: expected joint names"),
    ("scale zero", "{scale: {velocity: 0}}", "limits.scale.velocity: expected a scale factor 0 < s <= 1, got 0"),
    ("scale above one", "{scale: {effort: 1.5}}", "limits.scale.effort: expected a scale factor 0 < s <= 1"),
    ("scale negative", "{scale: {acceleration: -0.5}}", "limits.scale.acceleration: expected a scale factor"),
    ("scale NaN", "{scale: {velocity: .nan}}", "limits.scale.velocity: expected a scale factor"),
    ("scale unknown kind", "{scale: {position: 0.5}}", ("limits.scale.position: unknown key 'position' "
                                                       "(expected one of: velocity, acceleration, jerk, effort)")),
    ("scale a number", "{scale: 0.5}", "limits.scale: expected a mapping with keys velocity, acceleration, jerk, effort"),
]


@pytest.mark.parametrize("desc,limits,needle", INVALID, ids=[c[0] for c in INVALID])
def test_an_invalid_limits_section_exits_2_with_one_line_naming_the_key(workdir, desc, limits, needle):
    (workdir / "task.yaml").write_text(TASK + f"limits: {limits}\n")
    r = CliRunner().invoke(app, ["plan", "task.yaml", "-o", "out.csv"])
    assert r.exit_code == 2, (r.stderr, r.exception)
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and "task.yaml" in lines[0] and needle in lines[0], (needle, r.stderr)
    assert sorted(p.name for p in workdir.iterdir()) == ["arm.urdf", "task.yaml"]


def test_the_limits_override_replaces_the_mode_and_is_checked_like_the_key(workdir):
    task = load(workdir, "limits: {velocity: {elbow: 2.0}}\n")
    reported = apply_overrides(task, limits="report")
    assert reported.limits.mode == "report" and dict(reported.limits.velocity) == {"elbow": 2.0}
    assert apply_overrides(reported, limits="enforce").limits == task.limits
    assert apply_overrides(task, limits=None) == task
    with pytest.raises(TaskError, match=r"--limits: expected one of enforce, report, got 'off'"):
        apply_overrides(task, limits="off")
