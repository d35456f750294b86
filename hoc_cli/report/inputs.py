"""What ``hoc plan`` and ``hoc batch`` check before a solve, each failure one ``hoc: error:`` line.

``check_columns``, ``check_sample_times`` and ``read_urdf_text`` make sure every requested
output can be written before any work is done; ``check_starts`` checks a multi-start request.
"""
from __future__ import annotations

from pathlib import Path

from hoc_cli.errors import InputFileError, OutputError, TaskError
from hoc_cli.report.files import OutputTarget

#: the most starts of one multi-start solve (each is a whole solve; beyond a few dozen they rarely find a
#: better optimum, and a count like 10^6 would only keep the machine busy for days)
MAX_STARTS = 1000


def check_columns(targets: list[OutputTarget], joints) -> None:
    """Before any work: every joint name can be a CSV column when a CSV output is asked for."""
    csv = [t for t in targets if t.kind == "csv"]
    if not csv:
        return
    from hoc_cli.io.csv import column_problem

    for name in joints:
        problem = column_problem(name)
        if problem:
            raise OutputError(f"joint name {name!r} cannot be a CSV column ({problem}); write only an .mcap "
                              "output, or rename the joint", file=csv[0].label, key="--output")


def check_sample_times(targets: list[OutputTarget], T: float, rate: float, *, file, key: str = "output.rate") -> None:
    """Before any work: MCAP outputs stamp samples in whole nanoseconds, so no two may share one."""
    if not any(t.kind == "mcap" for t in targets):
        return
    import numpy as np

    from hoc_cli.io.mcap import time_ns
    from hoc_cli.trajectory import sample_times

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


def check_starts(starts: int, seed: int, init: Path | None, key: str = "--starts") -> None:
    """Refuse a starts count < 1 or > MAX_STARTS, a seed < 0, and multi-start with --init (TaskError, exit 2);
    ``key`` names where ``starts`` came from.
    """
    if isinstance(starts, bool) or not isinstance(starts, int) or not 1 <= starts <= MAX_STARTS:
        raise TaskError(f"expected an integer from 1 to {MAX_STARTS}, got {starts!r}", key=key)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise TaskError(f"expected an integer >= 0, got {seed!r}", key="--seed")
    if starts > 1 and init is not None:
        raise TaskError("multi-start cannot be combined with --init (a warm start is a single start)", key=key)
