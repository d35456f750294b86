"""The results folder of a batch, checked before any plan is solved (nothing is written by the checks).

Refused (OutputError, exit 2, naming the folder): a dangling symbolic link, a path that is not a
folder, a folder (or, when it does not exist yet, the folder it would be created in) that this
process cannot create files in (read-only, no permission, read-only file system), and results
files or a ``plans`` entry that are not what hoc writes there. Writability is tried, not guessed
from the permission bits: a temporary file is created and removed.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

from hoc_cli.errors import OutputError


def check_folder(out: Path, *, plans: bool, names: tuple[str, ...], key: str = "--output") -> None:
    """Raise OutputError unless ``out`` is, or can be created as, a folder hoc can write its results into.

    ``plans``: per-plan outputs go to ``out/plans`` (which must then be a folder too if it exists);
    ``names``: the results files (must not be folders).
    """
    out = Path(out)
    if out.is_symlink() and not out.exists():
        raise OutputError(f"is a symbolic link to {os.readlink(out)!r}, which does not exist (expected a results "
                          "folder, or a path where one can be created)", file=out, key=key)
    if out.exists():
        if not out.is_dir():
            raise OutputError("exists and is not a folder (expected a results folder)", file=out, key=key)
        _writable(out, out, key)
        for name in names:
            if (out / name).is_dir():
                raise OutputError(f"{name} is a folder (expected the results file hoc writes there)", file=out, key=key)
        sub = out / "plans"
        if plans and (sub.exists() or sub.is_symlink()):
            if not sub.is_dir():
                raise OutputError("plans exists and is not a folder (expected the folder of the per-plan files)",
                                  file=out, key=key)
            _writable(sub, out, key)
        return
    ancestor = out.parent
    while not ancestor.exists() and ancestor != ancestor.parent:
        if ancestor.is_symlink():
            raise OutputError(f"cannot be created: {str(ancestor)!r} is a symbolic link to a missing path",
                              file=out, key=key)
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise OutputError(f"cannot be created: {str(ancestor)!r} is not a folder", file=out, key=key)
    _writable(ancestor, out, key, creating=True)


def _writable(folder: Path, out: Path, key: str, creating: bool = False) -> None:
    try:
        fd, probe = tempfile.mkstemp(prefix=".hoc-write-test.", dir=folder)
    except OSError as exc:
        where = "is not writable" if not creating else f"cannot be created in {str(folder)!r}"
        if folder != out and not creating:
            where = f"{folder.name} is not writable"
        raise OutputError(f"{where} ({exc.strerror or type(exc).__name__}; expected a folder hoc can write to)",
                          file=out, key=key) from None
    os.close(fd)
    os.unlink(probe)
