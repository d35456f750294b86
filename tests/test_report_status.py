"""The one status enum of the reports (``hoc_cli.report.status``): every status a solver reports is one of it,
each has its words, and ``hoc plan`` and ``hoc batch`` say the same of the same plan."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from hoc_cli.cli import app
from hoc_cli.optimize.result import Status as OptimizerStatus
from hoc_cli.report.status import MESSAGES, Status, unmet_line

ROOT = Path(__file__).resolve().parent.parent


def test_every_optimizer_status_and_every_outer_loop_status_is_a_report_status():
    for s in OptimizerStatus:
        assert Status.of(s).value == s.value
    for s in ("converged", "not_converged", "infeasible", "goal_missed", "error"):  # limits, collision, goals, starts
        assert Status.of(s).value == s
    with pytest.raises(ValueError):
        Status.of("stalled")


def test_every_status_has_its_words():
    assert set(MESSAGES) == set(Status)
    assert MESSAGES[Status.INFEASIBLE].word == "infeasible" and MESSAGES[Status.MAX_ITER].word == "not converged"
    assert unmet_line(Status.INFEASIBLE, "x binds", "was written") == \
        "hoc: infeasible: x binds; the least-violating plan was written"
    assert unmet_line(Status.LINE_SEARCH_FAILED, "stuck", "was not written (-o none)") == \
        "hoc: not converged: stuck; the best iterate was not written (-o none)"
    # a converged solver whose constraint loop stopped short is not converged
    assert unmet_line(Status.CONVERGED, "collision", "was written").startswith("hoc: not converged: collision;")


def test_hoc_plan_exit_1_line_comes_from_the_table(tmp_path):
    task = ROOT / "configs" / "two_link.yaml"
    r = CliRunner().invoke(app, ["plan", str(task), "-o", "none", "--json", "--max-iter", "2", "--limits", "report"])
    assert r.exit_code == 1
    summary = json.loads(r.stdout)
    status = Status.of(summary["status"])
    assert status is Status.MAX_ITER and summary["converged"] is False
    assert unmet_line(status, summary["message"], "was not written (-o none)") in r.stderr
