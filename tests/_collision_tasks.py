"""Shared by the collision CLI tests: a working folder laid out as the repository (configs/ beside robots/),
and ``hoc plan`` of a task document written into it."""
from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
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


def coal_two_link(csv_path: Path, obstacle: dict) -> float:
    """The smallest signed distance, forearm and upper arm against the obstacle, at every CSV sample, by coal and
    Pinocchio (independent of hoc's collision code)."""
    coal = pytest.importorskip("coal")
    pin = pytest.importorskip("pinocchio")
    model = pin.buildModelFromUrdf(str(ROOT / "robots" / "two_link.urdf"))
    data = model.createData()
    rows = list(csv.DictReader(csv_path.open()))
    qs = np.array([[float(r["q.shoulder"]), float(r["q.elbow"])] for r in rows])
    along_x = pin.SE3(np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]]), np.array([0.5, 0, 0]))  # coal's z to x
    capsule = coal.Capsule(0.05, 1.0)
    if "sphere" in obstacle:
        shape = coal.Sphere(obstacle["sphere"]["radius"])
    else:
        shape = coal.Box(*obstacle["box"]["size"])
    place = coal.Transform3s(np.eye(3), np.array(obstacle["position"], float))
    req = coal.DistanceRequest()
    req.enable_signed_distance = True
    worst = np.inf
    for q in qs:
        pin.framesForwardKinematics(model, data, q)
        for link in ("upper_arm", "forearm"):
            M = data.oMf[model.getFrameId(link)] * along_x
            res = coal.DistanceResult()
            coal.distance(capsule, coal.Transform3s(M.rotation, M.translation), shape, place, req, res)
            worst = min(worst, res.min_distance)
    return worst
