"""Value checkers shared by every task section and by the CLI overrides.

Each checker takes the raw value and the key path it came from (``solver.tol``, or an option name
such as ``--tol`` for an override) and returns the validated value or raises a ``TaskError`` whose
message names the file, the key, what was expected and (bounded in size) what was found.
"""
from __future__ import annotations

import math
import reprlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hoc_cli.errors import TaskError
from hoc_cli.io.task.yaml12 import YAML11_NUMBER

Values = list[float] | dict[str, float]
Check = Callable[["Checker", Any, str], Any]  # (checker, raw value, key path) -> validated value

class _Repr(reprlib.Repr):
    """``reprlib.Repr`` that shows a numpy scalar as the Python number it holds (``1.49``, not
    ``np.float64(1.49)``): sweep values and overrides may come from numpy.
    """

    def repr1(self, x: Any, level: int) -> str:
        if type(x).__module__ == "numpy" and hasattr(x, "item") and getattr(x, "ndim", None) == 0:
            x = x.item()
        return super().repr1(x, level)


_REPR = _Repr()
_REPR.maxlevel, _REPR.maxlist, _REPR.maxtuple, _REPR.maxdict = 2, 4, 4, 4
_REPR.maxstring, _REPR.maxlong, _REPR.maxother = 48, 40, 48
SHOW_CHARS = 60
#: no joint position, rate, torque, link position or gravity of a physical task comes near this
#: (rad, m, rad/s, N·m, m/s²...); beyond it the cost overflows or loses every digit
MAX_MAGNITUDE = 1e6
NAME_CHARS = 60  # a joint name or key from the file, as part of a key path


def show(value: Any) -> str:
    """A short repr of ``value`` for an error message: never longer than ``SHOW_CHARS`` characters.

    ``reprlib`` bounds the work too (nesting depth, items per collection, digits), so a value that
    aliases expand to millions of items is never formatted in full.
    """
    try:
        text = _REPR.repr(value)
    except (ValueError, RecursionError):  # e.g. an int past Python's digit limit for str()
        text = f"<{type(value).__name__}>"
    return text if len(text) <= SHOW_CHARS else text[: SHOW_CHARS - 3] + "..."


def join(prefix: str, key: str) -> str:
    """``prefix.key``, or ``key`` at the top level; a key from the file is cut to ``NAME_CHARS``."""
    key = key if len(key) <= NAME_CHARS else key[: NAME_CHARS - 3] + "..."
    return f"{prefix}.{key}" if prefix else key


class Checker:
    """Validators that raise ``TaskError`` naming ``path`` and the key path."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def error(self, key: str | None, message: str) -> TaskError:
        """A ``TaskError`` for this file and key."""
        return TaskError(message, file=self.path, key=key or None)

    def fail(self, key: str, expected: str, got: Any = None, show_got: bool = True) -> TaskError:
        """``key: expected <expected>, got <value>``."""
        msg = f"expected {expected}"
        if show_got:
            msg += f", got {show(got)}"
            if isinstance(got, str) and YAML11_NUMBER.match(got):
                msg += " (text, not a number, in YAML 1.2: no 1:30 sexagesimal, 010 octal (write 0o10) or 1_5 separators)"
        return self.error(key, msg)

    def number(self, value: Any, key: str, *, positive: bool = False, what: str = "a finite number") -> float:
        """A finite float (bools and strings refused); > 0 when ``positive``."""
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(key, what, value)
        try:
            x = float(value)
        except OverflowError:  # an integer beyond the range of a double
            raise self.fail(key, what, value) from None
        if not math.isfinite(x) or (positive and x <= 0):
            raise self.fail(key, what, value)
        return x

    def integer(self, value: Any, key: str, minimum: int, maximum: int | None = None) -> int:
        """An int in [minimum, maximum]; a float with an integer value is accepted."""
        what = f"an integer >= {minimum}" if maximum is None else f"an integer >= {minimum} and <= {maximum}"
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and math.isfinite(value) and value.is_integer():
                value = int(value)
            else:
                raise self.fail(key, what, value)
        if value < minimum or (maximum is not None and value > maximum):
            raise self.fail(key, what, value)
        return int(value)

    def choice(self, value: Any, key: str, choices: tuple[str, ...]) -> str:
        """One of ``choices`` (strings)."""
        if not isinstance(value, str) or value not in choices:
            raise self.fail(key, "one of " + ", ".join(choices), value)
        return value

    def mapping(self, value: Any, key: str, allowed: tuple[str, ...]) -> dict:
        """A mapping whose keys are all in ``allowed`` (an unknown key names itself)."""
        if not isinstance(value, dict):
            raise self.fail(key, f"a mapping with keys {', '.join(allowed)}", value)
        for k in value:
            if k not in allowed:
                raise self.error(join(key, str(k)), f"unknown key {show(k)} (expected one of: {', '.join(allowed)})")
        return value

    def names(self, value: Any, key: str, what: str) -> dict[str, Any]:
        """A mapping with joint names (non-empty strings) as keys; the values are left to the caller."""
        if not isinstance(value, dict):
            raise self.fail(key, what, value)
        for name in value:
            if not isinstance(name, str):
                raise self.fail(key, "joint names (strings) as keys", name)
        return value

    def physical(self, value: Any, key: str, what: str = "a finite number") -> float:
        """A finite float of physical size: |x| <= ``MAX_MAGNITUDE`` (a joint value, a position, a torque)."""
        x = self.number(value, key, what=what)
        if abs(x) > MAX_MAGNITUDE:
            raise self.fail(key, f"{what} of physical size, |value| <= {MAX_MAGNITUDE:g}", x)
        return x

    def values(self, value: Any, key: str, physical: bool = True) -> Values:
        """A list of numbers, a single number, or a mapping joint name -> number; each finite and, with
        ``physical`` (joint positions and rates), of physical size (``physical``).
        """
        check = self.physical if physical else self.number
        if isinstance(value, dict):
            m = self.names(value, key, "a list of numbers or a mapping joint -> number")
            return {name: check(v, join(key, name)) for name, v in m.items()}
        if isinstance(value, (list, tuple)):
            return [check(v, f"{key}[{i}]") for i, v in enumerate(value)]
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return [check(value, key)]
        raise self.fail(key, "a list of numbers or a mapping joint -> number", value)
