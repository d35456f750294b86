"""``hoc inspect ROBOT.urdf [--json]``: the parsed kinematic tree, bodies, total mass, DOF.

Human tables go to standard error (like every hoc table: standard output carries only CSV or
JSON); ``--json`` prints one object on standard output:

``robot`` (name), ``file``, ``root_link``, ``dof``, ``joints`` (the default task joints: every
revolute, continuous and prismatic non-mimic joint in URDF tree order), ``total_mass`` (kg, every
link's mass summed), ``urdf_joints`` (every joint in tree order: ``name``, ``type``, ``axis``,
``parent``, ``child``, ``lower``, ``upper`` (rad|m), ``velocity`` (rad/s|m/s), ``effort`` (N·m|N),
``mimic``; null where the URDF gives none), ``links`` (every link: ``name``, ``mass`` kg, ``com``
m in the link frame), ``plannable`` (the dynamics model loads) and ``problem`` (why not, or null).

A URDF that cannot be parsed is exit 2 with one line; one that parses but cannot be planned on
(e.g. a movable joint carrying no mass) is still shown, with the problem as a warning.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

from rich.table import Table

from hoc_cli.commands.common import EXIT_OK, print_json, stderr_console
from hoc_cli.errors import ModelError


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


def run(robot: Path, as_json: bool = False) -> int:
    doc = describe(robot)
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
    for table in (jt, bt):
        table.caption_justify = "left"
        console.print(table, markup=False)
    if doc["problem"]:
        console.print(f"warning: cannot plan with this URDF as it is: {doc['problem']}", markup=False)
    return EXIT_OK


def _num(x) -> str:
    return "—" if x is None else f"{x:.6g}"
