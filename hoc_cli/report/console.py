"""Lines on standard error: ``hoc: error:`` and ``hoc: warning:`` lines, warnings about a plan, the rich console.

Errors and warnings are plain text (no rich markup: paths may contain brackets). ``rich`` is
imported only when a console is made (``stderr_console``).
"""
from __future__ import annotations

import sys
import warnings

from hoc_cli.errors import HocWarning


def say(line: str) -> None:
    """One line on standard error; a closed terminal (SIGHUP, EIO) or pipe is not a second failure."""
    try:
        sys.stderr.write(line + "\n")
        sys.stderr.flush()
    except (OSError, ValueError):
        pass


def report_error(message: str) -> None:
    """One plain line on standard error (no rich markup: paths may contain brackets)."""
    say(f"hoc: error: {message}")


def warn(message: str) -> None:
    """A ``hoc: warning:`` line on standard error, terminal or not (silenced by ``-q``: see
    ``hoc_cli.commands.common.run_guarded``, which shows ``HocWarning`` s with ``show_warning``).
    """
    warnings.warn(HocWarning(message), stacklevel=2)


def show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings as one line on standard error (the ``warnings.showwarning`` of a run)."""
    say(f"hoc: warning: {message}")


class SilentConsole:
    """The console of a ``-q`` run: prints nothing, is no terminal (what a quiet rich ``Console`` does, without
    importing rich).
    """

    quiet = True
    is_terminal = False

    def print(self, *objects, **kwargs) -> None:
        return None


def stderr_console(quiet: bool = False, progress: bool = False):
    """Rich console on standard error; decorated only on a terminal unless ``progress``. With ``quiet`` and
    without ``progress``, a ``SilentConsole`` (nothing would be shown).
    """
    if quiet and not progress:
        return SilentConsole()
    from rich.console import Console

    return Console(stderr=True, quiet=quiet, force_terminal=True if progress else None, highlight=False)


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
