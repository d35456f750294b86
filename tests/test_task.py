"""Task files: valid ones load with defaults; malformed ones give exit 2 and one clear line."""
import dataclasses
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from hoc_cli.cli import app
from hoc_cli.errors import TaskError
from hoc_cli.io.task import apply_overrides, load_task, resolve

LINK = """<link name="{n}"><inertial><origin xyz="0 0 0.2"/><mass value="1"/>
<inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>"""
ROBOT = f"""<robot name="r"><link name="base"/>{LINK.format(n="l1")}{LINK.format(n="l2")}
<joint name="a" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 1 0"/>
<limit lower="-3" upper="3" effort="10" velocity="5"/></joint>
<joint name="b" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.4"/><axis xyz="0 1 0"/>
<limit lower="-3" upper="3" effort="10" velocity="5"/></joint></robot>"""

GOOD = """\
robot: r.urdf
joints: [a, b]
x0: {q: [0.0, 0.1]}
x1: {q: {b: -0.6, a: 1.2}, dq: [0.0, 0.0]}
T: 1.5
N: 16
"""


@pytest.fixture
def taskdir(tmp_path):
    (tmp_path / "r.urdf").write_text(ROBOT)
    return tmp_path


def write(d: Path, text: str, name="task.yaml") -> Path:
    p = d / name
    p.write_text(text)
    return p


def test_a_minimal_task_loads_with_the_spec_defaults(taskdir):
    task = load_task(write(taskdir, GOOD))
    assert task.robot == taskdir / "r.urdf"
    assert (task.order, task.cost, task.method, task.tol, task.max_iter, task.rate) == (
        "quintic", "covariant", "pr-cg", 1e-10, 5000, 100.0)
    assert task.gravity == (0.0, 0.0, -9.81)
    s = resolve(task, task.joints)
    np.testing.assert_array_equal(s.q1, [1.2, -0.6])  # mapping resolved by joint name
    np.testing.assert_array_equal(s.dq0, [0.0, 0.0])  # dq defaults to zeros


def test_overrides_replace_task_keys_and_are_validated(taskdir):
    task = load_task(write(taskdir, GOOD))
    t2 = apply_overrides(task, N=4, order="cubic", T=2.0, tol=1e-6, max_iter=10)
    assert (t2.N, t2.order, t2.T, t2.tol, t2.max_iter) == (4, "cubic", 2.0, 1e-6, 10)
    with pytest.raises(TaskError, match="--elements"):
        apply_overrides(task, N=0)


def test_resolve_rejects_unknown_joint_names_and_wrong_lengths(taskdir):
    task = load_task(write(taskdir, GOOD.replace("{b: -0.6, a: 1.2}", "{b: -0.6, c: 1.2}")))
    with pytest.raises(TaskError, match=r"x1.q.c: unknown joint 'c'"):
        resolve(task, task.joints)
    with pytest.raises(TaskError, match=r"x0.q: expected 3 values"):
        resolve(load_task(write(taskdir, GOOD)), ("a", "b", "c"))


# (description, task text, substring the one-line error must contain)
MALFORMED = [
    ("empty file", "", "empty file"),
    ("YAML syntax error", "robot: [r.urdf\nT: 1", "invalid YAML at line"),
    ("top level is a list", "- 1\n- 2\n", "expected a mapping"),
    ("missing robot", GOOD.replace("robot: r.urdf\n", ""), "robot: missing required key"),
    ("missing x1", GOOD.replace("x1: {q: {b: -0.6, a: 1.2}, dq: [0.0, 0.0]}\n", ""), "x1: missing required key"),
    ("unknown top-level key", GOOD + "durration: 2\n", "unknown key 'durration'"),
    ("unknown solver key", GOOD + "solver: {tolerance: 1e-6}\n", "solver.tolerance: unknown key"),
    ("T is zero", GOOD.replace("T: 1.5", "T: 0"), "T: expected a duration T > 0"),
    ("T negative", GOOD.replace("T: 1.5", "T: -2"), "T: expected a duration T > 0"),
    ("T is a string", GOOD.replace("T: 1.5", "T: fast"), "T: expected a duration"),
    ("N is zero", GOOD.replace("N: 16", "N: 0"), "N: expected an integer >= 1"),
    ("N is fractional", GOOD.replace("N: 16", "N: 2.5"), "N: expected an integer >= 1"),
    ("NaN in x0", GOOD.replace("[0.0, 0.1]", "[0.0, .nan]"), "x0.q[1]: expected a finite number"),
    ("inf in x1.dq", GOOD.replace("dq: [0.0, 0.0]", "dq: [0.0, .inf]"), "x1.dq[1]: expected a finite number"),
    ("unknown order", GOOD + "order: septic\n", "order: expected one of quintic, cubic"),
    ("unknown cost", GOOD + "cost: energy\n", "cost: expected one of covariant, torque"),
    ("unknown method", GOOD + "solver: {method: bfgs}\n", "solver.method: expected one of"),
    ("wrong length", GOOD.replace("[0.0, 0.1]", "[0.0, 0.1, 0.2]"), "x0.q: expected 2 values"),
    ("unknown joint in mapping", GOOD.replace("{b: -0.6, a: 1.2}", "{b: -0.6, z: 1.2}"), "x1.q.z: unknown joint 'z'"),
    ("robot file missing", GOOD.replace("r.urdf", "nope.urdf"), "robot: URDF file not found"),
    ("gravity of length 2", GOOD + "gravity: [0, -9.81]\n", "gravity: expected a list of 3 numbers"),
    ("state without q", GOOD.replace("x0: {q: [0.0, 0.1]}", "x0: {dq: [0.0, 0.1]}"), "x0.q: missing required key"),
    ("output rate negative", GOOD + "output: {rate: -5}\n", "output.rate: expected a sample rate > 0"),
    ("duplicate joints", GOOD.replace("[a, b]", "[a, a]"), "joints: expected distinct joint names"),
    ("duplicate key", GOOD + "T: 2.0\n", "duplicate key 'T'"),
    ("N too large", GOOD.replace("N: 16", "N: 1000000000"), "N: expected an integer >= 1 and <= 100000"),
]


@pytest.mark.parametrize("desc,text,needle", MALFORMED, ids=[m[0] for m in MALFORMED])
def test_malformed_task_exits_2_with_one_line_naming_file_and_key(taskdir, desc, text, needle, monkeypatch):
    monkeypatch.chdir(taskdir)
    path = write(taskdir, text)
    result = CliRunner().invoke(app, ["plan", str(path)])
    assert result.exit_code == 2, result.output
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, result.stderr
    assert str(path) in lines[0] and needle in lines[0]
    assert "Traceback" not in result.output
    assert sorted(p.name for p in taskdir.iterdir()) == ["r.urdf", "task.yaml"]  # nothing created


def test_missing_task_file_exits_2_naming_the_file(tmp_path):
    result = CliRunner().invoke(app, ["plan", str(tmp_path / "absent.yaml")])
    assert result.exit_code == 2
    assert "absent.yaml: file not found" in result.stderr


def test_cli_override_with_invalid_value_exits_2(taskdir):
    result = CliRunner().invoke(app, ["plan", str(write(taskdir, GOOD)), "-N", "0"])
    assert result.exit_code == 2 and "--elements: expected an integer >= 1" in result.stderr


def test_exponent_floats_without_a_dot_are_numbers(taskdir):
    task = load_task(write(taskdir, GOOD + "solver: {tol: 1e-8, max_iter: 100}\n"))
    assert task.tol == 1e-8


def test_yaml_tags_that_construct_python_objects_are_rejected(taskdir):
    with pytest.raises(TaskError, match="invalid YAML"):
        load_task(write(taskdir, GOOD + "x: !!python/object/apply:os.system ['true']\n"))


# --------------------------------------------------------------------------- sections and overrides
def test_each_section_is_a_frozen_dataclass_and_the_flat_views_read_them(taskdir):
    from hoc_cli.io.task import BoundarySpec, OutputSpec, SolverSpec, State, TimeSpec

    task = load_task(write(taskdir, GOOD + "solver: {method: newton}\noutput: {rate: 50}\n"))
    assert task.time == TimeSpec(T=1.5, N=16, order="quintic")
    assert task.solver == SolverSpec(method="newton", tol=1e-10, max_iter=5000)
    assert task.output == OutputSpec(rate=50.0)
    assert task.boundary == BoundarySpec(x0=State(q=[0.0, 0.1], dq=None),
                                         x1=State(q={"b": -0.6, "a": 1.2}, dq=[0.0, 0.0]))
    assert task.robot_spec.joints == ("a", "b") and task.robot_spec.robot == task.robot
    assert (task.T, task.N, task.method, task.rate, task.x0) == (1.5, 16, "newton", 50.0, task.boundary.x0)
    for section in (task, task.time, task.solver, task.output, task.boundary, task.robot_spec, task.limits):
        with pytest.raises(dataclasses.FrozenInstanceError):
            section.T = 2.0  # type: ignore[misc, union-attr]


# How each overridable key is written in the task file.
IN_FILE = {
    "N": lambda v: GOOD.replace("N: 16", f"N: {v}"),
    "T": lambda v: GOOD.replace("T: 1.5", f"T: {v}"),
    "order": lambda v: GOOD + f"order: {v}\n",
    "cost": lambda v: GOOD + f"cost: {v}\n",
    "tol": lambda v: GOOD + f"solver: {{tol: {v}}}\n",
    "max_iter": lambda v: GOOD + f"solver: {{max_iter: {v}}}\n",
    "method": lambda v: GOOD + f"solver: {{method: {v}}}\n",
    "limits": lambda v: GOOD + f"limits: {{mode: {v}}}\n",
    "collision": lambda v: GOOD + f"collision: {{mode: {v}}}\n",
}
PROBES = [0, -1, 1, 3, 2.5, 1e-6, 1e4, 100000, 100001, True, "x", "quintic", "cubic", "covariant", "torque",
          "pr-cg", "newton", "enforce", "report", "check", "off", None]
WHERE = {"N": ("time", "N"), "T": ("time", "T"), "order": ("time", "order"), "cost": ("", "cost"),
         "tol": ("solver", "tol"), "max_iter": ("solver", "max_iter"), "method": ("solver", "method"),
         "limits": ("limits", "mode"), "collision": ("collision", "mode")}


@pytest.mark.parametrize("key", sorted(IN_FILE))
def test_a_cli_override_accepts_and_refuses_exactly_what_the_task_key_does(taskdir, key):
    import json

    from hoc_cli.io.task import OVERRIDES

    assert set(OVERRIDES) == set(IN_FILE)
    base = load_task(write(taskdir, GOOD))
    section, attr = WHERE[key]
    for value in PROBES:
        if value is None:
            continue
        try:
            from_file, file_error = load_task(write(taskdir, IN_FILE[key](json.dumps(value)))), None
        except TaskError as exc:
            from_file, file_error = None, exc
        try:
            from_cli, cli_error = apply_overrides(base, **{key: value}), None
        except TaskError as exc:
            from_cli, cli_error = None, exc
        assert (file_error is None) == (cli_error is None), (key, value, file_error, cli_error)
        if file_error is None:
            get = (lambda t: getattr(t, attr)) if not section else (lambda t: getattr(getattr(t, section), attr))
            assert get(from_file) == get(from_cli) and type(get(from_file)) is type(get(from_cli))
        else:
            assert cli_error.key == OVERRIDES[key].option
            assert file_error.detail.replace("duration T >", "duration >") == cli_error.detail, (file_error, cli_error)


def test_an_unknown_override_is_a_programming_error(taskdir):
    with pytest.raises(ValueError, match="unknown override"):
        apply_overrides(load_task(write(taskdir, GOOD)), rate=5)


def test_a_duration_override_is_checked_against_the_output_rate(taskdir):
    task = load_task(write(taskdir, GOOD + "output: {rate: 1000}\n"))
    with pytest.raises(TaskError, match=r"--duration: T·rate = 2000 s × 1000 Hz gives more than 1000000"):
        apply_overrides(task, T=2000.0)
