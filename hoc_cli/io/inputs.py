"""Input paths: refuse what is not a regular file before opening it.

Opening a FIFO blocks until a writer appears, and reading ``/dev/zero`` or ``/dev/urandom`` never
ends; ``stat`` does neither. Every command checks its input files with :func:`file_problem`
before it opens them (symbolic links are followed, so a link to a regular file is fine).
"""
from __future__ import annotations

import os
import stat
from pathlib import Path

_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def file_problem(path: str | Path) -> str | None:
    """None when ``path`` is a regular file (links followed); else what it is instead.

    Returns e.g. ``"file not found"``, ``"is a directory"``, ``"is a character device, not a regular
    file"``; a name the system cannot look up (too long, a NUL byte) is not found either.
    """
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return "file not found"
    except NotADirectoryError:
        return "file not found (a part of the path is not a directory)"
    except (OSError, ValueError) as exc:
        reason = getattr(exc, "strerror", None) or type(exc).__name__
        return f"file not found ({reason})"
    if stat.S_ISREG(mode):
        return None
    for test, what in _KINDS:
        if test(mode):
            return "is a directory" if what == "a directory" else f"is {what}, not a regular file"
    return "is not a regular file"
