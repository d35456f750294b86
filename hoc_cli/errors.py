"""Exceptions raised by hoc: every user-facing failure is a ``HocError`` subclass.

The CLI turns a ``HocError`` into one line on standard error and exit code 2
(invalid input) or 1 (numerical failure); nothing else should escape to the user
without ``--debug``.
"""
from __future__ import annotations

from pathlib import Path


class HocError(Exception):
    """Base class: a message that names the file, the key (or joint) and what was expected."""

    exit_code: int = 2

    def __init__(self, message: str, *, file: str | Path | None = None, key: str | None = None) -> None:
        self.file = str(file) if file is not None else None
        self.key = key
        self.detail = message
        parts = []
        if self.file:
            parts.append(self.file)
        if key:
            parts.append(key)
        prefix = ": ".join(parts)
        super().__init__(f"{prefix}: {message}" if prefix else message)


def naming_file(fn, file: str | Path):
    """``fn()``, with ``file`` named in a ``HocError`` that names a key but no file (the maths, e.g.
    ``hoc_cli.solve``, knows the task key at fault, not the file it came from); others pass unchanged.
    """
    try:
        return fn()
    except HocError as exc:
        if exc.file is not None or exc.key is None:
            raise
        raise type(exc)(exc.detail, file=file, key=exc.key) from None


class TaskError(HocError):
    """The task YAML (or a CLI override of one of its keys) is invalid."""


class ModelError(HocError):
    """The URDF cannot be turned into a dynamics model (bad joint type, cycle, massless subtree...)."""


class JointSelectionError(ModelError):
    """The task's ``joints``, ``locked`` or ``gravity`` do not fit the URDF.

    ``task_key`` names the task key at fault (``locked.nope``, ``joints[2]``), so that a command can
    blame the task file rather than the URDF (see ``hoc_cli.io.robot.load_model``).
    """

    def __init__(self, message: str, *, file: str | Path | None = None, key: str | None = None,
                 task_key: str) -> None:
        super().__init__(message, file=file, key=key)
        self.task_key = task_key


class OutputError(HocError):
    """An output path cannot be written (missing directory, unknown extension...)."""


class OutputWriteError(OutputError):
    """Writing an output failed while hoc was writing it (disk full, I/O error); nothing was replaced."""

    exit_code = 1


class InputFileError(HocError):
    """A torque file, plan file or warm-start file is unreadable or does not match the task."""


class NumericalError(HocError):
    """The computation failed numerically (NaN cost, singular mass matrix, stalled line search)."""

    exit_code = 1


class Infeasible(HocError):
    """The task is provably infeasible within its limits, found before any solve (exit 1, nothing written).

    ``summary``: the JSON summary of the run (``status: infeasible``, what binds), for ``--json``.
    """

    exit_code = 1

    def __init__(self, message: str, *, file: str | Path | None = None, key: str | None = None,
                 summary: dict | None = None) -> None:
        super().__init__(message, file=file, key=key)
        self.summary = summary or {}


class HocWarning(UserWarning):
    """Something the user should know but that does not stop the run (printed as one line)."""
