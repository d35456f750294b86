"""A URDF's ``<collision>`` elements as :class:`~hoc_cli.collision.geometry.Shape` objects, meshes read.

Each link's collision elements become shapes in the link frame (the element's ``<origin>``):
``<sphere radius>``, ``<box size>``, ``<cylinder radius length>``, ``<capsule radius length>``
(axis z, as some URDFs write it) and ``<mesh filename scale>``. Mesh file names are resolved as:

- ``package://PKG/rest``: ``DIR/rest`` for the nearest folder DIR named PKG above the URDF, or
  ``DIR/PKG/rest`` for a folder DIR above the URDF or on ``ROS_PACKAGE_PATH`` (example-robot-data's
  ``package://example-robot-data/robots/…`` resolves this way against ``…/cmeel.prefix/share``);
- ``file:///abs/path`` and absolute paths as written; other paths relative to the URDF's folder.

Every failure is a :class:`~hoc_cli.errors.ModelError` naming the URDF, the link and what is wrong.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from hoc_cli.collision.geometry import Shape
from hoc_cli.errors import ModelError
from hoc_cli.io.meshes import MeshError, read_vertices
from hoc_cli.model.urdf_checks import read


def _numbers(text: str | None, count: int, what: str, src: str, key: str, positive: bool = True) -> list[float]:
    try:
        values = [float(v) for v in (text or "").split()]
    except ValueError:
        values = []
    if len(values) != count or not all(np.isfinite(values)) or (positive and min(values) <= 0):
        expected = f"{count} finite number{'s' if count > 1 else ''}" + (" > 0" if positive else "")
        raise ModelError(f"{what}={text!r} (expected {expected} in m)", file=src, key=key)
    return values


def resolve_mesh(filename: str, urdf: Path) -> Path | None:
    """The file a URDF mesh ``filename`` names (see the module docstring), or None if none exists."""
    if filename.startswith("package://"):
        package, _, rest = filename[len("package://"):].partition("/")
        roots = list(urdf.resolve().parents)
        roots += [Path(p) for p in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep) if p]
        for root in roots:
            for candidate in ((root / rest) if root.name == package else None, root / package / rest):
                if candidate is not None and candidate.is_file():
                    return candidate
        return None
    if filename.startswith("file://"):
        filename = filename[len("file://"):]
    path = Path(filename)
    if not path.is_absolute():
        path = urdf.parent / path
    return path if path.is_file() else None


def read_collision_shapes(path, *, label: str | None = None, skip=()) -> dict[str, list[Shape]]:
    """Link name → its collision shapes in the link frame, for every link with ``<collision>`` elements
    (except the links in ``skip``, whose geometry is not read: a task replaces it).
    """
    robot, path, src = read(path, label)
    out: dict[str, list[Shape]] = {}
    for link in robot.links:
        if link.name in skip:
            continue
        key = f"link {link.name!r}"
        for collision in link.collisions:
            if collision.error is not None:
                raise ModelError(f"<collision><origin>: {collision.error}", file=src, key=key)
            pose = np.eye(4) if collision.origin is None else np.asarray(collision.origin, float)
            if not np.all(np.isfinite(pose)):
                raise ModelError("<collision><origin> is not finite", file=src, key=key)
            at = collision.attributes
            kind = collision.shape
            if kind == "sphere":
                shape = Shape("sphere", pose, radius=_numbers(at.get("radius"), 1, "<sphere radius>", src, key)[0])
            elif kind == "box":
                shape = Shape("box", pose, size=np.array(_numbers(at.get("size"), 3, "<box size>", src, key)))
            elif kind in ("cylinder", "capsule"):
                r = _numbers(at.get("radius"), 1, f"<{kind} radius>", src, key)[0]
                L = _numbers(at.get("length"), 1, f"<{kind} length>", src, key)[0]
                if kind == "cylinder":
                    shape = Shape("cylinder", pose, radius=r, length=L)
                else:
                    shape = Shape("capsule", pose, radius=r, a=np.array([0, 0, -L / 2]), b=np.array([0, 0, L / 2]))
            elif kind == "mesh":
                filename = at.get("filename")
                if not filename:
                    raise ModelError("<mesh> has no filename attribute", file=src, key=key)
                scale = _numbers(at.get("scale", "1 1 1"), 3, "<mesh scale>", src, key, positive=False)
                found = resolve_mesh(filename, Path(path))
                if found is None:
                    raise ModelError(f"mesh {filename!r} not found (package:// is looked up in the folders above "
                                     "the URDF and on ROS_PACKAGE_PATH); give the link's geometry in the task's "
                                     "collision.robot instead", file=src, key=key)
                try:
                    V = read_vertices(found) * np.array(scale)
                except MeshError as exc:
                    raise ModelError(f"mesh {str(found)!r}: {exc}", file=src, key=key) from None
                shape = Shape("mesh", pose, vertices=V, source=filename)
            else:
                raise ModelError(f"<collision><geometry> holds {'nothing' if kind is None else f'<{kind}>'} "
                                 "(expected box, sphere, cylinder, capsule or mesh)", file=src, key=key)
            out.setdefault(link.name, []).append(shape)
    return out
