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


REFERENCE = ROOT / "docs" / "reference.md"


def documented_statuses(text: str) -> dict[str, list[str]]:
    """The rows of docs/reference.md's "Status values" table: status value -> its cells after the first."""
    section = text.split("## Status values", 1)[1].split("\n## ", 1)[0]
    rows = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("| `") and len(cells) == 6:
            rows[cells[0].strip("`")] = cells[1:]
    return rows


def test_every_status_is_documented_with_its_exit_code_and_words():
    rows = documented_statuses(REFERENCE.read_text(encoding="utf-8"))
    assert set(rows) == {s.value for s in Status}, "docs/reference.md's Status values table is not the enum"
    for status in Status:
        meaning, code, word, kept, counted = rows[status.value]
        assert meaning and (code == "0") == (status is Status.CONVERGED), status
        assert (word, kept, counted) == (MESSAGES[status].word, MESSAGES[status].kept, MESSAGES[status].counted)


def test_the_status_table_check_sees_a_missing_row():
    text = REFERENCE.read_text(encoding="utf-8")
    rows = documented_statuses(text)
    assert rows["infeasible"][1:] == ["1", "infeasible", "the least-violating plan", "not converged"]
    without = "\n".join(line for line in text.splitlines() if not line.startswith("| `goal_missed`"))
    assert set(documented_statuses(without)) == {s.value for s in Status} - {"goal_missed"}
