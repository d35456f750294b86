"""Shared plumbing for commands: error reporting, exit codes, signals, checks made before any work.

Output files (targets, atomic writes) live in :mod:`hoc_cli.commands.files`, re-exported here.

Exit codes (README, Exit codes): 0 success, 1 ran but did not meet what was asked (or an output could not
be written: disk full, I/O error), 2 invalid input (or an output that would replace an input),
129 hung up (SIGHUP: a closed terminal or ssh session), 130 interrupted by SIGINT, 143 terminated
by SIGTERM. A failed or interrupted run changes no output and leaves no temporary file.
"""
from __future__ import annotations

import json
import math
import signal
import sys
import warnings
from pathlib import Path
from typing import Any, Callable

from rich.console import Console

from hoc_cli.commands import files as _files
from hoc_cli.commands.files import (  # noqa: F401  (re-exported: the commands import them from here)
    OUTPUT_KINDS,
    TERMINATING,
    OutputTarget,
    atomic_output,
    output_transaction,
    parse_outputs,
    refuse_inputs,
    what_changed,
)
from hoc_cli.errors import HocError, HocWarning, InputFileError, JointSelectionError, OutputError, TaskError
from hoc_cli.io.inputs import file_problem

EXIT_OK, EXIT_UNMET, EXIT_INPUT, EXIT_SIGHUP, EXIT_SIGINT, EXIT_SIGTERM = 0, 1, 2, 129, 130, 143
_SIGNAL_WORDS = {getattr(signal, "SIGHUP", -1): "hung up (SIGHUP)", signal.SIGTERM: "terminated"}


class Terminated(BaseException):
    """Raised from the SIGTERM/SIGHUP handler so that ``finally`` blocks clean up temporary files."""

    def __init__(self, signum: int = signal.SIGTERM) -> None:
        super().__init__(signum)
        self.signum = signum


def stderr_console(quiet: bool = False, progress: bool = False) -> Console:
    """Rich console on standard error; silent with ``quiet``; decorated only on a terminal unless ``progress``."""
    return Console(stderr=True, quiet=quiet, force_terminal=True if progress else None, highlight=False)


def _say(line: str) -> None:
    """One line on standard error; a closed terminal (SIGHUP, EIO) or pipe is not a second failure."""
    try:
        sys.stderr.write(line + "\n")
        sys.stderr.flush()
    except (OSError, ValueError):
        pass


def report_error(message: str) -> None:
    """One plain line on standard error (no rich markup: paths may contain brackets)."""
    _say(f"hoc: error: {message}")


def warn(message: str) -> None:
    """A ``hoc: warning:`` line on standard error, terminal or not (silenced by ``-q``: see run_guarded)."""
    warnings.warn(HocWarning(message), stacklevel=2)


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings as one line on standard error (HocWarning only; others are silenced without --debug)."""
    _say(f"hoc: warning: {message}")


def run_guarded(body: Callable[[], int], debug: bool = False, quiet: bool = False) -> int:
    """Run a command body and map failures to exit codes; tracebacks only with ``debug``.

    SIGTERM and SIGHUP raise :class:`Terminated` and SIGINT ``KeyboardInterrupt`` in the body, once:
    a second signal while the first unwinds (removing temporary files) is ignored. ``quiet``
    silences every warning.
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

    handled = list(TERMINATING)
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:  # not when SIGINT is ignored
        handled.append(signal.SIGINT)
    previous: dict[int, Any] = {}
    try:
        for sig in handled:
            previous[sig] = signal.signal(sig, _on_signal)
    except ValueError:  # not in the main thread (e.g. some test runners)
        pass
    _files._committed.clear()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always" if debug else "ignore")
            warnings.simplefilter("ignore" if quiet else "always", HocWarning)
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
        report_error(f"interrupted; {what_changed()}")
        return EXIT_SIGINT
    except Terminated as exc:
        report_error(f"{_SIGNAL_WORDS.get(exc.signum, f'signal {exc.signum}')}; {what_changed()}")
        return 128 + exc.signum
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def load_model(task, *, urdf_label: str | None = None, task_label: str | None = None):
    """``load_robot`` for a task; a ``joints``/``locked``/``gravity`` misfit blames the task key.

    ``urdf_label`` and ``task_label`` are what messages call the URDF and the task file (default:
    their paths), e.g. ``plan.mcap: attachment robot.urdf`` for a plan's attached files.
    """
    from hoc_cli.model import load_robot

    try:
        return load_robot(task.robot, joints=list(task.joints) if task.joints else None, locked=task.locked,
                          gravity=task.gravity, label=urdf_label)
    except JointSelectionError as exc:
        named = exc.key == exc.task_key or exc.task_key.startswith("locked.")  # the key names the joint
        raise TaskError(exc.detail if named else f"{exc.key}: {exc.detail}",
                        file=task_label or task.path, key=exc.task_key) from None


def check_columns(targets: list[OutputTarget], joints) -> None:
    """Before any work: every joint name can be a CSV column when a CSV output is asked for."""
    from hoc_cli.io.csv import column_problem

    csv = [t for t in targets if t.kind == "csv"]
    if not csv:
        return
    for name in joints:
        problem = column_problem(name)
        if problem:
            raise OutputError(f"joint name {name!r} cannot be a CSV column ({problem}); write only an .mcap "
                              "output, or rename the joint", file=csv[0].label, key="--output")


def check_sample_times(targets: list[OutputTarget], T: float, rate: float, *, file, key: str = "output.rate") -> None:
    """Before any work: MCAP outputs stamp samples in whole nanoseconds, so no two may share one."""
    import numpy as np

    from hoc_cli.io.mcap import time_ns
    from hoc_cli.trajectory import sample_times

    if not any(t.kind == "mcap" for t in targets):
        return
    ns = time_ns(sample_times(T, rate))
    if ns.size > 1 and not np.all(np.diff(ns) > 0):
        if rate > 1e9:
            why = f"{rate:g} Hz puts samples less than 1 ns apart"
        else:
            why = f"T = {float(T)!r} s leaves the last sample within 1 ns of the one before it"
        raise TaskError(f"{why}, and MCAP time stamps are whole nanoseconds (expected a rate <= 1e9 Hz and "
                        "T not within 1 ns of a multiple of 1/rate)", file=file, key=key)


def read_urdf_text(path: Path, label: str | None = None) -> str:
    """The URDF document as text (stored in MCAP outputs), read before any work is done."""
    try:
        return Path(path).read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise InputFileError("is not UTF-8 text (hoc stores the URDF in its MCAP outputs as UTF-8)",
                             file=label or path) from None
    except OSError as exc:
        raise InputFileError(f"cannot be read ({exc.strerror or type(exc).__name__})", file=label or path) from None


def warn_limit_violations(violations: list[dict]) -> None:
    """One warning line per limit broken (standard error, terminal or not; silenced by ``-q``)."""
    def show(x) -> str:
        return "none" if x is None else f"{x:.4g}"

    for v in violations:
        limit = v.get("limit", ())
        if isinstance(limit, list):
            limit = f"[{', '.join(show(x) for x in limit)}]"
        elif limit != ():
            limit = show(limit)
        where = f" at t = {v['t']:.4g} s" if "t" in v else ""
        said = f" {limit}" if limit != () else ""
        warn(f"joint {v['joint']!r} exceeds its {v['kind']} limit{said}: worst {v['worst']:.4g}{where}")


def json_ready(obj: Any) -> Any:
    """``obj`` with every non-finite float (an absent limit is ±inf) as None, ready for strict JSON."""
    if isinstance(obj, dict):
        return {k: json_ready(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_ready(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    try:
        import numpy as np
    except ImportError:  # pragma: no cover
        return obj
    if isinstance(obj, np.ndarray):
        return json_ready(obj.tolist())
    if isinstance(obj, np.floating) and not np.isfinite(obj):
        return None
    return obj


def validate_json(obj: Any) -> str:
    """Strict JSON text of ``obj`` (raises before any output is written if it cannot be serialised)."""
    return json.dumps(obj, indent=2, allow_nan=False, default=_jsonable)


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
