"""``hoc plan`` with a collision section: the certified clearance against coal at 1 kHz, collisions reported,
x0/x1 in collision refused (exit 2), ``--collision check|off``, and bad names one-line errors."""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
import yaml
from _collision_tasks import plan, task_folder
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from hoc_cli.cli import app

ROOT = Path(__file__).resolve().parents[1]
TABLE = ROOT / "configs" / "lbr7_table.yaml"


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    return task_folder(tmp_path, monkeypatch, ("lbr7.urdf",))


def table_task() -> dict:
    return yaml.safe_load(TABLE.read_text())


def _coal_clearance(doc: dict, csv_path: Path) -> tuple[float, float]:
    """(min over samples of coal's distance over robot–obstacle pairs, the same over self pairs) with Pinocchio's
    kinematics and coal's exact shapes (the post as a cylinder), independent of hoc's collision code."""
    obstacle, self_ = coal_per_sample(doc, csv_path)
    return float(obstacle.min()), float(self_.min())


def coal_per_sample(doc: dict, csv_path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(coal's smallest robot–obstacle distance (K,) m at each sample of the CSV, the same over self pairs)."""
    coal = pytest.importorskip("coal")
    pin = pytest.importorskip("pinocchio")
    model = pin.buildModelFromUrdf(str(ROOT / "robots" / "lbr7.urdf"))
    data = model.createData()
    rows = list(csv.DictReader(csv_path.open()))
    joints = [f"lbr_joint_{i}" for i in range(1, 8)]
    qs = np.array([[float(r[f"q.{j}"]) for j in joints] for r in rows])
    prims = []  # (frame id, coal shape, placement in the link frame)
    for link, shapes in doc["collision"]["robot"].items():
        for s in shapes:
            if "capsule" in s:
                a, b, r = (np.array(s["capsule"][k], float) for k in ("a", "b")), None, s["capsule"]["radius"]
                a, b = a
                prims.append((model.getFrameId(link), coal.Capsule(r, float(np.linalg.norm(b - a))),
                              pin.SE3(np.eye(3), (a + b) / 2), link))
            else:
                prims.append((model.getFrameId(link), coal.Sphere(s["sphere"]["radius"]), pin.SE3.Identity(), link))
    obstacles = []
    for o in doc["collision"]["obstacles"]:
        p = np.array(o["position"], float)
        if "box" in o:
            obstacles.append((o["name"], coal.Box(*o["box"]["size"]), coal.Transform3s(np.eye(3), p)))
        elif "cylinder" in o:
            obstacles.append((o["name"], coal.Cylinder(o["cylinder"]["radius"], o["cylinder"]["length"]),
                              coal.Transform3s(np.eye(3), p)))
        else:
            obstacles.append((o["name"], coal.Halfspace(np.array(o["half_space"]["normal"], float), float(p[2])),
                              coal.Transform3s.Identity()))
    ignore = {frozenset(p) for p in doc["collision"].get("ignore", [])}
    adjacent = {frozenset((f"lbr_link_{i}", f"lbr_link_{i + 1}")) for i in range(7)} | {
        frozenset(("lbr_link_7", "lbr_flange")), frozenset(("lbr_link_6", "lbr_flange"))}
    req = coal.DistanceRequest()
    req.enable_signed_distance = True
    worst_obstacle, worst_self = np.full(len(qs), np.inf), np.full(len(qs), np.inf)
    for k, q in enumerate(qs):
        pin.framesForwardKinematics(model, data, q)
        placed = []
        for frame, shape, local, link in prims:
            M = data.oMf[frame] * local
            placed.append((link, shape, coal.Transform3s(M.rotation, M.translation)))
        for link, shape, T in placed:
            if link == "lbr_link_0":
                continue
            for name, oshape, OT in obstacles:
                if frozenset((link, name)) in ignore:
                    continue
                res = coal.DistanceResult()
                coal.distance(shape, T, oshape, OT, req, res)
                worst_obstacle[k] = min(worst_obstacle[k], res.min_distance)
        for i, (l1, s1, T1) in enumerate(placed):
            for l2, s2, T2 in placed[i + 1:]:
                if l1 == l2 or frozenset((l1, l2)) in adjacent | ignore:
                    continue
                res = coal.DistanceResult()
                coal.distance(s1, T1, s2, T2, req, res)
                worst_self[k] = min(worst_self[k], res.min_distance)
    return worst_obstacle, worst_self


def test_the_shipped_table_reach_is_certified_and_coal_agrees_at_1_khz(workdir):
    doc = table_task()
    doc["robot"] = "../robots/lbr7.urdf"
    doc["output"] = {"rate": 1000.0}
    r, s = plan(workdir, doc)
    assert r.exit_code == 0, r.stderr
    assert s["collision_mode"] == "enforce" and s["collisions"] == []  # the section's default
    c = s["min_clearance"]
    assert c["certified"] and c["lower_bound"] >= c["margin"] == 0.01
    obstacle, self_ = _coal_clearance(doc, workdir / "out.csv")
    assert min(obstacle, self_) >= 0.01 - 1e-9
    assert c["lower_bound"] <= min(obstacle, self_) + 1e-9  # the post is a capsule for hoc: coal's cylinder is farther
    assert c["distance"] >= min(obstacle, self_) - 1e-9 or c["pair"][1] == "post"


def test_a_plan_through_an_obstacle_is_reported_with_its_interval(workdir):
    doc = table_task()
    doc["robot"] = "../robots/lbr7.urdf"
    doc["collision"]["obstacles"].append({"name": "bar", "box": {"size": [0.04, 0.04, 0.1]}, "position": [0.21, 0.07, 0.45]})
    r, s = plan(workdir, doc, "--collision", "check")
    assert r.exit_code == 0, r.stderr  # check mode: reported, not enforced
    assert not s["min_clearance"]["certified"] and s["min_clearance"]["distance"] < 0
    hits = [c for c in s["collisions"] if "bar" in c["pair"]]
    assert hits and all(c["depth"] > 0 and c["certain"] and 0 < c["interval"][0] < c["interval"][1] < 1.5 for c in hits)
    assert "and bar overlap by" in r.stderr and "hoc: warning:" in r.stderr
    assert (workdir / "out.csv").exists()


def test_enforced_the_reach_past_the_bar_is_certified_clear_and_coal_agrees_at_1_khz(workdir):
    doc = table_task()
    doc["robot"] = "../robots/lbr7.urdf"
    doc["N"] = 8
    doc["output"] = {"rate": 1000.0}
    doc["collision"]["obstacles"].append({"name": "bar", "box": {"size": [0.04, 0.04, 0.1]}, "position": [0.21, 0.07, 0.45]})
    r, s = plan(workdir, doc, "--collision", "check")
    assert r.exit_code == 0 and s["min_clearance"]["distance"] < 0  # the free plan drives the tool through the bar
    r, s = plan(workdir, doc)
    assert r.exit_code == 0, r.stderr
    c = s["min_clearance"]
    assert s["collision_mode"] == "enforce" and s["converged"] and s["collisions"] == []
    assert c["certified"] and c["lower_bound"] >= 0.01 - 1e-9
    obstacle, self_ = _coal_clearance(doc, workdir / "out.csv")
    assert min(obstacle, self_) >= 0.01 - 1e-9


def test_enforced_self_collision_keeps_the_wrist_from_the_forearm(workdir):
    doc = table_task()
    doc["robot"] = "../robots/lbr7.urdf"
    doc["N"] = 8
    doc["output"] = {"rate": 1000.0}
    doc["collision"].update({"obstacles": [], "ignore": [], "margin": 0.03})
    doc["x0"], doc["x1"] = {"q": [0.0, 0.6, 0.0, -2.0, -1.5, 1.8, 0.0]}, {"q": [0.0, 0.6, 0.0, -2.0, 1.5, 1.8, 0.0]}
    r, free = plan(workdir, doc, "--collision", "check")
    assert r.exit_code == 0 and free["min_clearance"]["distance"] < 0.02
    assert free["min_clearance"]["pair"] == ["lbr_link_5", "lbr_link_7"]
    r, s = plan(workdir, doc)
    assert r.exit_code == 0, r.stderr
    assert s["converged"] and s["min_clearance"]["certified"] and s["min_clearance"]["lower_bound"] >= 0.03 - 1e-9
    _, self_ = _coal_clearance(doc, workdir / "out.csv")
    assert self_ >= 0.03 - 1e-9
    assert s["cost"] >= free["cost"]


def test_a_start_in_collision_is_an_input_error_naming_the_pair_and_depth(workdir):
    doc = table_task()
    doc["robot"] = "../robots/lbr7.urdf"
    doc["collision"]["obstacles"][0]["position"] = [0.75, 0.0, 0.35]
    r, s = plan(workdir, doc)
    assert r.exit_code == 2 and s is None
    assert r.stderr.count("\n") == 1 and "task.yaml: x0.q: lbr_flange and table overlap by" in r.stderr
    assert not (workdir / "out.csv").exists()


def test_collision_off_and_check_on_a_task_without_a_section(workdir):
    doc = table_task()
    doc["robot"] = "../robots/lbr7.urdf"
    doc["N"] = 4  # the plan itself does not matter here
    r, s = plan(workdir, doc, "--collision", "off")
    assert r.exit_code == 0 and s["collision_mode"] == "off" and "min_clearance" not in s
    del doc["collision"]
    r, s = plan(workdir, doc)
    assert r.exit_code == 0 and s["collision_mode"] == "off"
    r, s = plan(workdir, doc, "--collision", "check")  # the URDF has no collision geometry: nothing to check
    assert r.exit_code == 0 and s["collision_mode"] == "check" and s["min_clearance"] is None and s["collisions"] == []
    r, s = plan(workdir, doc, "--collision", "enforce")  # asked for: reported as such, with nothing to impose
    assert r.exit_code == 0 and s["collision_mode"] == "enforce" and s["min_clearance"] is None
    r, _ = plan(workdir, doc, "--collision", "on")
    assert r.exit_code == 2 and "--collision: expected one of enforce, check, off" in r.stderr


@pytest.mark.parametrize("edit, message", [
    (lambda c: c["robot"].update({"lbr_hand": []}), "task.yaml: collision.robot.lbr_hand: no link 'lbr_hand'"),
    (lambda c: c.update({"ignore": [["lbr_link_3", "shelf"]]}), "task.yaml: collision.ignore[0][1]: 'shelf' is neither"),
])
def test_unknown_names_are_one_line_errors(workdir, edit, message):
    doc = table_task()
    doc["robot"] = "../robots/lbr7.urdf"
    edit(doc["collision"])
    r, _ = plan(workdir, doc)
    assert r.exit_code == 2 and message in r.stderr and r.stderr.count("\n") == 1


def test_a_scene_in_another_frame_is_refused_naming_the_scene_key(workdir):
    (workdir / "scene.yaml").write_text(
        "world:\n  collision_objects:\n    - header: {frame_id: camera}\n      id: box\n"
        "      primitives: [{type: box, dimensions: [0.1, 0.1, 0.1]}]\n"
        "      primitive_poses: [{position: [2, 0, 0.5], orientation: [0, 0, 0, 1]}]\n")
    doc = table_task()
    doc["robot"] = "../robots/lbr7.urdf"
    doc["collision"]["scene"] = "scene.yaml"
    r, _ = plan(workdir, doc)
    assert r.exit_code == 2 and "scene.yaml: world.collision_objects[0].header.frame_id: frame_id 'camera'" in r.stderr
    assert "collision.frames" in r.stderr
    doc["collision"]["frames"] = {"camera": "lbr_link_3"}  # a moving link cannot hold a scene
    r, _ = plan(workdir, doc)
    assert r.exit_code == 2 and "task.yaml: collision.frames.camera: 'lbr_link_3' is not a link fixed" in r.stderr


MBM_SCENE = """\
world:
  collision_objects:
    - header:
        frame_id: base_link
      id: side_cap
      primitives:
        - type: box
          dimensions: [0.7, 0.7, 0.04]
      primitive_poses:
        - position: [0.9, 0, 1.35]
          orientation: [0, 0.383, 0, 0.924]
"""


def test_a_motionbenchmaker_scene_is_read_as_is_with_its_frame_named(workdir):
    """MotionBenchMaker's box scene writes frame_id base_link and a quaternion of norm 1.0002 (rounded): accepted,
    normalised, and placed on the fixed link that collision.frames names."""
    from hoc_cli.io.task import load_task
    from hoc_cli.model import load_robot
    from hoc_cli.report.collision import task_collision

    urdf = (workdir.parent / "robots" / "lbr7.urdf")
    text = urdf.read_text().replace("</robot>", '<link name="mount"/><joint name="m" type="fixed"><parent link="lbr_link_0"/>'
                                    '<child link="mount"/><origin xyz="0 0 -0.5" rpy="0 0 0.3"/></joint></robot>')
    urdf.write_text(text)
    (workdir / "scene.yaml").write_text(MBM_SCENE)
    doc = table_task()
    doc["robot"] = "../robots/lbr7.urdf"
    doc["collision"]["scene"] = "scene.yaml"
    doc["collision"]["frames"] = {"base_link": "mount"}
    (workdir / "task.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    task = load_task(workdir / "task.yaml")
    scene = task_collision(task, load_robot(urdf))
    (cap,) = [o.primitive for o in scene.obstacles if o.name == "side_cap"]
    q = np.array([0, 0.383, 0, 0.924]) / np.linalg.norm([0, 0.383, 0, 0.924])
    Rz = Rotation.from_euler("z", 0.3).as_matrix()
    assert np.allclose(cap.center, Rz @ [0.9, 0, 1.35] + [0, 0, -0.5], atol=1e-12)
    assert np.allclose(cap.rotation, Rz @ Rotation.from_quat(q).as_matrix(), atol=1e-12)
    assert np.array_equal(cap.half, [0.35, 0.35, 0.02])
    r, s = plan(workdir, doc)
    assert r.exit_code == 0, r.stderr


def test_the_mcap_carries_the_collision_scene_once_latched_and_only_when_checked(workdir):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    doc = table_task()
    doc["robot"] = "../robots/lbr7.urdf"
    (workdir / "task.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    found = {}
    for extra in ((), ("--collision", "off")):
        r = CliRunner().invoke(app, ["plan", "task.yaml", "-q", "-o", "plan.mcap", *extra])
        assert r.exit_code == 0, r.stderr
        with (workdir / "plan.mcap").open("rb") as fh:
            found[extra] = list(make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
                topics=["/collision_scene"]))
    assert found[("--collision", "off")] == []
    (_, channel, message, decoded), = found[()]
    assert message.log_time == 0 and "durability: 1" in channel.metadata["offered_qos_profiles"]
    spaces = {m.ns for m in decoded.markers}
    assert {"obstacle/table", "obstacle/post", "obstacle/floor"} <= spaces
    assert {f"robot/{link}" for link in doc["collision"]["robot"]} <= spaces


def test_the_mcap_carries_the_clearance_at_every_sample_as_coal_measures_it(workdir):
    """/collision_clearance is the smallest pair distance at each /joint_states sample: equal to coal's at every
    sample (the post left out: hoc takes a cylinder as its capsule), absent without a check; ``hoc plot`` draws it."""
    from hoc_cli.commands.plot import read_plot_inputs
    from hoc_cli.io.mcap import read_plan

    doc = table_task()
    doc["robot"] = "../robots/lbr7.urdf"
    doc["collision"]["obstacles"] = [o for o in doc["collision"]["obstacles"] if o["name"] != "post"]
    (workdir / "task.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    r = CliRunner().invoke(app, ["plan", "task.yaml", "-q", "--collision", "check", "-o", "plan.mcap", "-o", "plan.csv"])
    assert r.exit_code == 0, r.stderr
    clearance = read_plan(workdir / "plan.mcap").clearance
    obstacle, self_ = coal_per_sample(doc, workdir / "plan.csv")
    assert clearance.shape == obstacle.shape and clearance.size > 100
    assert np.max(np.abs(clearance - np.minimum(obstacle, self_))) < 1e-9
    traj, _, drawn, margin = read_plot_inputs(workdir / "plan.mcap")
    assert drawn is not None and np.array_equal(drawn, clearance) and margin == 0.01
    heights = []
    for source in ("plan.mcap", "plan.csv"):  # the same joints and panels; the CSV has no clearance panel
        r = CliRunner().invoke(app, ["plot", source, "-o", "fig.png"])
        assert r.exit_code == 0, r.stderr
        heights.append(int.from_bytes((workdir / "fig.png").read_bytes()[20:24], "big"))  # PNG IHDR height
    assert heights[0] - heights[1] == round(2.2 * 110)  # CLEARANCE_HEIGHT inches at 110 dpi
    r = CliRunner().invoke(app, ["plan", "task.yaml", "-q", "--collision", "off", "-o", "plan.mcap"])
    assert r.exit_code == 0 and read_plan(workdir / "plan.mcap").clearance is None


def test_the_free_T_catch_over_a_table_is_enforced_and_its_clearance_agrees_with_coal(workdir):
    """The catch (configs/catch_ball.yaml) over a table, a free T with the constraint enforced: its free-T optimum
    keeps the margin (certified), so it is the plan (``collision_active`` false, no warning), and its certified
    clearance holds for coal at 1 kHz."""
    doc = yaml.safe_load((ROOT / "configs" / "catch_ball.yaml").read_text())
    doc["robot"] = "../robots/lbr7.urdf"
    doc["output"] = {"rate": 1000.0}
    doc["collision"] = {"margin": 0.01, "robot": table_task()["collision"]["robot"],
                        "obstacles": [{"name": "table", "box": {"size": [0.6, 0.8, 0.04]}, "position": [0.65, 0.0, 0.23]}]}
    r, s = plan(workdir, doc)
    assert r.exit_code == 0, r.stderr
    assert "hoc: warning:" not in r.stderr
    assert s["collision_mode"] == "enforce" and s["collision_active"] is False and s["collisions"] == []
    assert s["reached"]["position_error"] <= 1e-9 and 0.3 <= s["T"] <= 0.5
    c = s["min_clearance"]
    assert c["certified"] and c["pair"] == ["lbr_flange", "table"] and c["lower_bound"] >= 0.01
    obstacle, self_ = _coal_clearance(doc, workdir / "out.csv")
    assert min(obstacle, self_) >= c["lower_bound"] - 1e-9
    assert abs(obstacle - c["distance"]) <= 1e-6  # the flange's capsule against the table: the same exact shapes
