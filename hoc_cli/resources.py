"""Where the robots shipped with hoc live: ``robots/`` in a source checkout, or
``<prefix>/share/hoc/robots`` in an installed package (pyproject's data-files).
"""
from __future__ import annotations

import sys
import sysconfig
from pathlib import Path


def shipped_robot(name: str) -> Path | None:
    """Path of a shipped URDF (e.g. "pendulum.urdf"), or None if it cannot be found."""
    candidates = [Path(__file__).resolve().parent.parent / "robots",
                  Path(sys.prefix) / "share" / "hoc" / "robots",
                  Path(sysconfig.get_paths()["data"]) / "share" / "hoc" / "robots"]
    for folder in candidates:
        path = folder / name
        if path.is_file():
            return path
    return None
