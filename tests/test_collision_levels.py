"""How a collision plan's levels are solved: the full level's Gauss points."""
from __future__ import annotations

import pytest
from _collision_tasks import plan, task_folder

import hoc_cli.planner as planner
from tests.test_collision_enforce import BALL, two_link


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    return task_folder(tmp_path, monkeypatch, ("two_link.urdf",))


def test_a_collision_plan_starts_its_full_level_at_four_more_gauss_points_in_the_same_plan(workdir, monkeypatch):
    """The two-link arm round the ball (N = 16) passes the quadrature check at the default 8 points too: 12 give the
    same plan (J to 1e-12) in the same number of evaluations, and no plan is solved again for its quadrature."""
    r, s = plan(workdir, two_link([BALL], N=16))
    monkeypatch.setattr(planner, "CONSTRAINT_EXTRA_G", 0)
    r0, s0 = plan(workdir, two_link([BALL], N=16))
    assert r.exit_code == 0 and r0.exit_code == 0
    assert (s["gauss_points"], s0["gauss_points"]) == (12, 8)
    assert s["cost"] == pytest.approx(s0["cost"], rel=1e-12) and s["evaluations"] == s0["evaluations"]
