"""Locks on output folders, so that concurrent runs never mix or lose each other's files.

Two kinds, both ``fcntl.flock`` locks (released by the kernel when their process ends, so a
killed run leaves no stale lock behind):

- ``FolderLock``: one ``hoc batch`` run per results folder. Held for the whole run on the file
  ``DIR/.hoc-batch.lock`` (which records the holder's process id); a second run into the same
  folder is refused at once (exit 2) instead of overwriting the first one's rows.
- ``directories_locked``: the moment a run renames its finished outputs into place (all of them,
  or none: ``hoc_cli.report.files.output_transaction``) it holds a lock on each folder they go
  to, so that two runs writing the same files (``hoc plan`` twice with the same ``-o``) replace
  them one whole set after the other: the MCAP and the CSV always come from the same run.
"""
from __future__ import annotations

import errno
import os
from contextlib import contextmanager
from pathlib import Path
from typing import Iterable, Iterator

from hoc_cli.errors import OutputError

LOCK_NAME = ".hoc-batch.lock"

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX: no locking
    fcntl = None  # type: ignore[assignment]


class FolderLock:
    """``with FolderLock(folder):`` holds ``folder/.hoc-batch.lock`` exclusively, or raises OutputError (exit 2).

    The lock file is removed on release. A lock file left by a process that died is not a lock
    (the kernel released its flock); the next run takes it over.
    """

    def __init__(self, folder: Path, key: str = "--output") -> None:
        self.folder, self.key = Path(folder), key
        self.path = self.folder / LOCK_NAME
        self.fd: int | None = None

    def __enter__(self) -> FolderLock:
        if fcntl is None:  # pragma: no cover
            return self
        for _ in range(20):  # a holder may remove the file between our open and our flock: take the new one
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
            except OSError as exc:
                raise OutputError(f"cannot create its lock file {LOCK_NAME} ({exc.strerror}; expected a writable "
                                  "folder)", file=self.folder, key=self.key) from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                holder = _read_pid(fd)
                os.close(fd)
                if exc.errno not in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                    raise OutputError(f"cannot lock it ({exc.strerror})", file=self.folder, key=self.key) from None
                who = f" (process {holder})" if holder else ""
                raise OutputError(f"is in use by another 'hoc batch' run{who}; wait for it to end, or write to "
                                  "another folder (expected one run per results folder)",
                                  file=self.folder, key=self.key) from None
            if _same_file(fd, self.path):
                self.fd = fd
                os.ftruncate(fd, 0)
                os.write(fd, f"{os.getpid()}\n".encode())
                return self
            os.close(fd)  # the file we locked was removed meanwhile
        raise OutputError("cannot lock it (its lock file keeps changing)", file=self.folder, key=self.key)

    def __exit__(self, *exc) -> None:
        if self.fd is None:
            return
        try:
            os.unlink(self.path)  # while still holding it: a waiting run then sees a new file
        except OSError:
            pass
        os.close(self.fd)
        self.fd = None


def _read_pid(fd: int) -> int | None:
    try:
        text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None


def _same_file(fd: int, path: Path) -> bool:
    try:
        a, b = os.fstat(fd), os.stat(path)
    except OSError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


@contextmanager
def directories_locked(paths: Iterable[Path]) -> Iterator[None]:
    """Hold an exclusive flock on the folder of each path (sorted, so that two runs cannot deadlock).

    Blocks while another run holds one (it holds them only while renaming its files into place). A
    folder that cannot be opened or locked is skipped: the renames then fail or succeed on their own.
    """
    if fcntl is None:  # pragma: no cover
        yield
        return
    folders = sorted({os.path.realpath(Path(p).parent if str(Path(p).parent) else ".") for p in paths})
    held: list[int] = []
    try:
        for folder in folders:
            try:
                fd = os.open(folder, os.O_RDONLY | os.O_CLOEXEC)
            except OSError:
                continue
            held.append(fd)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX)
            except OSError:
                pass
        yield
    finally:
        for fd in reversed(held):
            os.close(fd)
