"""The vertices of a mesh file (STL binary or ASCII, Wavefront OBJ, COLLADA DAE), for collision fitting.

Collision primitives are fitted to a mesh's vertices only (every vertex inside, so the convex hull
is inside): faces, normals and materials are not read. Units are the file's, multiplied by the
URDF's ``scale``; COLLADA files are placed by their scene (each ``<instance_geometry>`` under the
node transforms ``<matrix>``, ``<translate>``, ``<rotate>``, ``<scale>`` above it) and converted to
metres by ``<unit meter>``. A COLLADA ``<up_axis>`` is not applied (ROS tools read the coordinates as
written). Every failure is a :class:`MeshError` saying what is wrong with the file.
"""
from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

FORMATS = (".stl", ".obj", ".dae")
MAX_BYTES = 512 * 1024 * 1024  # a collision mesh beyond this is refused rather than read into memory


class MeshError(ValueError):
    """A mesh file cannot be read: missing, unknown format, or malformed."""


def read_vertices(path: str | Path) -> np.ndarray:
    """The distinct vertices (V, 3) of a mesh file, in the file's units (COLLADA: metres), V >= 1.

    Raises
    ------
    MeshError
        the file is missing, larger than ``MAX_BYTES``, of an unknown format, or holds no vertex
        or a malformed one.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise MeshError(f"unknown mesh format {path.suffix!r} (expected one of {', '.join(FORMATS)})")
    try:
        size = path.stat().st_size
        if not path.is_file():
            raise MeshError("is not a regular file")
        if size > MAX_BYTES:
            raise MeshError(f"is {size} bytes (at most {MAX_BYTES} are read)")
        data = path.read_bytes()
    except OSError as exc:
        raise MeshError(f"cannot be read ({exc.strerror or exc})") from None
    reader = {".stl": _stl, ".obj": _obj, ".dae": _dae}[suffix]
    vertices = reader(data)
    if vertices.size == 0:
        raise MeshError("holds no vertex")
    if not np.all(np.isfinite(vertices)):
        raise MeshError("has a vertex that is not finite")
    return np.unique(vertices, axis=0)


def _stl(data: bytes) -> np.ndarray:
    if len(data) >= 84:
        count = int.from_bytes(data[80:84], "little")
        if len(data) == 84 + 50 * count:  # binary: the size matches the triangle count exactly
            records = np.frombuffer(data, dtype=np.dtype([("normal", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")]),
                                    count=count, offset=84)
            return records["v"].reshape(-1, 3).astype(float)
    text = data.decode("ascii", errors="replace")
    if not text.lstrip().lower().startswith("solid"):
        raise MeshError("is neither a binary STL (its size does not match its triangle count) nor an ASCII STL "
                        "(it does not start with 'solid')")
    return _numbers_after(text, r"^\s*vertex\s+(.*)$", "vertex")


def _obj(data: bytes) -> np.ndarray:
    return _numbers_after(data.decode("utf-8", errors="replace"), r"^\s*v\s+(.*)$", "v", at_least=True)


def _numbers_after(text: str, pattern: str, what: str, at_least: bool = False) -> np.ndarray:
    """Three numbers from every line matching ``pattern`` (OBJ may add a weight or colours after them)."""
    rows = []
    for lineno, match in ((text.count("\n", 0, m.start()) + 1, m) for m in re.finditer(pattern, text, re.M)):
        parts = match.group(1).split()
        if len(parts) < 3 or (len(parts) != 3 and not at_least):
            raise MeshError(f"line {lineno}: '{what}' needs 3 coordinates, got {len(parts)}")
        try:
            rows.append([float(p) for p in parts[:3]])
        except ValueError:
            raise MeshError(f"line {lineno}: '{what}' coordinates are not numbers") from None
    return np.array(rows, dtype=float).reshape(-1, 3)


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def _floats(text: str | None, where: str) -> np.ndarray:
    try:
        return np.array([float(v) for v in (text or "").split()], dtype=float)
    except ValueError:
        raise MeshError(f"{where} holds a value that is not a number") from None


def _node_transform(node: ET.Element) -> np.ndarray:
    """The (4, 4) transform of a COLLADA ``<node>``: its transform elements composed in document order."""
    T = np.eye(4)
    for child in node:
        tag = _local(child.tag)
        if tag not in ("matrix", "translate", "rotate", "scale"):
            continue
        v = _floats(child.text, f"<{tag}>")
        need = {"matrix": 16, "translate": 3, "rotate": 4, "scale": 3}[tag]
        if v.size != need:
            raise MeshError(f"<{tag}> has {v.size} numbers (expected {need})")
        M = np.eye(4)
        if tag == "matrix":
            M = v.reshape(4, 4)
        elif tag == "translate":
            M[:3, 3] = v
        elif tag == "scale":
            M[:3, :3] = np.diag(v)
        else:
            axis, angle = v[:3], math.radians(v[3])
            norm = np.linalg.norm(axis)
            if norm > 0:
                k = axis / norm
                Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
                M[:3, :3] = np.eye(3) + math.sin(angle) * Kx + (1 - math.cos(angle)) * Kx @ Kx
        T = T @ M
    return T


def _dae(data: bytes) -> np.ndarray:
    try:
        root = ET.fromstring(data)
    except ET.ParseError as exc:
        raise MeshError(f"malformed XML ({exc})") from None
    unit = 1.0
    for el in root.iter():
        if _local(el.tag) == "unit" and el.get("meter") is not None:
            unit = float(_floats(el.get("meter"), "<unit meter>")[0])
            break
    sources = {el.get("id"): el for el in root.iter() if _local(el.tag) == "source"}
    geometries: dict[str, np.ndarray] = {}
    for geometry in (el for el in root.iter() if _local(el.tag) == "geometry"):
        points = []
        for vertices in (el for el in geometry.iter() if _local(el.tag) == "vertices"):
            for inp in vertices:
                if _local(inp.tag) == "input" and inp.get("semantic") == "POSITION":
                    source = sources.get((inp.get("source") or "").lstrip("#"))
                    if source is None:
                        raise MeshError(f"<vertices> refers to a missing <source> {inp.get('source')!r}")
                    array = next((e for e in source if _local(e.tag) == "float_array"), None)
                    values = _floats(None if array is None else array.text, "<float_array>")
                    if values.size % 3:
                        raise MeshError(f"positions of geometry {geometry.get('id')!r} are not triples")
                    points.append(values.reshape(-1, 3))
        geometries[geometry.get("id") or ""] = np.concatenate(points) if points else np.zeros((0, 3))
    placed = []
    instanced: set[str] = set()

    def walk(node: ET.Element, T: np.ndarray) -> None:
        for child in node:
            tag = _local(child.tag)
            if tag == "node":
                walk(child, T @ _node_transform(child))
            elif tag == "instance_geometry":
                key = (child.get("url") or "").lstrip("#")
                if key in geometries:
                    instanced.add(key)
                    P = geometries[key]
                    placed.append(P @ T[:3, :3].T + T[:3, 3])

    for scene in (el for el in root.iter() if _local(el.tag) == "visual_scene"):
        walk(scene, np.eye(4))
    # a geometry that no scene node places is taken as written (some exporters write no scene)
    placed += [P for key, P in geometries.items() if key not in instanced]
    points = np.concatenate(placed) if placed else np.zeros((0, 3))
    return points * unit
