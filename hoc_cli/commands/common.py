"""Shared plumbing for commands: exit codes, signals and the run guard, input files refused before any work.

What ``hoc plan`` and ``hoc batch`` both report and write (lines on standard error, JSON, output files,
the checks before a solve) lives in :mod:`hoc_cli.report`, which the commands import directly.

Exit codes (README, Exit codes): 0 success, 1 ran but did not meet what was asked (or an output could not
be written: disk full, I/O error), 2 invalid input (or an output that would replace an input),
129 hung up (SIGHUP: a closed terminal or ssh session), 130 interrupted by SIGINT, 143 terminated
by SIGTERM. A failed or interrupted run changes no output and leaves no temporary file.
"""
from __future__ import annotations

import signal
import warnings
from pathlib import Path
from typing import Any, Callable

from hoc_cli.errors import HocError, HocWarning, InputFileError
from hoc_cli.io.inputs import file_problem
from hoc_cli.report.console import (
    report_error,
    show_warning,
)
from hoc_cli.report.files import (
    TERMINATING,
    Terminated,
    redelivered_when_swallowed,
    signal_handlers,
    start_run,
    what_changed,
)

EXIT_OK, EXIT_UNMET, EXIT_INPUT, EXIT_SIGHUP, EXIT_SIGINT, EXIT_SIGTERM = 0, 1, 2, 129, 130, 143
_SIGNAL_WORDS = {getattr(signal, "SIGHUP", -1): "hung up (SIGHUP)", signal.SIGTERM: "terminated"}


def run_guarded(body: Callable[[], int], debug: bool = False, quiet: bool = False) -> int:
    """Run a command body and map failures to exit codes; tracebacks only with ``debug``.

    SIGTERM and SIGHUP raise :class:`Terminated` and SIGINT ``KeyboardInterrupt`` in the body, once:
    a second signal while the first unwinds (removing temporary files) is ignored; one whose exception
    Python swallowed (raised in a ``__del__`` or a garbage-collection callback) is raised again
    (``redelivered_when_swallowed``). ``quiet`` silences every warning.
    """
    fired = False

    def _on_signal(signum: int, frame: Any) -> None:
        nonlocal fired
        if fired:
            return
        fired = True
        if signum == signal.SIGINT:
            raise KeyboardInterrupt
        raise Terminated(signum)

    def _lost(signum: int) -> None:
        nonlocal fired
        fired = False  # its exception never reached the body: the redelivered signal raises again

    handled = list(TERMINATING)
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:  # not when SIGINT is ignored
        handled.append(signal.SIGINT)
    with signal_handlers(handled, _on_signal), redelivered_when_swallowed(_lost):  # no handlers outside the main thread
        return _run_body(body, debug, quiet)


def _run_body(body: Callable[[], int], debug: bool, quiet: bool) -> int:
    """``body()`` with its failures mapped to exit codes and one ``hoc: error:`` line (``run_guarded``)."""
    start_run()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always" if debug else "ignore")
            warnings.simplefilter("ignore" if quiet else "always", HocWarning)
            warnings.showwarning = show_warning if not debug else warnings.showwarning
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
        report_error(f"interrupted; {what_changed()}")
        return EXIT_SIGINT
    except Terminated as exc:
        report_error(f"{_SIGNAL_WORDS.get(exc.signum, f'signal {exc.signum}')}; {what_changed()}")
        return 128 + exc.signum


def refuse_irregular(inputs: list[tuple[Path | str | None, str | None, str]], *, missing_ok: bool = False) -> None:
    """InputFileError (exit 2) for an input that is not a regular file, before anything opens it.

    ``inputs``: (path or None, the option that gave it or None for an argument, what was expected,
    e.g. "a plan's MCAP file"). A FIFO would block the open and ``/dev/zero`` would be read forever.
    With ``missing_ok`` a path that does not exist is left to the command (a glob, say).
    """
    for path, key, expected in inputs:
        if path is None:
            continue
        problem = file_problem(path)
        if problem is None or (missing_ok and problem.startswith("file not found")):
            continue
        raise InputFileError(f"{problem} (expected {expected})", file=path, key=key)


def refuse_urdf_task(path: Path) -> None:
    """InputFileError (exit 2) when a URDF is given where a task YAML is expected, pointing to ``hoc new``."""
    path = Path(path)
    if file_problem(path) is not None:
        return  # load_task reports a missing file, a directory, a FIFO or a device without opening it
    looks_like_xml = path.suffix.lower() in (".urdf", ".xml")
    if not looks_like_xml:
        try:
            with open(path, "rb") as fh:
                head = fh.read(512).lstrip(b"\xef\xbb\xbf \t\r\n")
        except OSError:
            return  # load_task reports a missing or unreadable file
        looks_like_xml = head.startswith((b"<?xml", b"<robot"))
    if looks_like_xml:
        raise InputFileError(f"is a URDF (a robot), not a task; write a task for this robot with: hoc new {path} "
                             "-o task.yaml (then edit x1 and plan it)", file=path)
