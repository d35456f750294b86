"""The task's `collision:` section and MoveIt scene files: parsed values, and one-line errors naming file and key."""
import math
import textwrap
from pathlib import Path

import numpy as np
import pytest

from hoc_cli.errors import TaskError
from hoc_cli.io.task import load_task
from tests._robots import ERD

ROOT = Path(__file__).resolve().parents[1]
HEAD = f"robot: {ROOT / 'robots' / 'lbr7.urdf'}\nx0: {{q: [0, 0, 0, 0, 0, 0, 0]}}\nx1: {{q: [0.1, 0, 0, 0, 0, 0, 0]}}\nT: 1.0\nN: 4\n"


def task(tmp_path, body: str, name: str = "t.yaml"):
    path = tmp_path / name
    path.write_text(HEAD + textwrap.dedent(body))
    return load_task(path)


def rz(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def test_a_task_without_a_collision_section_checks_nothing(tmp_path):
    spec = task(tmp_path, "").collision
    assert not spec.given and spec.mode == "off"


def test_every_obstacle_kind_with_its_pose(tmp_path):
    spec = task(tmp_path, """
        collision:
          margin: 0.02
          ignore: [[lbr_link_7, table]]
          robot:
            lbr_link_5: [{capsule: {a: [0, 0, -0.1], b: [0, 0, 0.1], radius: 0.06}}, {sphere: {radius: 0.05}, position: [0, 0, 0.2]}]
            lbr_link_6: []
          obstacles:
            - {name: table, box: {size: [1.0, 0.8, 0.04]}, position: [0.5, 0, 0.2], orientation: [0.7071067811865476, 0, 0, 0.7071067811865476]}
            - {name: post, cylinder: {radius: 0.05, length: 0.8}, position: [0.4, 0.3, 0.6]}
            - {name: ball, sphere: {radius: 0.1}, position: [0, 0.5, 1]}
            - {name: bar, capsule: {a: [0, 0, 0], b: [0.2, 0, 0], radius: 0.02}, position: [1, 1, 1]}
            - {name: floor, half_space: {normal: [0, 0, 2]}, position: [0, 0, -0.1]}
        """).collision
    assert spec.given and spec.mode == "enforce" and not spec.mode_given and spec.margin == 0.02 and spec.self_collision
    assert spec.ignore == (("lbr_link_7", "table"),)
    assert [s.kind for s in spec.robot["lbr_link_5"]] == ["capsule", "sphere"] and spec.robot["lbr_link_6"] == ()
    assert spec.robot["lbr_link_5"][1].pose[2, 3] == 0.2
    by = {o.name: o.shape for o in spec.obstacles}
    assert np.allclose(by["table"].pose[:3, :3], rz(math.pi / 2)) and np.array_equal(by["table"].size, [1.0, 0.8, 0.04])
    assert by["post"].radius == 0.05 and by["post"].length == 0.8
    assert by["ball"].radius == 0.1 and np.array_equal(by["ball"].pose[:3, 3], [0, 0.5, 1])
    assert np.array_equal(by["bar"].b, [0.2, 0, 0])
    assert np.array_equal(by["floor"].normal, [0, 0, 1])


def test_a_moveit_scene_is_read_as_written_in_ros_order(tmp_path):
    (tmp_path / "scene.yaml").write_text(textwrap.dedent("""
        name: shelf
        world:
          collision_objects:
            - header: {frame_id: lbr_link_0}
              id: shelf
              primitives:
                - {type: box, dimensions: [0.4, 0.6, 0.02]}
                - {type: cylinder, dimensions: [0.5, 0.03]}
              primitive_poses:
                - {position: [0.6, 0, 0.5], orientation: [0, 0, 0.7071067811865476, 0.7071067811865476]}
                - position: {x: 0.6, y: 0.2, z: 0.25}
                  orientation: {x: 0, y: 0, z: 0, w: 1}
            - header: {frame_id: lbr_link_0}
              id: can
              primitives: [{type: sphere, dimensions: [0.05]}]
              primitive_poses: [{position: [0.5, -0.3, 0.6], orientation: [0, 0, 0, 1]}]
        """))
    spec = task(tmp_path, "collision: {scene: scene.yaml}\n").collision
    names = [o.name for o in spec.obstacles]
    assert names == ["shelf[0]", "shelf[1]", "can"]
    box, cyl, ball = (o.shape for o in spec.obstacles)
    assert np.allclose(box.pose[:3, :3], rz(math.pi / 2)) and np.array_equal(box.size, [0.4, 0.6, 0.02])
    assert cyl.length == 0.5 and cyl.radius == 0.03 and np.array_equal(cyl.pose[:3, 3], [0.6, 0.2, 0.25])
    assert ball.radius == 0.05
    assert {o.frame for o in spec.obstacles} == {"lbr_link_0"}


def test_srdf_pairs_are_read(tmp_path):
    spec = task(tmp_path, f"collision: {{srdf: {ERD / 'panda_description/srdf/panda.srdf'}}}\n").collision
    assert ("panda_link0", "panda_link1") in spec.disabled and len(spec.disabled) > 10


SCENE_OK = ("world: {collision_objects: [{id: a, primitives: [{type: box, dimensions: [1, 1, 1]}], "
            "primitive_poses: [{position: [0, 0, 0], orientation: [0, 0, 0, 1]}]}]}")


@pytest.mark.parametrize("body,key,expect", [
    ("collision: 3", "collision", "a mapping"),
    ("collision: {mode: on}", "collision.mode", "one of enforce, check, off"),
    ("collision: {margin: -1}", "collision.margin", "a length >= 0"),
    ("collision: {self: maybe}", "collision.self", "true or false"),
    ("collision: {wat: 1}", "collision.wat", "unknown key"),
    ("collision: {srdf: nope.srdf}", "collision.srdf", "not found"),
    ("collision: {ignore: [[a]]}", "collision.ignore[0]", "a pair"),
    ("collision: {frames: {base_link: 3}}", "collision.frames.base_link", "a URDF link name"),
    ("collision: {frames: [base_link]}", "collision.frames", "a mapping scene frame_id"),
    ("collision: {robot: {l: {sphere: {radius: 1}}}}", "collision.robot.l", "a list of shapes"),
    ("collision: {robot: {l: [{half_space: {normal: [0, 0, 1]}}]}}", "collision.robot.l[0].half_space", "unknown key"),
    ("collision: {obstacles: [{box: {size: [1, 1, 1]}}]}", "collision.obstacles[0].name", "missing required key"),
    ("collision: {obstacles: [{name: a, box: {size: [1, 0, 1]}}]}", "collision.obstacles[0].box.size[1]", "a length > 0"),
    ("collision: {obstacles: [{name: a, sphere: {radius: 1}, box: {size: [1, 1, 1]}}]}", "collision.obstacles[0]", "exactly one shape"),
    ("collision: {obstacles: [{name: a, sphere: {}}]}", "collision.obstacles[0].sphere.radius", "missing required key"),
    ("collision: {obstacles: [{name: a, sphere: {radius: 1}, orientation: [1, 1, 0, 0]}]}", "collision.obstacles[0].orientation", "unit quaternion"),
    ("collision: {obstacles: [{name: a, sphere: {radius: 1}, position: [0, 0]}]}", "collision.obstacles[0].position", "3 numbers"),
    ("collision: {obstacles: [{name: a, half_space: {normal: [0, 0, 0]}}]}", "collision.obstacles[0].half_space.normal", "non-zero"),
    ("collision: {obstacles: [{name: a, sphere: {radius: 1}}, {name: a, sphere: {radius: 1}}]}", "collision.obstacles[1].name", "used twice"),
])
def test_a_malformed_entry_names_the_file_and_key(tmp_path, body, key, expect):
    with pytest.raises(TaskError) as err:
        task(tmp_path, body + "\n")
    assert err.value.key == key and expect in err.value.detail and str(err.value.file).endswith("t.yaml")
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("scene,key,expect", [
    ("x: 1", None, "MoveIt planning scene"),
    (SCENE_OK.replace("box", "cone"), "world.collision_objects[0].primitives[0].type", "cones are not supported"),
    (SCENE_OK.replace("[1, 1, 1]", "[1, 1]"), "world.collision_objects[0].primitives[0].dimensions", "full side lengths"),
    (SCENE_OK.replace("[0, 0, 0, 1]", "[0, 0, 0, 1.02]"), "world.collision_objects[0].primitive_poses[0].orientation",
     "x, y, z, w: ROS order"),
    (SCENE_OK.replace("primitive_poses: [{position: [0, 0, 0], orientation: [0, 0, 0, 1]}]", "primitive_poses: []"),
     "world.collision_objects[0].primitive_poses", "one pose per primitive"),
    (SCENE_OK.replace("id: a,", "id: a, meshes: [{}],"), "world.collision_objects[0].meshes", "not supported"),
    ("world: [1", None, "invalid YAML"),
])
def test_a_malformed_scene_names_the_scene_file_and_key(tmp_path, scene, key, expect):
    (tmp_path / "s.yaml").write_text(scene)
    with pytest.raises(TaskError) as err:
        task(tmp_path, "collision: {scene: s.yaml}\n")
    assert str(err.value.file).endswith("s.yaml") and err.value.key == key and expect in err.value.detail


def test_a_malformed_srdf_names_the_srdf(tmp_path):
    (tmp_path / "r.srdf").write_text("<robot><disable_collisions link1='a'/></robot>")
    with pytest.raises(TaskError) as err:
        task(tmp_path, "collision: {srdf: r.srdf}\n")
    assert str(err.value.file).endswith("r.srdf") and "link1 and link2" in err.value.detail
