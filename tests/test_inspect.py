"""`hoc inspect`: the tree, the masses and the default joints agree with an independent reading of the XML."""
import json
import math
import sysconfig
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from typer.testing import CliRunner

import hoc_cli.model  # noqa: E402,F401
from hoc_cli.cli import app

REPO = Path(__file__).resolve().parents[1]
ERD = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix/share/example-robot-data/robots"
SHIPPED = sorted((REPO / "robots").glob("*.urdf"))
THIRD_PARTY = [ERD / p for p in (
    "ur_description/urdf/ur5_robot.urdf",          # 6-DOF arm
    "panda_description/urdf/panda.urdf",           # 7-DOF arm + a mimic finger
    "kinova_description/robots/kinova.urdf",       # continuous joints
    "baxter_description/urdf/baxter.urdf",         # branching: two arms on a torso
)]
MOVABLE = ("revolute", "continuous", "prismatic")


def reference(path: Path) -> dict:
    """What inspect must report, read with xml.etree only: masses summed, joints depth-first."""
    root = ET.parse(path).getroot()
    mass = math.fsum(float(m.get("value")) for m in root.findall("link/inertial/mass"))
    joints = root.findall("joint")
    children: dict[str, list] = {}
    for j in joints:
        children.setdefault(j.find("parent").get("link"), []).append(j)
    child_links = {j.find("child").get("link") for j in joints}
    (base,) = [link.get("name") for link in root.findall("link") if link.get("name") not in child_links]
    order, stack = [], list(reversed(children.get(base, [])))
    while stack:
        j = stack.pop()
        order.append(j)
        stack.extend(reversed(children.get(j.find("child").get("link"), [])))
    default = [j.get("name") for j in order if j.get("type") in MOVABLE and j.find("mimic") is None]
    return {"total_mass": mass, "joints": default, "tree": [j.get("name") for j in order], "root": base,
            "by_name": {j.get("name"): j for j in joints}}


def inspect_json(path: Path) -> dict:
    r = CliRunner().invoke(app, ["inspect", str(path), "--json"])
    assert r.exit_code == 0, r.stderr
    return json.loads(r.stdout)


ROBOTS = [pytest.param(p, id=p.stem) for p in SHIPPED] + [
    pytest.param(p, id=p.stem)
    for p in THIRD_PARTY]


@pytest.mark.parametrize("path", ROBOTS)
def test_json_gives_dof_total_mass_and_default_joints_as_the_xml_says(path):
    doc, ref = inspect_json(path), reference(path)
    assert doc["joints"] == ref["joints"]
    assert doc["dof"] == len(ref["joints"])
    assert doc["total_mass"] == pytest.approx(ref["total_mass"], rel=1e-12)
    assert doc["root_link"] == ref["root"]
    assert [j["name"] for j in doc["urdf_joints"]] == ref["tree"]
    assert doc["plannable"] is True and doc["problem"] is None


@pytest.mark.parametrize("path", ROBOTS)
def test_every_joint_has_its_type_parent_child_axis_and_limits(path):
    ref = reference(path)
    for j in inspect_json(path)["urdf_joints"]:
        x = ref["by_name"][j["name"]]
        assert (j["type"], j["parent"], j["child"]) == (x.get("type"), x.find("parent").get("link"), x.find("child").get("link"))
        limit = x.find("limit")
        if j["type"] in MOVABLE:
            axis = [float(a) for a in (x.find("axis").get("xyz") if x.find("axis") is not None else "1 0 0").split()]
            norm = math.sqrt(sum(a * a for a in axis))
            assert j["axis"] == pytest.approx([a / norm for a in axis], abs=1e-15)
            if limit is not None and limit.get("effort") is not None:
                assert j["effort"] == float(limit.get("effort"))
            if j["type"] == "revolute" and limit is not None and limit.get("lower") is not None:
                assert (j["lower"], j["upper"]) == (float(limit.get("lower")), float(limit.get("upper")))
        else:
            assert j["axis"] is None


def test_every_body_reports_its_mass_and_centre_of_mass():
    path = REPO / "robots" / "two_link.urdf"
    root = ET.parse(path).getroot()
    links = {link["name"]: link for link in inspect_json(path)["links"]}
    assert set(links) == {link.get("name") for link in root.findall("link")}
    for link in root.findall("link"):
        inertial = link.find("inertial")
        if inertial is None:
            assert links[link.get("name")]["mass"] == 0.0
            continue
        assert links[link.get("name")]["mass"] == float(inertial.find("mass").get("value"))
        origin = inertial.find("origin")
        if origin is not None and origin.get("rpy") in (None, "0 0 0"):
            assert links[link.get("name")]["com"] == [float(c) for c in origin.get("xyz").split()]


def test_the_human_tables_go_to_stderr_and_name_every_joint_and_the_total_mass(tmp_path):
    path = tmp_path / "arm.urdf"
    path.write_text(ARM)
    r = CliRunner().invoke(app, ["inspect", str(path)])
    assert r.exit_code == 0 and r.stdout == ""
    for word in ("2 degrees of freedom", "total mass 3.5 kg", "shoulder", "elbow", "tip_mount", "prismatic"):
        assert word in r.stderr


ARM = """<robot name="arm">
  <link name="base"><inertial><mass value="2.0"/><inertia ixx="1" iyy="1" izz="1" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="upper"><inertial><origin xyz="0.1 0 0"/><mass value="1.0"/><inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="fore"><inertial><mass value="0.5"/><inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="tip"/>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="upper"/><axis xyz="0 0 2"/>
    <limit lower="-1" upper="1" velocity="2" effort="30"/></joint>
  <joint name="elbow" type="prismatic"><parent link="upper"/><child link="fore"/><axis xyz="1 0 0"/>
    <limit lower="0" upper="0.2" velocity="0.5" effort="100"/></joint>
  <joint name="tip_mount" type="fixed"><parent link="fore"/><child link="tip"/></joint>
</robot>
"""


def test_a_urdf_that_parses_but_cannot_be_planned_on_is_shown_with_the_problem(tmp_path):
    path = tmp_path / "massless.urdf"
    path.write_text(ARM.replace('<joint name="tip_mount" type="fixed">', '<joint name="tip_mount" type="revolute">'))
    doc = inspect_json(path)
    assert doc["dof"] == 3 and doc["plannable"] is False and "tip_mount" in doc["problem"]
    r = CliRunner().invoke(app, ["inspect", str(path)])
    assert r.exit_code == 0 and "warning: cannot plan" in r.stderr


@pytest.mark.parametrize("content, expected", [
    (None, "file not found"),
    ("<robot name='x'><link name='a'>", "malformed XML"),
    ("<robot name='x'><link name='a'/><link name='b'/><joint name='free' type='floating'>"
     "<parent link='a'/><child link='b'/></joint></robot>", "free"),
])
def test_an_unreadable_urdf_is_one_line_on_stderr_and_exit_2(tmp_path, content, expected):
    path = tmp_path / "bad.urdf"
    if content is not None:
        path.write_text(content)
    for args in ([str(path)], [str(path), "--json"]):
        r = CliRunner().invoke(app, ["inspect", *args])
        assert r.exit_code == 2 and r.stdout == ""
        assert r.stderr.count("\n") == 1 and str(path) in r.stderr and expected in r.stderr
