"""Command-line values converted without building a pydantic adapter per parameter (start-up time).

typer converts every parameter's value, given or not, through a pydantic ``TypeAdapter`` built for
that parameter: importing pydantic and building the adapters of ``hoc plan``'s options costs
about a quarter of a plain plan's start-up. ``install`` wraps typer's ``build_runtime_param`` so
that the values hoc's options take (``str``, ``int``, ``float``, ``Path`` and lists of them) are
converted directly when they are written the plain way (``12``, ``-3``, ``0.5``, ``1e-8``, a
path); anything else (a value typer would refuse, an exotic spelling, another type) goes to
typer's own conversion, which gives its own result and error message. The result is the same
either way: ``tests/test_option_values.py`` checks each plain spelling against typer's.
"""
from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path
from typing import Any, get_args, get_origin

_INT = re.compile(r"[+-]?(?:0|[1-9][0-9]{0,17})")
_FLOAT = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]{1,3})?")


class Unplain(Exception):
    """A value not written the plain way: typer's own conversion decides."""


def plain_value(annotation: Any, value: Any, *, minimum=None, maximum=None) -> Any:
    """``value`` (a command-line string) as ``annotation`` (str, int, float or Path); ``Unplain`` unless the
    value is written the plain way and within [``minimum``, ``maximum``] (None: no bound).
    """
    if not isinstance(value, str):
        raise Unplain
    if annotation is str:
        return value
    if annotation is int:
        if not _INT.fullmatch(value):
            raise Unplain
        out = int(value)
    elif annotation is float:
        if not _FLOAT.fullmatch(value):
            raise Unplain
        out = float(value)
        if not math.isfinite(out):
            raise Unplain
    elif annotation is Path:
        if value == "" or "\x00" in value:
            raise Unplain
        return Path(value)
    else:
        raise Unplain
    if (minimum is not None and out < minimum) or (maximum is not None and out > maximum):
        raise Unplain
    return out


def install() -> None:
    """Convert plain values of typer parameters directly (see the module docstring); typer versions without
    the hook (``typer.core.build_runtime_param``) are left as they are.
    """
    try:
        from typer import core
        from typer._coercion import RuntimeParam
        from typer._param_types import coerce_cli_path, routes_to_path
    except ImportError:
        return
    full_build = getattr(core, "build_runtime_param", None)
    if full_build is None or getattr(full_build, "hoc_plain", False):
        return
    fields = tuple(f.name for f in dataclasses.fields(RuntimeParam)) if dataclasses.is_dataclass(RuntimeParam) else ()
    if fields != ("parameter_info", "annotation") or not hasattr(RuntimeParam, "_coerce_value"):
        return  # another typer than the one this was written against: its own conversion throughout

    class PlainRuntimeParam(RuntimeParam):
        """typer's ``RuntimeParam`` (its handling of missing values kept) converting plain values itself."""

        def __init__(self, descriptor) -> None:
            super().__init__(parameter_info=descriptor.parameter_info, annotation=descriptor.annotation)
            object.__setattr__(self, "descriptor", descriptor)
            object.__setattr__(self, "full", None)

        def _typer(self):
            if self.full is None:
                object.__setattr__(self, "full", full_build(self.descriptor))
            return self.full

        def _coerce_value(self, value: Any, param, ctx) -> Any:
            info = self.parameter_info
            if info.parser is not None or info.clamp:
                return self._typer()._coerce_value(value, param=param, ctx=ctx)
            try:
                if self.descriptor.is_list:
                    if not isinstance(value, (list, tuple)):
                        raise Unplain
                    item = get_args(self.annotation)[0]
                    return [self._one(item, v, param, ctx) for v in value]
                return self._one(self.annotation, value, param, ctx)
            except Unplain:
                return self._typer()._coerce_value(value, param=param, ctx=ctx)

        def _one(self, annotation, value, param, ctx) -> Any:
            info = self.parameter_info
            out = plain_value(annotation, value, minimum=info.min, maximum=info.max)
            if annotation is Path:  # typer's checks of the path itself (exists, readable, …), without pydantic
                return coerce_cli_path(out, info, path_type=info.path_type or Path, param=param, ctx=ctx)
            return out

    def plain(descriptor) -> bool:
        """Whether the values of this parameter may be converted here: a str, int, float, Path or bool, or a
        list of one, without typer's path checks on a type other than Path, choices or a file to open.
        """
        if descriptor.file_annotation is not None or descriptor.is_tuple or descriptor.is_choice:
            return False
        item = get_args(descriptor.annotation)[0] if descriptor.is_list else descriptor.annotation
        if get_origin(item) is not None or item not in (str, int, float, Path, bool):
            return False  # a bool's missing value (None) is kept here; any other goes to typer
        return (item is Path) == bool(routes_to_path(item, descriptor.parameter_info))

    def build_runtime_param(descriptor):
        return PlainRuntimeParam(descriptor) if plain(descriptor) else full_build(descriptor)

    build_runtime_param.hoc_plain = True
    core.build_runtime_param = build_runtime_param
