"""``hoc inspect ROBOT.urdf [--json]``: the parsed kinematic tree, bodies, total mass, DOF.

Human tables go to standard error (like every hoc table: standard output carries only CSV or
JSON); ``--json`` prints one object on standard output:

``robot`` (name), ``file``, ``root_link``, ``dof``, ``joints`` (the default task joints: every
revolute, continuous and prismatic non-mimic joint in URDF tree order), ``total_mass`` (kg, every
link's mass summed), ``urdf_joints`` (every joint in tree order: ``name``, ``type``, ``axis``,
``parent``, ``child``, ``lower``, ``upper`` (rad|m), ``velocity`` (rad/s|m/s), ``effort`` (N·m|N),
``mimic``; null where the URDF gives none), ``links`` (every link: ``name``, ``mass`` kg, ``com``
m in the link frame), ``plannable`` (the dynamics model loads) and ``problem`` (why not, or null).

With ``--collision`` the document also has ``collision``: one entry per link with collision
geometry, ``link``, ``shapes`` (what the URDF gives: sphere, box, cylinder, capsule, mesh),
``volume`` (m³ of that geometry, a mesh's convex hull), ``primitives`` (the capsules hoc checks:
``a``, ``b`` m in the link frame, ``radius`` m; a sphere has a = b) and ``primitive_volume`` (m³).

A URDF that cannot be parsed is exit 2 with one line; one that parses but cannot be planned on
(e.g. a movable joint carrying no mass) is still shown, with the problem as a warning.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

from rich.table import Table

from hoc_cli.commands.common import EXIT_OK
from hoc_cli.errors import ModelError
from hoc_cli.report.console import stderr_console
from hoc_cli.report.jsonio import print_json


def describe(path: Path) -> dict:
    """The JSON document described in the module docstring. Raises ModelError for a bad URDF."""
    from hoc_cli.model import load_robot, urdf_joint_table, urdf_link_table

    joints = urdf_joint_table(path)  # validates file, XML, joint types and topology
    links = urdf_link_table(path)
    default = [j["name"] for j in joints if j["type"] != "fixed" and j["mimic"] is None]
    children = {j["child"] for j in joints}
    root = next((link["name"] for link in links if link["name"] not in children), None)
    try:
        load_robot(path)
        problem = None
    except ModelError as exc:
        problem = exc.detail if exc.key is None else f"{exc.key}: {exc.detail}"
    return {
        "robot": ET.parse(path).getroot().get("name"),
        "file": str(path),
        "root_link": root,
        "dof": len(default),
        "joints": default,
        "total_mass": math.fsum(link["mass"] for link in links),
        "urdf_joints": joints,
        "links": links,
        "plannable": problem is None,
        "problem": problem,
    }


def collision_table(path: Path) -> list[dict]:
    """The ``collision`` entries described in the module docstring; ModelError for unreadable geometry."""
    from hoc_cli.collision.geometry import robot_capsule
    from hoc_cli.io.collision_geometry import read_collision_shapes

    rows = []
    for link, shapes in read_collision_shapes(path).items():
        capsules = [robot_capsule(s) for s in shapes]
        rows.append({"link": link, "shapes": [s.kind for s in shapes], "volume": sum(s.volume for s in shapes),
                     "primitives": [{"a": c.a.tolist(), "b": c.b.tolist(), "radius": c.radius} for c in capsules],
                     "primitive_volume": sum(c.volume for c in capsules)})
    return rows


def run(robot: Path, as_json: bool = False, collision: bool = False) -> int:
    doc = describe(robot)
    if collision:
        doc["collision"] = collision_table(robot)
    if as_json:
        print_json(doc)
        return EXIT_OK
    console = stderr_console()
    if not console.is_terminal:
        console.width = 160  # a pipe or a file: do not wrap the tables at 80 columns
    console.print(f"robot {doc['robot']!r} ({doc['file']}): {doc['dof']} degree{'' if doc['dof'] == 1 else 's'} of freedom, "
                  f"total mass {doc['total_mass']:.6g} kg, root link {doc['root_link']!r}", markup=False)
    dof_index = {name: i for i, name in enumerate(doc["joints"])}
    jt = Table(title="joints (tree order; # = default task order)")
    for col in ("#", "joint", "type", "axis", "parent → child", "lower", "upper", "velocity", "effort"):
        jt.add_column(col, justify="right" if col in ("#", "lower", "upper", "velocity", "effort") else "left")
    for j in doc["urdf_joints"]:
        kind = j["type"] + (f" (mimic {j['mimic']})" if j["mimic"] else "")
        axis = "" if j["axis"] is None else " ".join(_num(a) for a in j["axis"])
        jt.add_row(str(dof_index.get(j["name"], "")), j["name"], kind, axis, f"{j['parent']} → {j['child']}",
                   *(_num(j[k]) for k in ("lower", "upper", "velocity", "effort")))
    bt = Table(title="bodies (links)")
    for col in ("link", "mass [kg]", "centre of mass [m]"):
        bt.add_column(col, justify="right" if col.startswith("mass") else "left")
    for link in doc["links"]:
        bt.add_row(link["name"], _num(link["mass"]), " ".join(_num(c) for c in link["com"]))
    tables = [jt, bt]
    if collision:
        ct = Table(title="collision geometry (link frame; capsules [a, b] radius r, a sphere has a = b)")
        for col in ("link", "geometry", "volume [cm³]", "primitives [m]", "primitive volume [cm³]", "ratio"):
            ct.add_column(col, justify="right" if "volume" in col or col == "ratio" else "left")
        for row in doc["collision"]:
            prims = "; ".join(("sphere " + _vec(p["a"]) if p["a"] == p["b"] else f"{_vec(p['a'])} → {_vec(p['b'])}")
                              + f" r {p['radius']:.4g}" for p in row["primitives"])
            ratio = row["primitive_volume"] / row["volume"] if row["volume"] > 0 else math.inf
            ct.add_row(row["link"], ", ".join(row["shapes"]), f"{row['volume'] * 1e6:.4g}", prims,
                       f"{row['primitive_volume'] * 1e6:.4g}", f"{ratio:.3g}")
        if not doc["collision"]:
            ct.caption = "the URDF has no <collision> elements (give geometry in the task: collision.robot)"
        tables.append(ct)
    for table in tables:
        table.caption_justify = "left"
        console.print(table, markup=False)
    if doc["problem"]:
        console.print(f"warning: cannot plan with this URDF as it is: {doc['problem']}", markup=False)
    return EXIT_OK


def _vec(v) -> str:
    return "(" + ", ".join(f"{x:.3g}" for x in v) + ")"


def _num(x) -> str:
    return "—" if x is None else f"{x:.6g}"
