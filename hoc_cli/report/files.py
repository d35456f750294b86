"""Output files: validating ``-o`` targets, refusing one that is an input, atomic all-or-none writes.

Every output is written to a temporary file beside its target (``.<name>.<random>.tmp``) and
renamed into place only when complete; inside ``output_transaction`` the renames wait until every
output is complete and run with SIGINT, SIGTERM and SIGHUP blocked. On any failure every temporary
file is removed and every existing target is left as it was. The renames of one transaction hold a
lock on the folders they go to (``hoc_cli.report.locks``), so two runs writing the same files
leave one run's whole set, never a mix of both.
"""
from __future__ import annotations

import errno
import os
import signal
import sys
import tempfile
import threading
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

from hoc_cli.errors import OutputError, OutputWriteError

OUTPUT_KINDS = {".csv": "csv", ".mcap": "mcap"}
#: ``-o none``: write no file at all (the JSON summary alone, with --json)
NO_OUTPUT = "none"
#: signals that end a run like SIGTERM: the exception unwinds, temporary files are removed
TERMINATING = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name))


class Terminated(BaseException):
    """Raised from the SIGTERM/SIGHUP handler so that ``finally`` blocks clean up temporary files."""

    def __init__(self, signum: int = signal.SIGTERM) -> None:
        super().__init__(signum)
        self.signum = signum


@dataclass(frozen=True)
class OutputTarget:
    """One requested output: a path (None for standard output) and its format ("csv" | "mcap")."""

    path: Path | None
    kind: str

    @property
    def label(self) -> str:
        return "-" if self.path is None else str(self.path)


def parse_outputs(outputs: list[str] | None, stem: str) -> list[OutputTarget]:
    """Validate ``-o`` values before any work is done. Default: ``<stem>.mcap`` and ``<stem>.csv`` in the cwd.

    Refused (OutputError, exit 2), each with its own message naming the file: a path given twice,
    a directory, an unknown extension, a missing or read-only directory, a name longer than the
    file system allows, a symbolic link loop, a dangling link into a missing directory.
    ``-o none`` alone writes no file (an empty list: e.g. for ``--json`` only); with another ``-o`` it
    is refused.
    """
    if not outputs:
        outputs = [f"{stem}.mcap", f"{stem}.csv"]
    if NO_OUTPUT in outputs:
        if len(outputs) > 1:
            raise OutputError(f"'-o {NO_OUTPUT}' writes no file and cannot be combined with another -o "
                              "(expected either none or files)", file=NO_OUTPUT, key="--output")
        return []
    targets: list[OutputTarget] = []
    seen: set = set()
    for raw in outputs:
        if raw == "-":
            if "-" in seen:
                raise OutputError("is given twice (expected each output once)", file=raw, key="--output")
            seen.add("-")
            targets.append(OutputTarget(None, "csv"))
            continue
        path = Path(raw)
        _check_name_length(path)
        kind = OUTPUT_KINDS.get(path.suffix.lower())
        real = _resolve_output(path)
        if real in seen:
            raise OutputError("is given twice (expected each output once)", file=raw, key="--output")
        seen.add(real)
        if real.is_dir():
            raise OutputError("is a directory (expected a file path)", file=path, key="--output")
        if kind is None:
            raise OutputError(f"unknown output extension {path.suffix or '(none)'!r} (expected .csv or .mcap, - for CSV on stdout, or none for no file)",
                              file=path, key="--output")
        check_output_directory(path)
        if not real.parent.is_dir():
            raise OutputError(f"is a symbolic link to {os.readlink(path)!r}, whose directory does not exist",
                              file=path, key="--output")
        if not os.access(real.parent, os.W_OK) or (real.exists() and not os.access(real, os.W_OK)):
            raise OutputError("not writable", file=path, key="--output")
        targets.append(OutputTarget(path, kind))
    return targets


def check_output_directory(path: Path) -> None:
    """OutputError (exit 2) naming ``path`` when the directory it would be written in is missing or not one."""
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        what = "is not a directory" if parent.exists() else "does not exist"
        raise OutputError(f"directory {str(parent)!r} {what}", file=path, key="--output")


def _name_max(directory: Path) -> int:
    try:
        return int(os.pathconf(directory if str(directory) else ".", "PC_NAME_MAX"))
    except (OSError, ValueError, AttributeError):
        return 255


def _check_name_length(path: Path) -> None:
    """OutputError (exit 2) for a file name, or a directory name on its way, longer than allowed."""
    shown = str(path)[:80] + ("…" if len(str(path)) > 80 else "")
    total = len(os.fsencode(os.path.abspath(path)))
    if total >= 4096:
        raise OutputError(f"path is {total} bytes long; the system allows fewer than 4096", file=shown, key="--output")
    limit = 255
    for parent in (path.parent if str(path.parent) else Path("."), *path.parents):
        try:
            if parent.is_dir():
                limit = _name_max(parent)
                break
        except OSError:
            continue
    for part in path.parts:
        size = len(os.fsencode(part))
        if size > limit:
            what = "file name" if part == path.name else f"directory name {part[:20]!r}…"
            raise OutputError(f"{what} is {size} bytes long; the file system allows at most {limit}",
                              file=shown, key="--output")


def _resolve_output(path: Path) -> Path:
    """Where writing ``path`` lands, symbolic links followed; OutputError for a link loop."""
    try:
        return Path(os.path.realpath(path, strict=True))
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise OutputError("is a symbolic link loop (expected a file path)", file=path, key="--output") from None
        return Path(os.path.realpath(path))  # the path, or a link's target, does not exist (yet)


def refuse_inputs(targets: list[OutputTarget], inputs: dict[str, Path | str | None]) -> None:
    """OutputError (exit 2) when an output is, symbolic links resolved, the same file as an input.

    ``inputs`` maps a description ("the task", "the URDF", "--init") to a path (None: absent).
    Hard links count as the same file too.
    """
    def identity(p) -> tuple[str, tuple[int, int] | None]:
        real = os.path.realpath(p)
        try:
            st = os.stat(real)
            return real, (st.st_dev, st.st_ino)
        except OSError:
            return real, None

    known = [(what, Path(p), *identity(p)) for what, p in inputs.items() if p is not None]
    for target in targets:
        if target.path is None:
            continue
        real, inode = identity(target.path)
        for what, path, in_real, in_inode in known:
            if real == in_real or (inode is not None and inode == in_inode):
                raise OutputError(f"is the same file as {what} {str(path)!r}; an output never replaces an input "
                                  "(expected another -o)", file=target.path, key="--output")


#: renames deferred by an open ``output_transaction`` (temporary file, target); None when none is open
_pending: list[tuple[str, Path]] | None = None
#: outputs replaced so far in this run (for the message after a late signal)
_committed: list[str] = []


@contextmanager
def output_transaction() -> Iterator[None]:
    """Defer the renames of every ``atomic_output`` in the block to its end: all targets change, or none.

    A run writing a CSV and an MCAP that is interrupted while writing the second leaves the first
    as it was too; on any exception every temporary file written in the block is removed. The
    renames run with SIGINT, SIGTERM and SIGHUP blocked, so a signal lands before or after them all.
    """
    global _pending
    outer, _pending = _pending, []
    mine = _pending
    try:
        yield
    except BaseException:
        _discard(mine)
        raise
    finally:
        _pending = outer
    if not mine:  # nothing to rename (e.g. -o none)
        return
    from hoc_cli.report.locks import directories_locked

    lock = directories_locked(path for _, path in mine)  # another run's renames into these folders: before or after
    try:
        lock.__enter__()
    except BaseException:
        _discard(mine)
        raise
    try:
        with _signals_blocked():
            for i, (tmp, path) in enumerate(mine):
                try:
                    os.replace(tmp, path)
                except BaseException as exc:
                    for rest, _ in mine[i:]:
                        _unlink(rest)
                    if isinstance(exc, OSError):
                        raise _write_error(path, exc) from None
                    raise
                _committed.append(str(path))
    finally:
        lock.__exit__(None, None, None)


#: depth of ``_signals_blocked`` blocks running now, and the signals that arrived inside them (handler, signum)
_held = 0
_deferred: list[tuple[Any, int]] = []


@contextmanager
def _signals_blocked() -> Iterator[None]:
    """SIGINT, SIGTERM and SIGHUP held for the block: the handlers installed by ``signal_handlers`` run at its end.

    The thread's signal mask alone is not enough: a process signal goes to any thread that does not
    block it (a BLAS or progress thread), and Python then runs the handler in the main thread at once.
    So the handlers themselves defer (``_deferring``) while a block runs, and the first signal that
    arrived is handled when the outermost block ends.
    """
    global _held
    mask = {signal.SIGINT, *TERMINATING}
    try:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, mask)
    except (AttributeError, ValueError, OSError):  # no POSIX signal masks here
        old = None
    _held += 1
    try:
        yield
    finally:
        _held -= 1
        if old is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)
        if not _held and _deferred:
            handler, signum = _deferred[0]
            _deferred.clear()
            handler(signum, None)


def _deferring(handler):
    """``handler`` run at once, or at the end of the ``_signals_blocked`` block running now."""
    def deferred_or_now(signum: int, frame: Any) -> None:
        if _held:
            _deferred.append((handler, signum))
            return
        handler(signum, frame)
    return deferred_or_now


@contextmanager
def signal_handlers(signals, handler) -> Iterator[None]:
    """``handler`` for each of ``signals`` in the block (held during ``_signals_blocked`` blocks), the handlers
    before it restored after it; outside the main thread (where Python sets no handler) nothing changes.
    """
    previous: dict[int, Any] = {}
    held = _deferring(handler)
    try:
        for sig in signals:
            previous[sig] = signal.signal(sig, held)
    except ValueError:  # not the main thread
        pass
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


REDELIVER_S = 0.01  # s before a swallowed signal is delivered again


@contextmanager
def redelivered_when_swallowed(on_lost: Callable[[int], None]) -> Iterator[None]:
    """A signal's exception (``KeyboardInterrupt``, :class:`Terminated`) that Python swallowed is delivered again.

    A signal handler runs wherever the main thread is, also in a ``__del__`` method or a garbage-collection
    or weakref callback (Dask's distributed registers one), where an exception cannot propagate: Python
    passes it to ``sys.unraisablehook`` and goes on, and the run would ignore the signal. In the block,
    such an exception is not printed; ``on_lost(signum)`` is called, and the signal is simulated for the
    main thread ``REDELIVER_S`` later (from a timer thread, so not inside the hook), where its handler runs
    again.
    """
    import _thread

    previous = sys.unraisablehook
    timers: list[threading.Timer] = []

    def hook(unraisable) -> None:
        exc = unraisable.exc_value
        if not isinstance(exc, (KeyboardInterrupt, Terminated)):
            previous(unraisable)
            return
        signum = exc.signum if isinstance(exc, Terminated) else signal.SIGINT
        on_lost(signum)
        timer = threading.Timer(REDELIVER_S, _thread.interrupt_main, (signum,))
        timer.daemon = True
        timers.append(timer)
        timer.start()

    sys.unraisablehook = hook
    try:
        yield
    finally:
        sys.unraisablehook = previous
        for timer in timers:  # a block that ended first took no redelivery: none reaches the code after it
            timer.cancel()


def _discard(pending: list[tuple[str, Path]]) -> None:
    """Remove the temporary files of ``pending`` renames (a failed or interrupted transaction)."""
    for tmp, _ in pending:
        _unlink(tmp)


def _unlink(tmp: str) -> None:
    try:
        os.unlink(tmp)
    except FileNotFoundError:
        pass


def _write_error(path: Path, exc: OSError) -> OutputWriteError:
    reason = exc.strerror or type(exc).__name__
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        reason += " (the disk is full)"
    return OutputWriteError(f"cannot be written: {reason}; the file was left as it was", file=path, key="--output")


def _temp_prefix(name: str, directory: Path) -> str:
    """``.<name>.`` cut so that the temporary file name (prefix + 8 random + ``.tmp``) fits the file system."""
    room = _name_max(directory) - len(".") - len(".") - 8 - len(".tmp")
    raw = os.fsencode(name)
    if len(raw) > room:
        name = raw[:max(room, 1)].decode("utf-8", "ignore") or "out"
    return f".{name}."


@contextmanager
def atomic_output(path: Path) -> Iterator[Any]:
    """Open a temporary binary file beside ``path``; rename it into place only if the block succeeds.

    On any exception (including KeyboardInterrupt and ``Terminated``) the temporary file is
    removed and an existing ``path`` is left untouched; an ``OSError`` while writing (disk full)
    becomes :class:`OutputWriteError` (exit 1) naming ``path``. Inside ``output_transaction``
    the rename waits for the end of the transaction.
    """
    shown = path
    if path.is_symlink():  # write through the link, as a plain `open(path, "w")` would
        path = Path(os.path.realpath(path))
    parent = path.parent if str(path.parent) else Path(".")
    tmp: str | None = None
    try:
        try:
            # signals blocked while the file is made and its name kept: a signal landing at once
            # after the file appears is raised here, with ``tmp`` set, and the file is removed below
            with _signals_blocked():
                fd, tmp = tempfile.mkstemp(prefix=_temp_prefix(path.name, parent), suffix=".tmp", dir=parent)
        except OSError as exc:
            raise _write_error(shown, exc) from None
        try:
            with os.fdopen(fd, "wb") as fh:
                yield fh
                fh.flush()
                os.fsync(fh.fileno())
            if path.exists():
                os.chmod(tmp, path.stat().st_mode & 0o777)
            else:
                umask = os.umask(0)
                os.umask(umask)
                os.chmod(tmp, 0o666 & ~umask)
        except OSError as exc:
            raise _write_error(shown, exc) from None
        if _pending is not None:
            _pending.append((tmp, path))
        else:
            with _signals_blocked():
                try:
                    os.replace(tmp, path)
                except OSError as exc:
                    raise _write_error(shown, exc) from None
                _committed.append(str(shown))
    except BaseException:
        if tmp is not None:
            _unlink(tmp)
        raise


def start_run() -> None:
    """A run begins: no output replaced yet (for ``what_changed``)."""
    _committed.clear()


def what_changed() -> str:
    """For the message after a signal: whether any output was already replaced in this run."""
    if not _committed:
        return "no output was changed"
    return f"every output was already written ({', '.join(_committed)})"
