"""docs/api.md: every Python block runs as printed, in order, from the repository's root, and
``hoc_cli.solve`` gives the CLI's answer on the same task."""
from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

ROOT = Path(__file__).resolve().parents[1]


def blocks() -> list[str]:
    text = (ROOT / "docs" / "api.md").read_text(encoding="utf-8")
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def test_the_api_page_has_an_example_per_goal_kind():
    code = "\n".join(blocks())
    for needle in ("q1=", "Free(", "link_goal(", "joint_via(", "link_via(", "match_velocity=True", "WarmStart(",
                   "N=None", "jerk="):
        assert needle in code, needle


def test_every_example_of_the_api_page_runs_as_printed(monkeypatch):
    monkeypatch.chdir(ROOT)
    namespace: dict = {}
    runnable = [b for b in blocks() if not b.lstrip().startswith("OptimalControlProblem(system")]  # the signature
    assert len(runnable) >= 6
    for i, block in enumerate(runnable):
        try:
            exec(compile(block, f"docs/api.md block {i}", "exec"), namespace)
        except Exception as exc:  # the failing block in the report
            pytest.fail(f"docs/api.md block {i} failed: {exc!r}\n{block}")


def test_solve_from_python_gives_the_cli_answer_on_a_shipped_free_time_task(tmp_path):
    from hoc_cli import Free, JointLimits, OptimalControlProblem, RobotSystem, load_robot, solve
    from hoc_cli.cli import app

    r = CliRunner().invoke(app, ["plan", str(ROOT / "configs" / "two_link_free_time.yaml"), "-o", "none", "--json",
                                 "-q"])
    cli = json.loads(r.stdout)
    model = load_robot(ROOT / "robots" / "two_link.urdf")
    problem = OptimalControlProblem(RobotSystem(model), q0=[0.0, 0.0], dq0=[0.0, 0.0], q1=[1.2, -0.6],
                                    time=Free(0.5, 3.0, weight=20.0, guess=1.5), N=16,
                                    limits=JointLimits.from_model(model))
    plan = solve(problem)
    assert plan.J == cli["cost"] and plan.T == cli["T"]
