"""Robot collision geometry: mesh files read as coal reads them, conservative capsule fits, `hoc inspect --collision`."""
import json
import math
import struct

import numpy as np
import pytest
from scipy.spatial import cKDTree
from typer.testing import CliRunner

from hoc_cli.cli import app
from hoc_cli.collision.geometry import Shape, robot_capsule
from hoc_cli.collision.shapes import Box, box_capsule, cylinder_capsule, fit_vertices
from hoc_cli.io.collision_geometry import read_collision_shapes
from hoc_cli.io.meshes import MeshError, read_vertices
from hoc_cli.model import load_robot
from tests._robots import ERD

ARMS = {
    "panda": "panda_description/urdf/panda.urdf",      # binary STL + boxes
    "ur5": "ur_description/urdf/ur5_robot.urdf",       # binary STL
    "kinova": "kinova_description/robots/kinova.urdf",  # COLLADA
    "xarm7": "xarm_description/urdf/xarm7.urdf",        # binary STL
    "z1": "z1_description/urdf/z1.urdf",                # cylinders + STL (upper-case suffix)
}
MESHES = ["panda_description/meshes/collision/link1.stl", "kinova_description/meshes/arm.dae",
          "kinova_description/meshes/base.dae", "z1_description/meshes/collision/z1_GripperMover.STL"]


def _segment_distance(P, a, b):
    """Independent point–segment distance (projection clamped to the segment)."""
    d = b - a
    L2 = d @ d
    t = np.zeros(len(P)) if L2 == 0 else np.clip((P - a) @ d / L2, 0, 1)
    return np.linalg.norm(P - a - t[:, None] * d, axis=1)


@pytest.mark.parametrize("mesh", MESHES)
def test_mesh_vertices_are_the_ones_coal_loads(mesh):
    coal = pytest.importorskip("coal")
    ours = read_vertices(ERD / mesh)
    theirs = np.array(coal.MeshLoader().load(str(ERD / mesh), np.ones(3)).vertices())
    # the same point sets (coal keeps float32-rounded coordinates): each point has a twin in the other set
    assert cKDTree(theirs).query(ours)[0].max() < 1e-6
    assert cKDTree(ours).query(theirs)[0].max() < 1e-6


def test_ascii_stl_and_obj_give_the_vertices_written(tmp_path):
    rng = np.random.default_rng(0)
    tris = rng.normal(size=(5, 3, 3))
    ascii_stl = "solid t\n" + "".join(
        "facet normal 0 0 1\n outer loop\n" + "".join(f"  vertex {x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in tri)
        + " endloop\nendfacet\n" for tri in tris) + "endsolid t\n"
    (tmp_path / "a.stl").write_text(ascii_stl)
    obj = "# cube\n" + "".join(f"v {x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in tris.reshape(-1, 3)) + "f 1 2 3\n"
    (tmp_path / "a.obj").write_text(obj)
    binary = b"x" * 80 + struct.pack("<I", 5) + b"".join(
        struct.pack("<3f", 0, 0, 1) + struct.pack("<9f", *tri.ravel()) + b"\0\0" for tri in tris)
    (tmp_path / "b.stl").write_bytes(binary)
    want = np.unique(tris.reshape(-1, 3), axis=0)
    assert np.array_equal(read_vertices(tmp_path / "a.stl"), want)
    assert np.array_equal(read_vertices(tmp_path / "a.obj"), want)
    assert np.allclose(read_vertices(tmp_path / "b.stl"), want, atol=1e-6)  # float32


@pytest.mark.parametrize("text,why", [("solid x\nvertex 1 2\n", "3 coordinates"), ("hello", "neither"),
                                      ("solid x\nendsolid", "no vertex")])
def test_a_malformed_mesh_says_what_is_wrong(tmp_path, text, why):
    (tmp_path / "m.stl").write_text(text)
    with pytest.raises(MeshError, match=why):
        read_vertices(tmp_path / "m.stl")


@pytest.mark.parametrize("name", ARMS)
def test_every_fitted_primitive_contains_its_geometry(name):
    """Conservative fits: every mesh vertex, box corner and cylinder rim point is inside its capsule."""
    shapes = read_collision_shapes(ERD / ARMS[name])
    assert shapes
    for link, items in shapes.items():
        for s in items:
            c = robot_capsule(s)
            T = s.pose
            if s.kind == "mesh":
                P = s.vertices @ T[:3, :3].T + T[:3, 3]
            elif s.kind == "box":
                signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
                P = (signs * s.size / 2) @ T[:3, :3].T + T[:3, 3]
            elif s.kind == "cylinder":
                phi = np.linspace(0, 2 * np.pi, 64)
                rim = np.array([[s.radius * math.cos(p), s.radius * math.sin(p), z]
                                for p in phi for z in (-s.length / 2, s.length / 2)])
                P = rim @ T[:3, :3].T + T[:3, 3]
            else:
                continue
            assert _segment_distance(P, c.a, c.b).max() <= c.radius * (1 + 1e-12), (link, s.kind)
            assert c.volume >= s.volume * (1 - 1e-9)  # contains the convex hull


def test_fits_of_a_long_cloud_box_and_cylinder_are_tight():
    rng = np.random.default_rng(1)
    # points on a capsule's surface: the fit recovers a capsule no larger than it
    t = rng.uniform(0, 1, 2000)
    ang = rng.uniform(0, 2 * np.pi, 2000)
    P = np.c_[0.05 * np.cos(ang), 0.05 * np.sin(ang), 0.4 * t]
    c = fit_vertices(P)
    assert c.radius == pytest.approx(0.05, rel=1e-3)
    assert c.length <= 0.4 + 1e-9
    box = Box(center=np.zeros(3), rotation=np.eye(3), half=np.array([0.3, 0.02, 0.01]))
    cb = box_capsule(box)
    assert cb.radius == pytest.approx(math.hypot(0.02, 0.01))
    assert sorted([cb.a[0], cb.b[0]]) == pytest.approx([-0.3, 0.3])  # the corners lie on the end circles
    cc = cylinder_capsule(np.eye(4), 0.1, 0.5)
    assert cc.radius == 0.1 and cc.length == pytest.approx(0.5)


def test_package_and_relative_mesh_paths_resolve(tmp_path):
    (tmp_path / "pkg" / "meshes").mkdir(parents=True)
    (tmp_path / "pkg" / "meshes" / "m.obj").write_text("v 0 0 0\nv 0 0 1\nv 0.1 0 0.5\n")
    (tmp_path / "pkg" / "urdf").mkdir()
    urdf = tmp_path / "pkg" / "urdf" / "r.urdf"
    urdf.write_text("""<robot name="r"><link name="base"/>
      <link name="a"><inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial>
        <collision><origin xyz="1 0 0"/><geometry><mesh filename="package://pkg/meshes/m.obj" scale="2 2 2"/></geometry></collision>
        <collision><geometry><mesh filename="../meshes/m.obj"/></geometry></collision>
        <collision><geometry><sphere radius="0.2"/></geometry></collision></link>
      <joint name="j" type="revolute"><parent link="base"/><child link="a"/><axis xyz="0 0 1"/>
        <limit lower="-1" upper="1" effort="1" velocity="1"/></joint></robot>""")
    shapes = read_collision_shapes(urdf)["a"]
    assert [s.kind for s in shapes] == ["mesh", "mesh", "sphere"]
    assert shapes[0].vertices.max() == 2.0 and shapes[1].vertices.max() == 1.0
    assert shapes[0].pose[0, 3] == 1.0
    doc = json.loads(CliRunner().invoke(app, ["inspect", str(urdf), "--json", "--collision"]).stdout)
    (row,) = doc["collision"]
    assert row["link"] == "a" and len(row["primitives"]) == 3
    assert row["primitives"][2] == {"a": [0.0, 0.0, 0.0], "b": [0.0, 0.0, 0.0], "radius": 0.2}
    assert row["primitive_volume"] >= row["volume"] > 0


def test_a_missing_mesh_or_bad_collision_origin_is_one_line_naming_the_link(tmp_path):
    urdf = tmp_path / "r.urdf"
    body = ('<inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial>'
            '<collision><origin xyz="0 0 x"/><geometry><box size="1 1 1"/></geometry></collision>'
            '<collision><geometry><mesh filename="package://nowhere/m.stl"/></geometry></collision>')
    urdf.write_text(f"""<robot name="r"><link name="base"/><link name="a">{body}</link>
      <joint name="j" type="revolute"><parent link="base"/><child link="a"/><axis xyz="0 0 1"/>
        <limit lower="-1" upper="1" effort="1" velocity="1"/></joint></robot>""")
    load_robot(urdf)  # planning without collision checking does not read collision elements
    r = CliRunner().invoke(app, ["inspect", str(urdf), "--collision"])
    assert r.exit_code == 2
    assert r.stderr.strip().count("\n") == 0
    assert "link 'a'" in r.stderr and "<origin xyz>" in r.stderr
    urdf.write_text(urdf.read_text().replace('xyz="0 0 x"', 'xyz="0 0 0"'))
    r = CliRunner().invoke(app, ["inspect", str(urdf), "--collision"])
    assert r.exit_code == 2 and "mesh 'package://nowhere/m.stl' not found" in r.stderr


def test_inspect_collision_lists_every_panda_link_with_a_smaller_hull_than_its_capsules():
    r = CliRunner().invoke(app, ["inspect", str(ERD / ARMS["panda"]), "--json", "--collision"])
    doc = json.loads(r.stdout)
    links = {row["link"]: row for row in doc["collision"]}
    assert {f"panda_link{i}" for i in range(8)} | {"panda_hand"} <= set(links)
    assert links["panda_leftfinger"]["shapes"] == ["box"] * 4
    for row in doc["collision"]:
        assert row["primitive_volume"] >= row["volume"] > 0
    r = CliRunner().invoke(app, ["inspect", str(ERD / ARMS["panda"]), "--collision"])
    assert r.exit_code == 0 and "collision geometry" in r.stderr


def test_robot_capsule_of_a_task_capsule_is_exact():
    s = Shape("capsule", np.eye(4), radius=0.06, a=np.array([0, 0, 0.1]), b=np.array([0, 0, -0.1]))
    c = robot_capsule(s)
    assert np.array_equal(c.a, [0, 0, 0.1]) and c.radius == 0.06
