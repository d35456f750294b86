"""Shared plumbing for commands: error reporting, exit codes, output targets, atomic writes.

Exit codes (SPEC.md): 0 success, 1 ran but did not meet what was asked, 2 invalid input,
130 interrupted by SIGINT, 143 terminated by SIGTERM.
"""
from __future__ import annotations

import json
import os
import signal
import sys
import tempfile
import warnings
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

from rich.console import Console

from hoc_cli.errors import HocError, HocWarning, OutputError

EXIT_OK, EXIT_UNMET, EXIT_INPUT, EXIT_SIGINT, EXIT_SIGTERM = 0, 1, 2, 130, 143
OUTPUT_KINDS = {".csv": "csv", ".mcap": "mcap"}


class Terminated(BaseException):
    """Raised from the SIGTERM handler so that ``finally`` blocks clean up temporary files."""


def stderr_console(quiet: bool = False, progress: bool = False) -> Console:
    """Rich console on standard error; silent with ``quiet``; decorated only on a terminal unless ``progress``."""
    return Console(stderr=True, quiet=quiet, force_terminal=True if progress else None, highlight=False)


def report_error(message: str) -> None:
    """One plain line on standard error (no rich markup: paths may contain brackets)."""
    sys.stderr.write(f"hoc: error: {message}\n")
    sys.stderr.flush()


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings as one line on standard error (HocWarning only; others are silenced without --debug)."""
    sys.stderr.write(f"hoc: warning: {message}\n")
    sys.stderr.flush()


def run_guarded(body: Callable[[], int], debug: bool = False) -> int:
    """Run a command body and map failures to exit codes; tracebacks only with ``debug``."""
    previous = signal.getsignal(signal.SIGTERM)

    def _on_term(signum: int, frame: Any) -> None:
        raise Terminated()

    try:
        signal.signal(signal.SIGTERM, _on_term)
    except ValueError:  # not in the main thread (e.g. some test runners)
        previous = None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always" if debug else "ignore")
            warnings.simplefilter("always", HocWarning)
            warnings.showwarning = _show_warning if not debug else warnings.showwarning
            return body()
    except HocError as exc:
        if debug:
            raise
        report_error(str(exc))
        return exc.exit_code
    except Exception as exc:  # a bug: still one line, and the traceback with --debug
        if debug:
            raise
        first = (str(exc).strip().splitlines() or [""])[0][:200]
        report_error(f"internal error ({type(exc).__name__}: {first}); please report it with the output of --debug")
        return EXIT_UNMET
    except KeyboardInterrupt:
        report_error("interrupted; no output was changed")
        return EXIT_SIGINT
    except Terminated:
        report_error("terminated; no output was changed")
        return EXIT_SIGTERM
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


@dataclass(frozen=True)
class OutputTarget:
    """One requested output: a path (None for standard output) and its format ("csv" | "mcap")."""

    path: Path | None
    kind: str

    @property
    def label(self) -> str:
        return "-" if self.path is None else str(self.path)


def parse_outputs(outputs: list[str] | None, stem: str) -> list[OutputTarget]:
    """Validate ``-o`` values before any work is done. Default: ``<stem>.mcap`` and ``<stem>.csv`` in the cwd."""
    if not outputs:
        outputs = [f"{stem}.mcap", f"{stem}.csv"]
    targets: list[OutputTarget] = []
    seen: set = set()
    for raw in outputs:
        identity = "-" if raw == "-" else os.path.realpath(raw)
        if identity in seen:
            raise OutputError("is given twice (expected each output once)", file=raw, key="--output")
        seen.add(identity)
        if raw == "-":
            targets.append(OutputTarget(None, "csv"))
            continue
        path = Path(raw)
        if path.is_dir():
            raise OutputError("is a directory (expected a file path)", file=path, key="--output")
        kind = OUTPUT_KINDS.get(path.suffix.lower())
        if kind is None:
            raise OutputError(f"unknown output extension {path.suffix or '(none)'!r} (expected .csv or .mcap, or - for CSV on stdout)", file=path, key="--output")
        parent = path.parent if str(path.parent) else Path(".")
        if not parent.is_dir():
            what = "is not a directory" if parent.exists() else "does not exist"
            raise OutputError(f"directory {str(parent)!r} {what}", file=path, key="--output")
        if path.is_dir():
            raise OutputError("is a directory (expected a file path)", file=path, key="--output")
        if not os.access(parent, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
            raise OutputError("not writable", file=path, key="--output")
        targets.append(OutputTarget(path, kind))
    return targets


#: renames deferred by an open ``output_transaction`` (temporary file, target); None when none is open
_pending: list[tuple[str, Path]] | None = None


@contextmanager
def output_transaction() -> Iterator[None]:
    """Defer the renames of every ``atomic_output`` in the block to its end: all targets change, or none.

    A run writing a CSV and an MCAP that is interrupted while writing the second leaves the first
    as it was too; on any exception every temporary file written in the block is removed.
    """
    global _pending
    outer, _pending = _pending, []
    mine = _pending
    try:
        yield
    except BaseException:
        for tmp, _ in mine:
            _unlink(tmp)
        raise
    finally:
        _pending = outer
    for i, (tmp, path) in enumerate(mine):
        try:
            os.replace(tmp, path)
        except BaseException:
            for rest, _ in mine[i:]:
                _unlink(rest)
            raise


def _unlink(tmp: str) -> None:
    try:
        os.unlink(tmp)
    except FileNotFoundError:
        pass


@contextmanager
def atomic_output(path: Path) -> Iterator[Any]:
    """Open a temporary binary file beside ``path``; rename it into place only if the block succeeds.

    On any exception (including KeyboardInterrupt and ``Terminated``) the temporary file is
    removed and an existing ``path`` is left untouched. Inside ``output_transaction`` the rename
    waits for the end of the transaction.
    """
    if path.is_symlink():  # write through the link, as a plain `open(path, "w")` would
        path = Path(os.path.realpath(path))
    parent = path.parent if str(path.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=parent)
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
        if _pending is not None:
            _pending.append((tmp, path))
        else:
            os.replace(tmp, path)
    except BaseException:
        _unlink(tmp)
        raise


def print_json(obj: Any) -> None:
    """One JSON object on standard output."""
    sys.stdout.write(json.dumps(obj, indent=2, allow_nan=False, default=_jsonable) + "\n")
    sys.stdout.flush()


def _jsonable(x: Any) -> Any:
    import numpy as np

    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.floating, np.integer, np.bool_)):
        return x.item()
    if isinstance(x, Path):
        return str(x)
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")
