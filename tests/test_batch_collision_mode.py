"""``hoc batch`` rows name the collision mode in effect: ``N: auto`` plans with check where the section's default
enforce cannot apply (``hoc plan`` warns; a batch row says so in ``collision_mode``), a fixed T enforces, and a
task without a ``collision:`` section has no such column."""
from __future__ import annotations

import pytest
import yaml
from _collision_tasks import plan, task_folder

BALL = {"name": "ball", "sphere": {"radius": 0.1}, "position": [1.75, 0, 0.55]}
ARM = {"upper_arm": [{"capsule": {"a": [0, 0, 0], "b": [1, 0, 0], "radius": 0.05}}],
       "forearm": [{"capsule": {"a": [0, 0, 0], "b": [1, 0, 0], "radius": 0.05}}]}


def _task(N) -> dict:
    return {"robot": "../robots/two_link.urdf", "x0": {"q": [0.0, 0.0]}, "x1": {"q": [1.2, -0.6]}, "T": 1.5, "N": N,
            "collision": {"robot": ARM, "obstacles": [BALL]}}


def test_a_batch_row_names_the_collision_mode_in_effect(tmp_path, monkeypatch):
    pytest.importorskip("pyarrow")
    pytest.importorskip("distributed")
    from hoc_cli.batch import execute_batch
    from hoc_cli.batch.engine import connect

    d = task_folder(tmp_path, monkeypatch, ("two_link.urdf",))
    r, single = plan(d, _task("auto"))
    assert r.exit_code == 0 and single["collision_mode"] == "check" and "collision enforcement" in r.stderr
    files = []
    for name, doc in (("fixed.yaml", _task(8)), ("auto.yaml", _task("auto")), ("plain.yaml", {**_task(8), "collision": None})):
        if doc["collision"] is None:
            doc = {k: v for k, v in doc.items() if k != "collision"}
        (d / name).write_text(yaml.safe_dump(doc, sort_keys=False))
        files.append(str(d / name))
    with connect(workers=1) as client:
        run = execute_batch(files, client, out_dir=d / "out")
    rows = {row["task"].rsplit("/", 1)[-1]: row for row in run.table.to_pylist()}
    assert {k: rows[k]["status"] for k in rows} == {"fixed.yaml": "converged", "auto.yaml": "converged", "plain.yaml": "converged"}
    assert rows["fixed.yaml"]["collision_mode"] == "enforce" and rows["auto.yaml"]["collision_mode"] == "check"
    assert rows["plain.yaml"]["collision_mode"] is None and rows["plain.yaml"]["min_clearance"] is None
    assert rows["auto.yaml"]["min_clearance"] == pytest.approx(single["min_clearance"]["distance"], abs=1e-12)
