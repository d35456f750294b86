"""CSV trajectories: ``t,q.<joint>…,dq.<joint>…,ddq.<joint>…,u.<joint>…`` (SPEC.md, Outputs).

One header row, then one row per sample (K rows). Columns: t [s]; q [rad or m]; q̇ [rad/s or m/s];
q̈ [rad/s² or m/s²]; u [N·m or N], joints in task order within each group. Every float is written
with ``repr`` (the shortest string that parses back to the same double), so a file read back
with :func:`read_csv` gives bit-identical arrays. Lines end with ``\\n``.
"""
from __future__ import annotations

import io
import math
import os
from pathlib import Path
from typing import IO

import numpy as np

from hoc_cli.errors import InputFileError
from hoc_cli.trajectory import Trajectory

GROUPS = ("q", "dq", "ddq", "u")
#: characters that str.splitlines (used by read_csv) treats as line ends
_LINE_BREAKS = set("\n\r\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029")
_FORBIDDEN = set(',"') | _LINE_BREAKS


def header(joints: tuple[str, ...] | list[str]) -> list[str]:
    """Column names for ``joints``: ``["t", "q.j0", …, "dq.j0", …, "ddq.j0", …, "u.j0", …]`` (1 + 4n)."""
    return ["t"] + [f"{g}.{j}" for g in GROUPS for j in joints]


def column_problem(joint: str) -> str | None:
    """Why ``joint`` cannot name CSV columns that :func:`read_csv` reads back as written, or None.

    Refused: an empty name, a comma, a double quote or a line break (they would split or quote the
    header cell), and leading or trailing white space (the reader strips header cells).
    """
    if not joint:
        return "it is empty"
    if _LINE_BREAKS & set(joint):
        return "it contains a line break"
    bad = sorted(_FORBIDDEN & set(joint))
    if bad:
        return "it contains " + " and ".join(repr(c) for c in bad)
    if joint != joint.strip():
        return "it starts or ends with white space"
    return None


def write_csv(fh: IO, traj: Trajectory) -> None:
    """Write ``traj`` (t (K,), q, dq, ddq, u (K, n)) as CSV to ``fh``, a binary or text stream.

    Raises ValueError if a joint name cannot be a CSV column (contains a comma, a quote or a
    line break) or if the arrays do not have the shapes above.
    """
    joints = tuple(traj.joints)
    for j in joints:
        problem = column_problem(j)
        if problem:
            raise ValueError(f"joint name {j!r} cannot be a CSV column ({problem})")
    K, n = traj.K, len(joints)
    table = [np.asarray(traj.t, dtype=float).reshape(K, 1)]
    for g in GROUPS:
        a = np.asarray(getattr(traj, g), dtype=float)
        if a.shape != (K, n):
            raise ValueError(f"trajectory {g} has shape {a.shape}, expected ({K}, {n})")
        table.append(a)
    rows = np.hstack(table).tolist()  # Python floats: repr gives the shortest exact form
    lines = [",".join(header(joints))]
    lines.extend(",".join(map(repr, row)) for row in rows)
    text = "\n".join(lines) + "\n"
    if isinstance(fh, io.TextIOBase):
        fh.write(text)
    else:
        fh.write(text.encode("utf-8"))


def read_csv(path: str | os.PathLike) -> Trajectory:
    """Read a CSV written by :func:`write_csv` (or by hand, in the same layout) into a Trajectory.

    Validates the header (``t`` first, then four groups q/dq/ddq/u naming the same joints in the
    same order), that every row has 1 + 4n finite numbers, and that t is strictly increasing.
    The result has no Hermite representation (``mesh`` and ``coeffs`` are None).

    Raises InputFileError naming the file, the line and what was expected.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputFileError("file not found (expected a CSV written by hoc)", file=path) from None
    except UnicodeDecodeError:
        raise InputFileError("not a text file (expected a CSV written by hoc)", file=path) from None
    except OSError as exc:
        raise InputFileError(f"cannot be read ({exc.strerror})", file=path) from None
    lines = text.splitlines()
    if not lines or not lines[0].strip():
        raise InputFileError("empty file (expected a header row t,q.<joint>…,dq.<joint>…,ddq.<joint>…,u.<joint>…)", file=path)
    joints = _parse_header(lines[0], path)
    width = 1 + 4 * len(joints)
    values = []
    for lineno, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        cells = line.split(",")
        if len(cells) != width:
            raise InputFileError(f"line {lineno} has {len(cells)} values, expected {width} (as in the header)", file=path)
        try:
            row = [float(c) for c in cells]
        except ValueError:
            bad = next(c for c in cells if not _is_float(c))
            raise InputFileError(f"line {lineno}: {bad.strip()!r} is not a number", file=path) from None
        for col, x in enumerate(row):
            if not math.isfinite(x):
                name = header(joints)[col]
                raise InputFileError(f"line {lineno}, column {name}: {x} is not a finite number", file=path)
        values.append(row)
    if not values:
        raise InputFileError("no data rows after the header (expected one row per sample)", file=path)
    data = np.array(values, dtype=float)
    t = data[:, 0].copy()
    if t.size > 1 and not np.all(np.diff(t) > 0):
        k = int(np.argmin(np.diff(t) > 0))
        raise InputFileError(f"t must increase strictly, but line {k + 3} has t = {t[k + 1]!r} after {t[k]!r}", file=path)
    n = len(joints)
    blocks = [data[:, 1 + i * n: 1 + (i + 1) * n].copy() for i in range(4)]
    return Trajectory(joints=joints, t=t, q=blocks[0], dq=blocks[1], ddq=blocks[2], u=blocks[3])


def _parse_header(line: str, path: Path) -> tuple[str, ...]:
    expected = "expected t,q.<joint>…,dq.<joint>…,ddq.<joint>…,u.<joint>…"
    cols = [c.strip() for c in line.split(",")]
    if cols[0] != "t":
        raise InputFileError(f"header starts with {cols[0]!r}, {expected}", file=path)
    rest = cols[1:]
    if not rest or len(rest) % 4:
        raise InputFileError(f"header has {len(rest)} columns after t, {expected} (4 per joint)", file=path)
    n = len(rest) // 4
    groups = [rest[i * n:(i + 1) * n] for i in range(4)]
    joints = []
    for c in groups[0]:
        if not c.startswith("q.") or len(c) == 2:
            raise InputFileError(f"header column {c!r} where a q.<joint> column was expected; {expected}", file=path)
        joints.append(c[2:])
    if len(set(joints)) != n:
        raise InputFileError(f"header names a joint twice among {joints}", file=path)
    for g, cols_g in zip(GROUPS[1:], groups[1:]):
        want = [f"{g}.{j}" for j in joints]
        if cols_g != want:
            bad = next(c for c, w in zip(cols_g, want) if c != w)
            raise InputFileError(f"header column {bad!r} where {want[cols_g.index(bad)]!r} was expected "
                                 f"(the q, dq, ddq and u groups must name the same joints in the same order)", file=path)
    return tuple(joints)


def _is_float(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True
