"""Shared by the collision CLI tests: a working folder laid out as the repository (configs/ beside robots/),
and ``hoc plan`` of a task document written into it."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import yaml
from typer.testing import CliRunner

from hoc_cli.cli import app

ROOT = Path(__file__).resolve().parents[1]


def task_folder(tmp_path: Path, monkeypatch, urdfs: tuple[str, ...]) -> Path:
    """``tmp_path/configs`` (the current directory) beside ``tmp_path/robots`` holding copies of ``urdfs``."""
    (tmp_path / "configs").mkdir()
    (tmp_path / "robots").mkdir()
    for urdf in urdfs:
        shutil.copy(ROOT / "robots" / urdf, tmp_path / "robots" / urdf)
    monkeypatch.chdir(tmp_path / "configs")
    return tmp_path / "configs"


def plan(d: Path, doc: dict, *extra: str):
    """``hoc plan task.yaml --json -o out.csv`` of ``doc`` written to ``d``: (the CLI result, its JSON or None)."""
    (d / "task.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    r = CliRunner().invoke(app, ["plan", "task.yaml", "--json", "-o", "out.csv", *extra])
    return r, (json.loads(r.stdout) if r.stdout.strip().startswith("{") else None)
