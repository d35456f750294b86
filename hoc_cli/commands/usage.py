"""Command-line usage errors as one line: ``hoc: error: <option>: <what was expected>``, exit 2.

typer (click) reports a bad option value, an unknown option or a missing or extra argument with
its usage block and an ``Error:`` line. :class:`OneLineGroup` (the ``hoc`` app's group class) runs
the command line without click's own error display and prints one line instead; ``--help`` and
``hoc`` without arguments still print the usage. The exceptions are recognised by their
attributes (``param``, ``option_name``, ``exit_code``, ``format_message``), so the same code reads
click's exceptions and the ones typer ships with its own copy of click.
"""
from __future__ import annotations

import sys
from typing import Any

import typer.core

from hoc_cli.commands.common import EXIT_INPUT, EXIT_UNMET
from hoc_cli.report.console import report_error

_EXPECTED_PREFIXES = ("Input should be ", "Value should be ")


def _usage_exceptions() -> tuple[type[BaseException], ...]:
    """The exception bases of click's command-line errors: typer's vendored copy and/or click's."""
    found: list[type[BaseException]] = [typer.Abort]
    base = getattr(typer, "TyperException", None)  # typer >= 0.2x: its own click
    if isinstance(base, type):
        found.append(base)
    click = sys.modules.get("click")  # only a click already loaded can raise (importing it costs 80 ms of start-up)
    if click is not None:
        found += [click.ClickException, click.Abort]
    return tuple(found)


def _param_name(param: Any) -> str:
    """How the user wrote a parameter: the longest ``--option`` name, or an argument's metavar."""
    opts = [o for o in (getattr(param, "opts", None) or []) if o.startswith("-")]
    if opts:
        return max(opts, key=len)
    metavar = getattr(param, "metavar", None)
    if metavar:
        return str(metavar)
    return str(getattr(param, "name", "") or "argument").upper()


def _expected(message: str) -> str:
    """A library message ("Input should be greater than or equal to 1") as "expected …" text."""
    text = message.strip().rstrip(".")
    for prefix in _EXPECTED_PREFIXES:
        if text.startswith(prefix):
            return "expected " + text[len(prefix):]
    return text[:1].lower() + text[1:]


_KINDS = {int: "an integer", float: "a number", str: "a text value"}


def _wanted(param: Any) -> str | None:
    """What a parameter takes, from its type and range ("an integer >= 1"); None when unknown."""
    annotation = getattr(getattr(param, "type_descriptor", None), "annotation", None)
    click_type = getattr(param, "type", None)
    if annotation is None and click_type is not None:  # click's own types (older typer)
        annotation = {"integer": int, "float": float}.get(getattr(click_type, "name", ""), None)
    kind = _KINDS.get(annotation) if isinstance(annotation, type) else None
    if kind is None:
        return None
    lo = getattr(param, "min", None)
    hi = getattr(param, "max", None)
    if lo is None and hi is None and click_type is not None:
        lo, hi = getattr(click_type, "min", None), getattr(click_type, "max", None)
    bounds = [f">= {lo}" if lo is not None else "", f"<= {hi}" if hi is not None else ""]
    return " and ".join([kind + (" " + bounds[0] if bounds[0] else "")] + ([bounds[1]] if bounds[1] else []))


def _command(exc: BaseException, default: str) -> str:
    ctx = getattr(exc, "ctx", None)
    return getattr(ctx, "command_path", None) or default


def usage_line(exc: BaseException, command: str = "hoc") -> str:
    """The one-line message for a command-line error (without the ``hoc: error:`` prefix); ``command``
    names the command when the exception does not (click's parser raises some without a context).
    """
    command = _command(exc, command)
    see = f"see {command} --help"
    name = type(exc).__name__
    param = getattr(exc, "param", None)
    message = str(getattr(exc, "message", "") or exc)
    if name == "MissingParameter":
        what = "argument" if getattr(param, "param_type_name", "") == "argument" else "option"
        return f"{_param_name(param) if param is not None else what}: missing {what} ({see})"
    if name == "NoSuchOption":
        option = getattr(exc, "option_name", "") or "option"
        maybe = sorted(getattr(exc, "possibilities", None) or [])
        hint = f"did you mean {' or '.join(maybe)}? " if maybe else ""
        return f"{option}: no such option of {command} ({hint}{see})"
    if param is not None or getattr(exc, "param_hint", None):
        hint = getattr(exc, "param_hint", None)
        label = _param_name(param) if param is not None else (hint if isinstance(hint, str) else " / ".join(hint))
        wanted = _wanted(param) if param is not None else None
        return f"{label}: {'expected ' + wanted if wanted else _expected(message)} ({see})"
    option = getattr(exc, "option_name", None)
    if option:
        return f"{option}: {_expected(message)} ({see})"
    if name == "UsageError" and message.startswith("No such command"):
        return f"{command}: {_expected(message)} (expected one of the commands in hoc --help)"
    return f"{command}: {_expected(message)} ({see})"


class OneLineGroup(typer.core.TyperGroup):
    """The ``hoc`` command group: usage errors as one ``hoc: error:`` line (exit 2), never a usage block."""

    def main(self, args: Any = None, prog_name: str | None = None, complete_var: str | None = None,
             standalone_mode: bool = True, **extra: Any) -> Any:
        errors = _usage_exceptions()
        words = list(sys.argv[1:] if args is None else args)
        sub = next((w for w in words if not w.startswith("-")), None)
        command = f"hoc {sub}" if sub in self.commands else "hoc"
        try:
            code = super().main(args=words, prog_name=prog_name or "hoc", complete_var=complete_var,
                                standalone_mode=False, **extra)
        except errors as exc:  # type: ignore[misc]
            code = self._report(exc, command)
        if not standalone_mode:
            return code
        sys.exit(code if isinstance(code, int) else 0)

    @staticmethod
    def _report(exc: BaseException, command: str) -> int:
        name = type(exc).__name__
        if name == "NoArgsIsHelpError":  # `hoc` alone: the help, as before
            exc.show()  # type: ignore[attr-defined]
            return int(getattr(exc, "exit_code", EXIT_INPUT))
        if name == "Abort":
            report_error("aborted")
            return EXIT_UNMET
        code = int(getattr(exc, "exit_code", EXIT_INPUT))
        if code == EXIT_INPUT:
            report_error(usage_line(exc, command))
        else:
            format_message = getattr(exc, "format_message", None)
            report_error(format_message() if callable(format_message) else str(exc))
        return code
