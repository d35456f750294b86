"""Issue 13 item 1: `hoc new ROBOT.urdf` writes a commented task that plans as written, within the limits,
for every shipped robot and for a UR5 and a Panda from example-robot-data; `hoc examples` lists and copies
the example tasks shipped inside the package; a URDF given where a task is expected points to `hoc new`.
"""
import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from _robots import ERD, ROBOTS, SHIPPED
from typer.testing import CliRunner

from hoc_cli.cli import app
from hoc_cli.errors import HocWarning
from hoc_cli.io.task import load_yaml
from hoc_cli.model import load_robot, urdf_joint_table
from tests._robots import task_configs

ROOT = Path(__file__).resolve().parent.parent
ROBOT_FILES = {**{name: ROBOTS / name for name in SHIPPED},
               "ur5": ERD / "ur_description/urdf/ur5_robot.urdf", "panda": ERD / "panda_description/urdf/panda.urdf"}


def hoc(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


@pytest.mark.parametrize("robot", sorted(ROBOT_FILES), ids=sorted(ROBOT_FILES))
def test_hoc_new_writes_a_task_that_plans_as_written_within_the_limits(tmp_path, robot):
    urdf = ROBOT_FILES[robot]
    if not urdf.is_file():
        pytest.skip(f"{urdf} is not installed (example-robot-data)")
    task = tmp_path / "task.yaml"
    r = hoc("new", urdf, "-o", task)
    assert r.exit_code == 0, r.output
    assert r.stdout == "" and f"wrote {task}" in r.stderr
    doc = load_yaml(task.read_text())
    rows = {row["name"]: row for row in urdf_joint_table(urdf)}
    masters = {row["mimic"] for row in rows.values() if row["mimic"]}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", HocWarning)
        movable = [j for j in load_robot(urdf).joint_names if j not in masters]
    assert doc["joints"] == movable  # every movable joint, in model order
    assert set(doc.get("locked", {})) == masters & set(rows)
    assert doc["limits"] == {"mode": "enforce"} and doc["order"] == "quintic" and doc["cost"] == "covariant"
    for key in ("x0", "x1"):
        q = doc[key]["q"]
        assert list(q) == movable
        for j, v in q.items():
            lo, hi = rows[j]["lower"], rows[j]["upper"]
            assert (lo is None or lo < v) and (hi is None or v < hi), (key, j, v, lo, hi)  # strictly inside
    assert doc["x0"]["q"] != doc["x1"]["q"]
    text = task.read_text()
    for j in movable:  # each joint's limits as a comment
        assert f"#   {j} " in text
    r = hoc("plan", task, "-o", "none", "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["converged"] is True and s["limits_mode"] == "enforce" and s["limit_violations"] == []
    assert "warning" not in r.stderr  # no mimic warning: the masters are locked


def test_hoc_new_writes_the_robot_path_relative_to_the_task_and_refuses_to_replace_a_file(tmp_path):
    (tmp_path / "tasks").mkdir()
    out = tmp_path / "tasks" / "reach.yaml"
    assert hoc("new", ROBOTS / "pendulum.urdf", "-o", out).exit_code == 0
    ref = load_yaml(out.read_text())["robot"]
    assert (out.parent / ref).resolve() == (ROBOTS / "pendulum.urdf").resolve()
    before = out.read_text()
    r = hoc("new", ROBOTS / "lbr7.urdf", "-o", out)
    assert r.exit_code == 2 and "--force" in r.stderr and r.stderr.count("\n") == 1
    assert out.read_text() == before
    assert hoc("new", ROBOTS / "lbr7.urdf", "-o", out, "--force").exit_code == 0
    assert "lbr_joint_1" in out.read_text()


def test_hoc_new_to_stdout_and_its_default_name(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = hoc("new", ROBOTS / "two_link.urdf", "-o", "-")
    assert r.exit_code == 0 and load_yaml(r.stdout)["joints"] == ["shoulder", "elbow"]
    assert list(tmp_path.iterdir()) == []
    assert hoc("new", ROBOTS / "two_link.urdf", "-q").exit_code == 0
    assert [p.name for p in tmp_path.iterdir()] == ["two_link.yaml"]


@pytest.mark.parametrize("args, needle", [
    (["new", "nope.urdf"], "nope.urdf"),
    (["new", "{robot}", "-o", "{tmp}/t.txt"], "expected .yaml"),
    (["new", "{robot}", "-o", "{tmp}/no/dir/t.yaml"], "does not exist"),
    (["new", "{robot}", "-o", "{robot}/t.yaml"], "pendulum.urdf' is not a directory"),
    (["new", "{robot}", "-o", "{robot}"], "expected .yaml"),
])
def test_hoc_new_bad_input_is_one_line_and_exit_2(tmp_path, args, needle):
    args = [a.format(robot=ROBOTS / "pendulum.urdf", tmp=tmp_path) for a in args]
    r = hoc(*args)
    assert r.exit_code == 2 and needle in r.stderr and r.stderr.count("\n") == 1


@pytest.mark.parametrize("command", ["plan", "simulate"])
def test_a_urdf_given_as_a_task_says_so_and_points_to_hoc_new(tmp_path, command):
    for path in (ROBOTS / "lbr7.urdf", tmp_path / "robot.yaml"):
        if path.suffix == ".yaml":
            path.write_text((ROBOTS / "lbr7.urdf").read_text())  # a URDF under a task's name
        r = hoc(command, path, "-o", "none")
        assert r.exit_code == 2
        assert r.stderr.count("\n") == 1 and "is a URDF" in r.stderr and f"hoc new {path}" in r.stderr


# --------------------------------------------------------------------------- hoc examples
def test_hoc_examples_lists_every_shipped_task_with_its_robot():
    r = hoc("examples")
    assert r.exit_code == 0
    names = [line.split()[0] for line in r.stdout.splitlines()]
    assert names == [p.stem for p in task_configs()]  # the hoc catch scenario is not a task
    robots = {line.split()[0]: line.split()[1] for line in r.stdout.splitlines()}
    assert robots["lbr7_reach"] == "lbr7.urdf" and robots["dual_arm"] == "dual_arm.urdf"


def test_hoc_examples_name_copies_the_task_and_its_robot_and_it_plans(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = hoc("examples", "pendulum_swing")
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pendulum.urdf", "pendulum_swing.yaml"]
    assert (tmp_path / "pendulum.urdf").read_bytes() == (ROBOTS / "pendulum.urdf").read_bytes()
    task = (tmp_path / "pendulum_swing.yaml").read_text()
    original = (ROOT / "configs" / "pendulum_swing.yaml").read_text()
    assert task == original.replace("robot: ../robots/pendulum.urdf", "robot: pendulum.urdf")
    plan = hoc("plan", "pendulum_swing.yaml", "-o", "p.csv", "-q")
    assert plan.exit_code == 0
    direct = hoc("plan", ROOT / "configs" / "pendulum_swing.yaml", "-o", "q.csv", "-q")
    assert direct.exit_code == 0
    assert (tmp_path / "p.csv").read_bytes() == (tmp_path / "q.csv").read_bytes()


def test_hoc_examples_never_replaces_a_file_without_force_and_names_unknown_examples(tmp_path):
    (tmp_path / "two_link.urdf").write_text("mine")
    r = hoc("examples", "two_link", "--dir", tmp_path)
    assert r.exit_code == 2 and "--force" in r.stderr
    assert (tmp_path / "two_link.urdf").read_text() == "mine" and not (tmp_path / "two_link.yaml").exists()
    assert hoc("examples", "two_link", "--dir", tmp_path, "--force", "-q").exit_code == 0
    assert (tmp_path / "two_link.urdf").read_text() != "mine"
    r = hoc("examples", "nope")
    assert r.exit_code == 2 and "lbr7_reach" in r.stderr and r.stderr.count("\n") == 1


def test_hoc_examples_makes_a_missing_folder_and_refuses_a_file_as_folder(tmp_path):
    r = hoc("examples", "two_link", "--dir", tmp_path / "new" / "sub", "-q")
    assert r.exit_code == 0 and (tmp_path / "new" / "sub" / "two_link.yaml").is_file()
    (tmp_path / "f").write_text("x")
    r = hoc("examples", "two_link", "--dir", tmp_path / "f")
    assert r.exit_code == 2 and "is not a directory" in r.stderr and (tmp_path / "f").read_text() == "x"


def test_the_examples_are_package_data_read_through_importlib_resources():
    from importlib import resources

    from hoc_cli.examples import examples

    folder = resources.files("hoc_cli.examples")
    shipped = examples()
    assert {e.name for e in shipped} == {p.stem for p in task_configs()}
    for e in shipped:
        assert (folder / "robots" / e.robot).is_file()
        assert (folder / "configs" / f"{e.name}.yaml").read_text() == (ROOT / "configs" / f"{e.name}.yaml").read_text()
    pyproject = (ROOT / "pyproject.toml").read_text()
    assert '"hoc_cli.examples" = ["configs/*.yaml", "robots/*.urdf"]' in pyproject


def test_the_task_template_keeps_x0_where_gravity_loads_the_joints_least():
    """On the UR5 at 0 the arm is horizontal (large shoulder torque): hoc new raises it."""
    from hoc_cli.commands.new import choose, gravity_load
    from hoc_cli.system import RobotSystem

    urdf = ROBOT_FILES["ur5"]
    if not urdf.is_file():
        pytest.skip("example-robot-data is not installed")
    model = load_robot(urdf)
    t = choose(model, {})
    effort = np.asarray(model.effort_limit)
    at_zero = gravity_load(RobotSystem(model), effort, np.zeros((1, model.n)))[0]
    assert t.gravity_load == pytest.approx(gravity_load(RobotSystem(model), effort, t.q0[None])[0])
    assert t.gravity_load < 0.5 * at_zero
