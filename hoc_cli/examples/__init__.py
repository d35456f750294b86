"""The example tasks and robots shipped inside the package, for ``hoc examples``.

``configs/`` (task YAML files) and ``robots/`` (URDF files) sit beside this module as package data
(in a source checkout they are links to the repository's ``configs/`` and ``robots/``), so they are
found through :mod:`importlib.resources` from a clone, an editable install and a wheel alike. Each
task names its robot as ``../robots/<file>.urdf``, relative to the task file.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from importlib import resources
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from importlib.abc import Traversable

#: the ``robot:`` line of a task file: key, value, and an optional trailing comment
_ROBOT_LINE = re.compile(r"^robot:[ \t]*(?P<value>[^#\n]*?)[ \t]*(?P<comment>#.*)?$", re.M)


@dataclass(frozen=True)
class Example:
    """One shipped task: ``name`` (file stem), ``description`` (its leading comment), the task text,
    and ``robot`` (the URDF file name in the package's ``robots/``).
    """

    name: str
    description: str
    text: str
    robot: str

    def robot_text(self) -> str:
        """The URDF document of this example's robot."""
        return (_folder("robots") / self.robot).read_text(encoding="utf-8")

    def text_beside_robot(self) -> str:
        """The task text with ``robot:`` naming the URDF by its file name (task and robot in one folder)."""
        return _ROBOT_LINE.sub(lambda m: f"robot: {self.robot}" + (f"   {m['comment']}" if m["comment"] else ""),
                               self.text, count=1)


def _folder(name: str) -> Traversable:
    return resources.files(__name__) / name


def _description(text: str) -> str:
    """The first sentence of the task file's leading comment (without '#')."""
    lines = []
    for line in text.splitlines():
        if not line.startswith("#"):
            break
        lines.append(line.lstrip("#").strip())
    words = " ".join(lines)
    end = words.find(". ")
    return words if end < 0 else words[: end + 1]


def examples() -> list[Example]:
    """Every shipped example task, sorted by name."""
    out = []
    for entry in sorted(_folder("configs").iterdir(), key=lambda e: e.name):
        if not entry.name.endswith(".yaml"):
            continue
        text = entry.read_text(encoding="utf-8")
        match = _ROBOT_LINE.search(text)
        if match is None:  # pragma: no cover  (every shipped task names its robot)
            continue
        robot = match["value"].strip().strip("'\"").rsplit("/", 1)[-1]
        out.append(Example(name=entry.name[: -len(".yaml")], description=_description(text), text=text, robot=robot))
    return out


def find(name: str) -> Example | None:
    """The example called ``name`` (with or without ``.yaml``), or None."""
    stem = name[: -len(".yaml")] if name.endswith(".yaml") else name
    return next((e for e in examples() if e.name == stem), None)
