"""The ``collision:`` section: obstacles, robot geometry overrides, self-collision, margin.

.. code-block:: yaml

    collision:
      mode: enforce               # enforce (default) | check | off
      margin: 0.01                # m, the clearance required (>= 0)
      self: true                  # check the robot against itself (default)
      srdf: robot.srdf            # <disable_collisions link1= link2=/> pairs are not checked
      ignore: [[link_a, link_b], [link_c, table]]
      robot:                      # replaces a link's URDF geometry (link frame)
        panda_link5: [{capsule: {a: [0, 0, -0.1], b: [0, 0, 0.1], radius: 0.06}}]
      obstacles:                  # URDF root frame
        - {name: table, box: {size: [1.0, 0.8, 0.04]}, position: [0.5, 0, 0.2], orientation: [1, 0, 0, 0]}
      scene: scene.yaml           # MoveIt collision_objects (MotionBenchMaker scenes), as written
      frames: {base_link: lbr_link_0}   # a scene's frame_id → a link fixed to the URDF root

A shape is one of ``sphere: {radius}``, ``capsule: {a, b, radius}``, ``box: {size}`` (full side
lengths), ``cylinder: {radius, length}`` (axis z) and, for obstacles, ``half_space: {normal}``
(the solid is the side of the plane through ``position`` opposite the normal), placed by
``position`` (m) and ``orientation`` (a unit quaternion w, x, y, z). Paths are relative to the task
file. The SRDF and the scene file are read here; link names are checked against the robot when the
task is resolved (``hoc_cli.report.collision``). Every error names the file and the key.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

from hoc_cli.errors import TaskError
from hoc_cli.io.inputs import file_problem
from hoc_cli.io.task.checks import Checker, join, show
from hoc_cli.io.task.yaml12 import load_yaml

if TYPE_CHECKING:  # imported on use: a task without a collision section does not load hoc_cli.collision
    from hoc_cli.collision.geometry import Shape

COLLISION_MODES = ("enforce", "check", "off")
COLLISION_KEYS = ("mode", "margin", "self", "srdf", "ignore", "robot", "obstacles", "scene", "frames")
SHAPE_KINDS = ("sphere", "capsule", "box", "cylinder", "half_space")
SHAPE_KEYS = {"sphere": ("radius",), "capsule": ("a", "b", "radius"), "box": ("size",),
              "cylinder": ("radius", "length"), "half_space": ("normal",)}
POSE_KEYS = ("position", "orientation")
DEFAULT_MARGIN = 0.01
MAX_OBSTACLES = 10_000
SCENE_QUATERNION_TOLERANCE = 1e-2  # |norm − 1| accepted (and normalised) in scene files: MoveIt normalises too


@dataclass(frozen=True, eq=False)
class ObstacleSpec:
    """A named obstacle: its shape (pose in ``frame``), and where it was written (file, key) for messages.

    ``frame`` is None for the task's own obstacles (the URDF root frame); a scene file's
    ``header.frame_id`` otherwise (checked against the root link when the task is resolved).
    """

    name: str
    shape: Shape
    file: Path
    key: str
    frame: str | None = None


@dataclass(frozen=True, eq=False)
class CollisionSpec:
    """The validated ``collision:`` section (``given`` False: the task has none, and nothing is checked
    unless ``--collision check`` asks for the robot against itself).

    margin in m; ``disabled``: link pairs from the SRDF; ``ignore``: the task's pairs (links or
    obstacles); ``robot``: link → shapes in the link frame.
    """

    given: bool = False
    mode: str = "off"  # without a collision section; "enforce" is the section's default
    mode_given: bool = False  # ``collision.mode`` written in the task (else the default)
    margin: float = DEFAULT_MARGIN
    self_collision: bool = True
    srdf: Path | None = None
    disabled: tuple[tuple[str, str], ...] = ()
    ignore: tuple[tuple[str, str], ...] = ()
    robot: Mapping[str, tuple[Shape, ...]] = field(default_factory=lambda: MappingProxyType({}))
    obstacles: tuple[ObstacleSpec, ...] = ()
    scene: Path | None = None
    frames: Mapping[str, str] = field(default_factory=lambda: MappingProxyType({}))


def check_collision_mode(c: Checker, value: Any, key: str) -> str:
    """``enforce``, ``check`` or ``off``."""
    return c.choice(value, key, COLLISION_MODES)


def _vec(c: Checker, value: Any, key: str, size: int, what: str) -> np.ndarray:
    if not isinstance(value, (list, tuple)) or len(value) != size:
        raise c.fail(key, f"a list of {size} numbers ({what})", value)
    return np.array([c.number(v, f"{key}[{i}]") for i, v in enumerate(value)])


def _rotation(w: float, x: float, y: float, z: float) -> np.ndarray:
    """(3, 3) rotation of the unit quaternion (w, x, y, z)."""
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def _unit_quaternion(c: Checker, q: np.ndarray, key: str, order: str, tolerance: float = 1e-6) -> np.ndarray:
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > tolerance:
        raise c.error(key, f"expected a unit quaternion ({order}), got norm {norm:.9g}")
    return q / norm


def _pose(c: Checker, m: dict, key: str) -> np.ndarray:
    T = np.eye(4)
    if m.get("position") is not None:
        T[:3, 3] = _vec(c, m["position"], f"{key}.position", 3, "x, y, z in m")
    if m.get("orientation") is not None:
        q = _vec(c, m["orientation"], f"{key}.orientation", 4, "a unit quaternion w, x, y, z")
        T[:3, :3] = _rotation(*_unit_quaternion(c, q, f"{key}.orientation", "w, x, y, z"))
    return T


def _length(c: Checker, value: Any, key: str, zero: bool = False) -> float:
    x = c.number(value, key, what="a length >= 0 in m" if zero else "a length > 0 in m")
    if x < 0 or (x == 0 and not zero):
        raise c.fail(key, "a length >= 0 in m" if zero else "a length > 0 in m", value)
    return x


def _shape(c: Checker, value: Any, key: str, extra: tuple[str, ...], kinds: tuple[str, ...]) -> tuple[Shape, dict]:
    """A shape entry ``{KIND: {...}, position?, orientation?, *extra}``; returns (shape, the mapping)."""
    from hoc_cli.collision.geometry import Shape

    m = c.mapping(value, key, kinds + POSE_KEYS + extra)
    present = [k for k in kinds if k in m]
    if len(present) != 1:
        raise c.error(key, f"expected exactly one shape key of: {', '.join(kinds)}"
                      + (f" (got {', '.join(present)})" if present else ""))
    kind = present[0]
    skey = f"{key}.{kind}"
    p = c.mapping(m[kind], skey, SHAPE_KEYS[kind])
    for k in SHAPE_KEYS[kind]:
        if k not in p:
            raise c.error(f"{skey}.{k}", f"missing required key '{k}'")
    T = _pose(c, m, key)
    if kind == "sphere":
        return Shape("sphere", T, radius=_length(c, p["radius"], f"{skey}.radius")), m
    if kind == "capsule":
        return Shape("capsule", T, radius=_length(c, p["radius"], f"{skey}.radius"),
                     a=_vec(c, p["a"], f"{skey}.a", 3, "x, y, z in m"), b=_vec(c, p["b"], f"{skey}.b", 3, "x, y, z in m")), m
    if kind == "box":
        size = _vec(c, p["size"], f"{skey}.size", 3, "full side lengths x, y, z in m")
        for i, s in enumerate(size):
            if s <= 0:
                raise c.fail(f"{skey}.size[{i}]", "a length > 0 in m", s)
        return Shape("box", T, size=size), m
    if kind == "cylinder":
        return Shape("cylinder", T, radius=_length(c, p["radius"], f"{skey}.radius"),
                     length=_length(c, p["length"], f"{skey}.length")), m
    n = _vec(c, p["normal"], f"{skey}.normal", 3, "an outward normal x, y, z")
    if np.linalg.norm(n) == 0:
        raise c.error(f"{skey}.normal", "expected a non-zero normal")
    return Shape("half_space", T, normal=n / np.linalg.norm(n)), m


def _name(c: Checker, value: Any, key: str, what: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise c.fail(key, what, value)
    return value


def _path(c: Checker, value: Any, key: str, what: str) -> Path:
    if not isinstance(value, str) or not value.strip():
        raise c.fail(key, f"a path to {what} (string)", value)
    path = Path(value)
    if not path.is_absolute():
        path = c.path.parent / path
    problem = file_problem(path)  # a FIFO or a device is refused before anything opens it
    if problem is not None and problem.startswith("file not found"):
        raise c.error(key, f"{what} not found: {str(path)[:200]!r}")
    if problem is not None:
        raise c.error(key, f"{str(path)[:200]!r} {problem} (expected {what})")
    return path


def read_srdf(c: Checker, path: Path, key: str) -> tuple[tuple[str, str], ...]:
    """The ``<disable_collisions link1 link2>`` pairs of an SRDF; errors name the SRDF (or ``key`` if unreadable)."""
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise TaskError(f"malformed XML ({exc}); expected an SRDF document", file=path) from None
    except OSError as exc:
        raise c.error(key, f"cannot be read ({exc.strerror})") from None
    pairs = []
    for i, el in enumerate(root.iter("disable_collisions")):
        a, b = el.get("link1"), el.get("link2")
        if not a or not b:
            raise TaskError("expected link1 and link2 attributes", file=path, key=f"<disable_collisions> #{i + 1}")
        pairs.append((a, b))
    return tuple(pairs)


# ------------------------------------------------------------------ MoveIt scene files
def _ros_pose(s: Checker, value: Any, key: str) -> np.ndarray:
    """A geometry_msgs/Pose written as ``{position: [x, y, z] | {x, y, z}, orientation: [x, y, z, w] | {x, y, z, w}}``."""
    m = s.mapping(value, key, POSE_KEYS)
    T = np.eye(4)

    def numbers(v: Any, k: str, names: str) -> np.ndarray:
        if isinstance(v, dict):
            v = s.mapping(v, k, tuple(names))
            missing = [n for n in names if n not in v]
            if missing:
                raise s.error(f"{k}.{missing[0]}", f"missing required key '{missing[0]}'")
            v = [v[n] for n in names]
        return _vec(s, v, k, len(names), ", ".join(names))

    if m.get("position") is not None:
        T[:3, 3] = numbers(m["position"], f"{key}.position", "xyz")
    if m.get("orientation") is not None:
        x, y, z, w = _unit_quaternion(s, numbers(m["orientation"], f"{key}.orientation", "xyzw"),
                                      f"{key}.orientation", "x, y, z, w: ROS order", SCENE_QUATERNION_TOLERANCE)
        T[:3, :3] = _rotation(w, x, y, z)
    return T


def read_scene(c: Checker, path: Path, key: str) -> tuple[ObstacleSpec, ...]:
    """The obstacles of a MoveIt planning-scene YAML (``world: {collision_objects: [...]}``, or a bare
    ``collision_objects`` list): box (full side lengths), sphere [radius] and cylinder [height, radius]
    primitives with their ``primitive_poses`` (composed with the object's ``pose`` when given).
    Errors name the scene file and the key in it.
    """
    from hoc_cli.collision.geometry import Shape

    s = Checker(path)
    try:
        doc = load_yaml(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise c.error(key, f"cannot be read as UTF-8 text ({exc.__class__.__name__})") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        raise TaskError(f"invalid YAML{where}: {getattr(exc, 'problem', None) or 'invalid syntax'}", file=path) from None
    if isinstance(doc, dict) and "world" in doc:
        world, base = doc["world"], "world"
        if not isinstance(world, dict):
            raise s.fail("world", "a mapping with collision_objects", world)
        objects, base = world.get("collision_objects", []), "world.collision_objects"
    elif isinstance(doc, dict) and "collision_objects" in doc:
        objects, base = doc["collision_objects"], "collision_objects"
    else:
        raise TaskError("expected a MoveIt planning scene (world: {collision_objects: [...]})", file=path)
    if objects is None:
        objects = []
    if not isinstance(objects, list):
        raise s.fail(base, "a list of collision objects", objects)
    out = []
    for i, obj in enumerate(objects):
        okey = f"{base}[{i}]"
        if not isinstance(obj, dict):
            raise s.fail(okey, "a collision object mapping (id, header, primitives, primitive_poses)", obj)
        name = _name(s, obj.get("id"), f"{okey}.id", "an object id (string)")
        frame = None
        header = obj.get("header")
        if isinstance(header, dict) and header.get("frame_id") is not None:
            frame = str(header["frame_id"])
        for what in ("meshes", "planes"):
            if obj.get(what):
                raise s.error(f"{okey}.{what}", f"{what} are not supported (expected primitives: box, sphere, cylinder)")
        op = obj.get("operation", "add")
        if op not in ("add", 0, "ADD"):
            raise s.fail(f"{okey}.operation", "add (a scene lists the objects present)", op)
        base_pose = _ros_pose(s, obj["pose"], f"{okey}.pose") if obj.get("pose") is not None else np.eye(4)
        prims, poses = obj.get("primitives") or [], obj.get("primitive_poses") or []
        if not isinstance(prims, list) or not isinstance(poses, list) or len(prims) != len(poses):
            raise s.error(f"{okey}.primitive_poses", f"expected one pose per primitive ({len(prims) if isinstance(prims, list) else '?'} "
                          f"primitives, {len(poses) if isinstance(poses, list) else '?'} poses)")
        for j, (prim, pose) in enumerate(zip(prims, poses)):
            pkey = f"{okey}.primitives[{j}]"
            if not isinstance(prim, dict):
                raise s.fail(pkey, "a primitive {type, dimensions}", prim)
            kind = prim.get("type")
            dims = prim.get("dimensions")
            T = base_pose @ _ros_pose(s, pose, f"{okey}.primitive_poses[{j}]")
            need = {"box": 3, "sphere": 1, "cylinder": 2}
            if kind not in need:
                raise s.fail(f"{pkey}.type", "one of box, sphere, cylinder (cones are not supported)", kind)
            if not isinstance(dims, list) or len(dims) != need[kind]:
                what = {"box": "[x, y, z] full side lengths", "sphere": "[radius]", "cylinder": "[height, radius]"}[kind]
                raise s.fail(f"{pkey}.dimensions", f"{need[kind]} lengths in m: {what}", dims)
            d = [_length(s, v, f"{pkey}.dimensions[{k}]") for k, v in enumerate(dims)]
            if kind == "box":
                shape = Shape("box", T, size=np.array(d))
            elif kind == "sphere":
                shape = Shape("sphere", T, radius=d[0])
            else:
                shape = Shape("cylinder", T, radius=d[1], length=d[0])
            label = name if len(prims) == 1 else f"{name}[{j}]"
            out.append(ObstacleSpec(name=label, shape=shape, file=path, key=pkey, frame=frame))
    return tuple(out)


def parse_collision(c: Checker, top: dict, parsed: dict) -> CollisionSpec:
    """``collision:`` (optional; without it a plan is not checked for collisions unless asked to)."""
    if top.get("collision") is None:
        return CollisionSpec()
    m = c.mapping(top["collision"], "collision", COLLISION_KEYS)
    mode = check_collision_mode(c, m.get("mode", "enforce"), "collision.mode")
    margin = _length(c, m.get("margin", DEFAULT_MARGIN), "collision.margin", zero=True)
    self_collision = m.get("self", True)
    if not isinstance(self_collision, bool):
        raise c.fail("collision.self", "true or false", self_collision)
    srdf = _path(c, m["srdf"], "collision.srdf", "an SRDF file") if m.get("srdf") is not None else None
    disabled = read_srdf(c, srdf, "collision.srdf") if srdf is not None else ()
    ignore = []
    if m.get("ignore") is not None:
        if not isinstance(m["ignore"], list):
            raise c.fail("collision.ignore", "a list of [name, name] pairs (links or obstacles)", m["ignore"])
        for i, pair in enumerate(m["ignore"]):
            key = f"collision.ignore[{i}]"
            if not isinstance(pair, list) or len(pair) != 2:
                raise c.fail(key, "a pair [name, name] of links or obstacles", pair)
            ignore.append(tuple(_name(c, v, f"{key}[{k}]", "a link or obstacle name") for k, v in enumerate(pair)))
    robot: dict[str, tuple[Shape, ...]] = {}
    if m.get("robot") is not None:
        links = c.names(m["robot"], "collision.robot", "a mapping link -> list of shapes")
        for link, shapes in links.items():
            key = join("collision.robot", link)
            if not isinstance(shapes, list):
                raise c.fail(key, "a list of shapes (sphere, capsule, box, cylinder; [] for none)", shapes)
            robot[link] = tuple(_shape(c, s, f"{key}[{i}]", (), SHAPE_KINDS[:4])[0] for i, s in enumerate(shapes))
    obstacles: list[ObstacleSpec] = []
    if m.get("obstacles") is not None:
        if not isinstance(m["obstacles"], list):
            raise c.fail("collision.obstacles", "a list of obstacles {name, <shape>, position, orientation}", m["obstacles"])
        for i, o in enumerate(m["obstacles"]):
            key = f"collision.obstacles[{i}]"
            shape, om = _shape(c, o, key, ("name",), SHAPE_KINDS)
            if "name" not in om:
                raise c.error(f"{key}.name", "missing required key 'name'")
            obstacles.append(ObstacleSpec(name=_name(c, om["name"], f"{key}.name", "an obstacle name (string)"),
                                          shape=shape, file=c.path, key=key))
    scene = None
    if m.get("scene") is not None:
        scene = _path(c, m["scene"], "collision.scene", "a scene file")
        obstacles += read_scene(c, scene, "collision.scene")
    frames: dict[str, str] = {}
    if m.get("frames") is not None:
        given = c.names(m["frames"], "collision.frames", "a mapping scene frame_id -> URDF link")
        frames = {k: _name(c, v, join("collision.frames", k), "a URDF link name") for k, v in given.items()}
    if len(obstacles) > MAX_OBSTACLES:
        raise c.error("collision.obstacles", f"expected at most {MAX_OBSTACLES} obstacles, got {len(obstacles)}")
    seen: dict[str, ObstacleSpec] = {}
    for o in obstacles:
        if o.name in seen:
            raise TaskError(f"obstacle name {show(o.name)} is used twice (expected distinct names)", file=o.file,
                            key=o.key if o.file != c.path else f"{o.key}.name")
        seen[o.name] = o
    return CollisionSpec(given=True, mode=mode, mode_given="mode" in m, margin=margin, self_collision=self_collision, srdf=srdf,
                         disabled=disabled, ignore=tuple(ignore), robot=MappingProxyType(robot),
                         obstacles=tuple(obstacles), scene=scene, frames=MappingProxyType(frames))


__all__ = ["COLLISION_MODES", "CollisionSpec", "ObstacleSpec", "check_collision_mode", "parse_collision",
           "read_scene", "read_srdf"]
