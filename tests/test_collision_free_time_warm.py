"""A free T with the collision constraint active ends in seconds: each fixed-T plan of the search starts from the
nearest one's multipliers (the collision rows' and the joint limits'), not from zero.

The catch of configs/catch_ball.yaml (T free in [0.3, 0.5] s) over a table with a 3 cm "lamp" that the plain catch
passes within 5 mm of: without the constraint's and the limits' multipliers, a warm-started fixed-T plan's first
limits' round left the rescaled start 9σ over a velocity limit, and the next rounds crawled (one plan ran for minutes).
"""
from __future__ import annotations

import pytest
import yaml
from _collision_tasks import ROOT, plan, task_folder
from test_collision_stall import LAMP, LBR7, TABLE, budget

ITERATIONS = 1500  # inner iterations allowed in all (the search takes about 500)


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    return task_folder(tmp_path, monkeypatch, ("lbr7.urdf",))


def test_the_free_time_catch_past_the_lamp_ends_certified_within_its_limits(workdir, monkeypatch):
    budget(monkeypatch, ITERATIONS)
    doc = yaml.safe_load((ROOT / "configs" / "catch_ball.yaml").read_text())
    doc.pop("output", None)
    doc |= {"N": 8, "collision": {"margin": 0.01, "robot": LBR7, "obstacles": [TABLE, LAMP]}}
    r, s = plan(workdir, doc)
    assert r.exit_code == 0, (r.stderr, r.exception)
    assert s["converged"] and s["collision_active"] and s["T_converged"]
    c = s["min_clearance"]
    assert c["certified"] and c["lower_bound"] >= 0.01 - 1e-9 and c["distance"] < 0.015  # the lamp binds
    assert s["reached"]["position_error"] <= 1e-9 and s["reached"]["velocity_error"] <= 1e-9
    assert s["limit_violations"] == [] and s["active_limits"]
    assert 0.3 < s["T"] < 0.5
