"""``hoc plot``: being built (see the issue tracker)."""
from __future__ import annotations

from hoc_cli.errors import HocError


def run(*args, **kwargs) -> int:
    raise HocError("'hoc plot' is not available in this build yet")
