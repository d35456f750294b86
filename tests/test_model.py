"""URDF loading: tree order, locking and merging, limits, and one clear ModelError per bad input."""
from __future__ import annotations

import numpy as np
import pytest

from hoc_cli import dynamics as D
from hoc_cli.errors import ModelError
from hoc_cli.model import RobotModel, load_robot, urdf_joint_table, urdf_link_table

from _robots import ERD, ROBOTS, SHIPPED

LINK = '<link name="{name}"><inertial><origin xyz="{com}"/><mass value="{mass}"/>' \
       '<inertia ixx="{ixx}" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>'


def link(name, mass=1.0, com="0 0 0.1", ixx=0.01):
    return LINK.format(name=name, mass=mass, com=com, ixx=ixx)


def joint(name, parent, child, kind="revolute", axis="0 0 1", xyz="0 0 0.2", extra=""):
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{xyz}" rpy="0 0 0"/><axis xyz="{axis}"/>{extra}</joint>')


def write(tmp_path, *elements, name="robot.urdf"):
    path = tmp_path / name
    path.write_text('<?xml version="1.0"?>\n<robot name="t">' + "".join(elements) + "</robot>")
    return path


def test_shipped_robots_load_with_their_documented_joints_and_masses():
    expected = {
        "pendulum.urdf": (["pivot"], 1.0),
        "two_link.urdf": (["shoulder", "elbow"], 2.0),
        "lbr7.urdf": ([f"lbr_joint_{i}" for i in range(1, 8)], 28.1),
        "dual_arm.urdf": (["torso_yaw", "left_shoulder_pitch", "left_shoulder_roll", "left_elbow",
                           "right_shoulder_pitch", "right_shoulder_roll", "right_elbow"], 20.2),
    }
    for name in SHIPPED:
        model = load_robot(ROBOTS / name)
        joints, mass = expected[name]
        assert isinstance(model, RobotModel)
        assert list(model.joint_names) == joints
        assert model.n == len(joints)
        assert model.total_mass == pytest.approx(mass)
        np.testing.assert_array_equal(model.gravity, [0.0, 0.0, -9.81])


def test_lbr7_has_the_published_kuka_link_lengths():
    model = load_robot(ROBOTS / "lbr7.urdf")
    poses = D.link_poses(model, np.zeros(7))
    z = {name: poses[name][2, 3] for name in model.link_names}
    assert z["lbr_link_2"] == pytest.approx(0.36)            # floor to A2
    assert z["lbr_link_4"] - z["lbr_link_2"] == pytest.approx(0.42)
    assert z["lbr_link_6"] - z["lbr_link_4"] == pytest.approx(0.40)
    assert z["lbr_flange"] - z["lbr_link_6"] == pytest.approx(0.126)


def test_every_shipped_link_inertia_is_physically_valid():
    for name in SHIPPED:
        for row in urdf_link_table(ROBOTS / name):
            assert row["mass"] >= 0.0
    import xml.etree.ElementTree as ET
    for name in SHIPPED:
        for inertia in ET.parse(ROBOTS / name).getroot().iter("inertia"):
            a = {k: float(v) for k, v in inertia.attrib.items()}
            I = np.array([[a["ixx"], a["ixy"], a["ixz"]], [a["ixy"], a["iyy"], a["iyz"]],
                          [a["ixz"], a["iyz"], a["izz"]]])
            p = np.linalg.eigvalsh(I)
            assert p.min() >= 0.0
            assert p[0] + p[1] >= p[2] - 1e-12  # triangle inequality


def test_default_joint_order_is_depth_first_with_children_in_document_order(tmp_path):
    path = write(
        tmp_path, link("base"), link("a"), link("b"), link("c"), link("d"),
        joint("j_b", "base", "b"), joint("j_a", "base", "a"), joint("j_c", "a", "c"), joint("j_d", "b", "d"),
    )
    assert load_robot(path).joint_names == ("j_b", "j_d", "j_a", "j_c")
    assert [row["name"] for row in urdf_joint_table(path)] == ["j_b", "j_d", "j_a", "j_c"]


def test_task_order_is_kept_and_parents_are_found_whatever_the_order(tmp_path):
    model = load_robot(ROBOTS / "two_link.urdf", joints=["elbow", "shoulder"])
    assert model.joint_names == ("elbow", "shoulder")
    assert list(model.parent) == [1, -1]
    assert list(model.order) == [1, 0]
    ref = load_robot(ROBOTS / "two_link.urdf")
    q = np.array([[0.3, -0.7]])
    np.testing.assert_allclose(D.mass_matrix(model, q[:, ::-1])[0], D.mass_matrix(ref, q)[0][::-1, ::-1])


def test_locked_joints_merge_into_their_parent_body(tmp_path):
    full = load_robot(ROBOTS / "two_link.urdf")
    locked = load_robot(ROBOTS / "two_link.urdf", joints=["shoulder"], locked={"elbow": 0.5})
    assert locked.locked == {"elbow": 0.5}
    q = np.array([[0.2, 0.5]])
    assert locked.body_mass[0] == pytest.approx(2.0)
    np.testing.assert_allclose(D.mass_matrix(locked, q[:, :1])[0, 0, 0], D.mass_matrix(full, q)[0, 0, 0])
    np.testing.assert_allclose(D.inverse_dynamics(locked, q[:, :1], [[0.0]], [[0.0]])[0, 0],
                               D.inverse_dynamics(full, q, [[0.0, 0.0]], [[0.0, 0.0]])[0, 0])
    poses = D.link_poses(locked, q[:, :1])
    np.testing.assert_allclose(poses["tool"], D.link_poses(full, q)["tool"], atol=1e-15)


def test_mimic_joints_are_always_locked_and_follow_their_locked_master():
    path = ERD / "panda_description" / "urdf" / "panda.urdf"
    assert path.is_file(), "the test extra installs example-robot-data"
    model = load_robot(path, joints=[f"panda_joint{i}" for i in range(1, 8)],
                       locked={"panda_finger_joint1": 0.03})
    assert model.locked == {"panda_finger_joint1": 0.03, "panda_finger_joint2": 0.03}
    from hoc_cli.errors import HocWarning

    with pytest.warns(HocWarning, match="'panda_finger_joint2' mimics task joint 'panda_finger_joint1'"):
        default = load_robot(path)
    assert "panda_finger_joint2" not in default.joint_names
    assert default.joint_names[-1] == "panda_finger_joint1"
    with pytest.raises(ModelError, match="mimic joint"):
        load_robot(path, joints=["panda_joint1", "panda_finger_joint2"])


def test_limits_axes_and_gravity_are_kept_and_axes_normalised(tmp_path):
    path = write(tmp_path, link("base"), link("a"), link("b"),
                 joint("j1", "base", "a", axis="0 0 2",
                       extra='<limit lower="-1" upper="2" velocity="3" effort="4"/>'),
                 joint("j2", "a", "b", kind="continuous", axis="1 1 0", extra='<limit velocity="5" effort="6"/>'))
    model = load_robot(path, gravity=[0.0, -9.81, 0.0])
    np.testing.assert_allclose(model.axis, [[0, 0, 1], [2 ** -0.5, 2 ** -0.5, 0]])
    np.testing.assert_array_equal(model.lower, [-1.0, -np.inf])
    np.testing.assert_array_equal(model.upper, [2.0, np.inf])
    np.testing.assert_array_equal(model.velocity_limit, [3.0, 5.0])
    np.testing.assert_array_equal(model.effort_limit, [4.0, 6.0])
    np.testing.assert_array_equal(model.gravity, [0.0, -9.81, 0.0])
    table = urdf_joint_table(path)
    assert table[1]["type"] == "continuous" and table[1]["lower"] is None and table[1]["effort"] == 6.0


def test_the_model_is_frozen():
    model = load_robot(ROBOTS / "two_link.urdf")
    with pytest.raises(Exception):
        model.inertia[0, 0, 0] = 1.0
    with pytest.raises(Exception):
        model.name = "other"


def expect_model_error(path, *words, **kwargs):
    with pytest.raises(ModelError) as info:
        load_robot(path, **kwargs)
    message = str(info.value)
    assert "\n" not in message
    assert str(path) in message
    for word in words:
        assert word in message
    return message


def test_a_missing_file_is_a_model_error(tmp_path):
    expect_model_error(tmp_path / "nope.urdf", "not found")


def test_malformed_xml_is_a_model_error(tmp_path):
    path = tmp_path / "bad.urdf"
    path.write_text("<robot name='x'><link name='a'></robot>")
    expect_model_error(path, "malformed XML")


def test_a_value_that_is_not_a_number_is_a_model_error_naming_the_element(tmp_path):
    path = write(tmp_path, link("base"), link("a", mass="heavy"), joint("j", "base", "a"))
    expect_model_error(path, "not a valid URDF", "link 'a'", "<mass value>='heavy' is not a number")
    path = write(tmp_path, link("base"), link("a"), joint("j", "base", "a", axis="0 1"), name="axis.urdf")
    expect_model_error(path, "joint 'j'", "<axis xyz>='0 1' is not 3 numbers")


@pytest.mark.parametrize("element,needles", [
    ('<link name="base"/><link name="a"/><joint name="j" type="revolute"><child link="a"/></joint>',
     ("joint 'j'", "has no <parent> element")),
    ('<link name="base"/><link/>', ("a <link>", "has no name attribute")),
    ('<link name="a"><inertial><mass value="1"/><inertia ixx="1" iyy="1" izz="1"/></inertial></link>',
     ("link 'a'", "<inertia> lacks ixy, ixz, iyz (all six are required)")),
])
def test_missing_urdf_elements_and_attributes_are_model_errors(tmp_path, element, needles):
    expect_model_error(write(tmp_path, element), "not a valid URDF", *needles)


def test_origins_follow_the_urdf_rpy_convention_against_scipy_and_yourdfpy(tmp_path):
    """T = Trans(xyz) · Rz(yaw) Ry(pitch) Rx(roll): scipy's extrinsic 'xyz' Euler angles, and the
    transform yourdfpy (test-only oracle) builds for the same <origin>."""
    import xml.etree.ElementTree as ET

    import yourdfpy
    from scipy.spatial.transform import Rotation

    from hoc_cli.model.urdf_xml import parse_robot

    rng = np.random.default_rng(11)
    for _ in range(5):
        xyz, rpy = rng.normal(size=3), rng.uniform(-np.pi, np.pi, 3)
        text = (f'<robot name="r"><link name="a"/><link name="b"/><joint name="j" type="fixed"><parent link="a"/>'
                f'<child link="b"/><origin xyz="{" ".join(repr(float(v)) for v in xyz)}" rpy="{" ".join(repr(float(v)) for v in rpy)}"/>'
                '</joint></robot>')
        T = parse_robot(ET.fromstring(text)).joints[0].origin
        np.testing.assert_allclose(T[:3, :3], Rotation.from_euler("xyz", rpy).as_matrix(), atol=1e-14)
        np.testing.assert_allclose(T[:3, 3], xyz, atol=0)
        path = tmp_path / "o.urdf"
        path.write_text(text)
        ref = yourdfpy.URDF.load(str(path), load_meshes=False, build_scene_graph=False,
                                 load_collision_meshes=False, build_collision_scene_graph=False)
        np.testing.assert_allclose(T, ref.robot.joints[0].origin, atol=1e-14)


@pytest.mark.parametrize("kind", ["floating", "planar"])
def test_floating_and_planar_joints_are_model_errors_naming_the_joint(tmp_path, kind):
    path = write(tmp_path, link("base"), link("a"), joint("free", "base", "a", kind=kind))
    expect_model_error(path, "joint 'free'", kind)


def test_a_cycle_is_a_model_error_naming_a_joint(tmp_path):
    path = write(tmp_path, link("base"), link("a"), link("b"),
                 joint("j1", "base", "a"), joint("j2", "a", "b"), joint("j3", "b", "a"))
    expect_model_error(path, "joint 'j3'", "closed loop")


def test_a_detached_loop_is_a_model_error_naming_a_joint(tmp_path):
    path = write(tmp_path, link("base"), link("a"), link("b"), link("c"),
                 joint("j1", "base", "a"), joint("j2", "b", "c"), joint("j3", "c", "b"))
    expect_model_error(path, "cycle", "joint 'j")


def test_several_roots_are_a_model_error_naming_a_root_link(tmp_path):
    path = write(tmp_path, link("base"), link("a"), link("stray"), joint("j1", "base", "a"))
    expect_model_error(path, "several root links", "link 'stray'")


def test_a_movable_joint_with_a_massless_subtree_is_a_model_error(tmp_path):
    path = write(tmp_path, link("base"), link("a"), '<link name="empty"/>',
                 joint("j1", "base", "a"), joint("j2", "a", "empty"))
    expect_model_error(path, "joint 'j2'", "singular mass matrix")


def test_a_point_mass_on_the_joint_axis_is_a_model_error(tmp_path):
    point = '<link name="p"><inertial><origin xyz="0 0 0.3"/><mass value="1"/>' \
            '<inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial></link>'
    path = write(tmp_path, link("base"), point, joint("spin", "base", "p"))
    expect_model_error(path, "joint 'spin'", "inertia about its axis")


def test_a_negative_mass_is_a_model_error_naming_the_link(tmp_path):
    path = write(tmp_path, link("base"), link("a", mass=-1.0), joint("j", "base", "a"))
    expect_model_error(path, "link 'a'", "negative")


def test_an_inertia_that_is_not_positive_semidefinite_is_a_model_error(tmp_path):
    path = write(tmp_path, link("base"), link("a", ixx=-0.5), joint("j", "base", "a"))
    expect_model_error(path, "link 'a'", "positive")


def test_two_joints_with_the_same_name_are_a_model_error(tmp_path):
    path = write(tmp_path, link("base"), link("a"), link("b"), joint("j", "base", "a"), joint("j", "a", "b"))
    expect_model_error(path, "joint 'j'", "unique")


def test_a_link_referenced_but_not_defined_is_a_model_error(tmp_path):
    path = write(tmp_path, link("base"), joint("j", "base", "ghost"))
    expect_model_error(path, "joint 'j'", "ghost")


def test_unknown_duplicate_or_fixed_names_in_joints_and_locked_are_model_errors():
    path = ROBOTS / "two_link.urdf"
    expect_model_error(path, "joint 'wrist'", "shoulder", joints=["wrist"])
    expect_model_error(path, "joint 'shoulder'", "twice", joints=["shoulder", "shoulder"])
    expect_model_error(path, "joint 'tool_joint'", "fixed", joints=["tool_joint"])
    expect_model_error(path, "joint 'wrist'", "cannot be locked", joints=["shoulder"], locked={"wrist": 0.0})
    expect_model_error(path, "joint 'elbow'", "both", joints=["elbow"], locked={"elbow": 0.0})
    expect_model_error(path, "gravity", gravity=[0.0, 9.81])
    expect_model_error(path, "joints must be a list", joints="shoulder")
    expect_model_error(path, "locked must map", joints=["shoulder"], locked=[1.0])


def test_inspect_tables_list_every_raw_joint_and_link():
    joints = urdf_joint_table(ROBOTS / "dual_arm.urdf")
    assert len(joints) == 8
    chest = next(row for row in joints if row["name"] == "chest_mount")
    assert chest["type"] == "fixed" and chest["axis"] is None
    links = urdf_link_table(ROBOTS / "dual_arm.urdf")
    assert sum(row["mass"] for row in links) == pytest.approx(20.2)
    assert next(row for row in links if row["name"] == "torso")["com"] == [0.02, 0.0, 0.25]


def test_a_robot_without_movable_joints_is_a_model_error(tmp_path):
    path = write(tmp_path, link("base"), link("a"), joint("fix", "base", "a", kind="fixed"))
    with pytest.raises(ModelError, match="no movable joints"):
        load_robot(path)


def test_a_mimic_joint_of_an_unknown_master_is_a_model_error(tmp_path):
    path = write(tmp_path, link("base"), link("a"), link("b"), joint("j1", "base", "a"),
                 joint("j2", "a", "b", extra='<mimic joint="nope" multiplier="1"/>'))
    with pytest.raises(ModelError, match="mimics 'nope'"):
        load_robot(path)


def test_moving_the_master_of_a_mimic_joint_warns_that_the_coupling_is_not_modelled(tmp_path):
    from hoc_cli.errors import HocWarning

    path = write(tmp_path, link("base"), link("a"), link("b"), joint("j1", "base", "a"),
                 joint("j2", "a", "b", extra='<mimic joint="j1" multiplier="1"/>'))
    with pytest.warns(HocWarning, match="mimics task joint 'j1'"):
        load_robot(path)


def test_an_indefinite_inertia_is_refused_on_a_moving_link_but_ignored_on_one_welded_to_the_base(tmp_path):
    """A link fixed to the root never moves, so its inertia cannot enter M or u (TIAGo's antennas
    have principal moments down to -3.5e-8 kg·m²); on a link a joint moves it is an error."""
    bad = ('<link name="{name}"><inertial><mass value="0.1"/>'
           '<inertia ixx="1e-7" ixy="1e-7" ixz="0" iyy="1e-8" iyz="0" izz="1e-7"/></inertial></link>')
    welded = write(tmp_path, link("base"), bad.format(name="antenna"), link("a"),
                   '<joint name="w" type="fixed"><parent link="base"/><child link="antenna"/></joint>',
                   joint("j", "base", "a"), name="welded.urdf")
    model = load_robot(welded)
    assert model.joint_names == ("j",)
    moving = write(tmp_path, link("base"), bad.format(name="a"), joint("j", "base", "a"), name="moving.urdf")
    expect_model_error(moving, "link 'a'", "not positive (semi)definite")
