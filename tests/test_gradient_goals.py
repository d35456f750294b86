"""``hoc plan --check-gradient`` on tasks with goals (hoc_cli/commands/gradient_goals.py): the cost gradient
with the free final state, the goal rows' Jacobian, ∂J/∂T and the rows' ∂c/∂T against central differences; each
part catches a 0.1 % error in its own derivative."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from hoc_cli.cli import app

CATCH = Path(__file__).resolve().parents[1] / "configs" / "catch_ball.yaml"


def check(tmp_path, monkeypatch, *extra):
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(app, ["plan", str(CATCH), "--check-gradient", "--json", "-N", "2", *extra])
    return r.exit_code, json.loads(r.stdout)["gradient_check"]


def test_the_catch_passes_every_part_and_writes_nothing(tmp_path, monkeypatch):
    code, c = check(tmp_path, monkeypatch)
    assert code == 0 and c["passed"] is True
    assert set(c["parts"]) == {"cost", "goal_rows", "dJ_dT", "goal_rows_dT"}
    assert all(p["max_rel_error"] <= 1e-6 for p in c["parts"].values())
    assert c["parts"]["cost"]["coordinates"] == c["parts"]["cost"]["of"] > 0
    assert not list(tmp_path.iterdir())


def _scaled(fn, which: int):
    def wrong(*a, **k):
        out = list(fn(*a, **k))
        out[which] = 1.001 * out[which]
        return tuple(out)
    return wrong


@pytest.mark.parametrize("part", ["goal_rows", "dJ_dT", "goal_rows_dT"])
def test_a_wrong_derivative_fails_its_part(tmp_path, monkeypatch, part):
    import hoc_cli.commands.gradient_goals as gg
    from hoc_cli.goals.residuals import FrameResidual
    from hoc_cli.goals.terms import GoalTerms

    if part == "goal_rows":  # ∂c/∂q of the link's target rows 0.1 % off
        monkeypatch.setattr(FrameResidual, "batch", _scaled(FrameResidual.batch, 1))
    elif part == "dJ_dT":
        monkeypatch.setattr(gg, "cost_time_derivative", _scaled(gg.cost_time_derivative, 0))
    else:
        monkeypatch.setattr(GoalTerms, "time_derivative", _scaled(GoalTerms.time_derivative, 0))
    code, c = check(tmp_path, monkeypatch)
    assert code == 1 and c["passed"] is False
    assert c["worst"] == part and 1e-4 < c["parts"][part]["max_rel_error"] < 1e-2

