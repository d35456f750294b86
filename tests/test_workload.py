"""The work estimate of ``hoc plan`` (issue 12, item 12): heavy runs are announced before the solve,
light ones are not; ``--progress`` reports at least every few seconds (``Heartbeat``)."""
import io
import shutil
import threading
import time
from pathlib import Path

import pytest
from rich.console import Console
from typer.testing import CliRunner

from hoc_cli.cli import app
from hoc_cli.commands import plan as plan_cmd
from hoc_cli.errors import OutputError
from hoc_cli.io.robot import load_model
from hoc_cli.io.task import load_task
from hoc_cli.report.workload import WARN_BYTES, WARN_SECONDS, Heartbeat, estimate_workload
from tests._robots import task_configs

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = task_configs()  # the hoc catch scenario is not a task


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.stem)
def test_the_shipped_tasks_are_light(path):
    """Every shipped task runs in seconds (measured: 0.8 to 3.7 s): none may be announced as heavy."""
    task = load_task(path, purpose="plan")
    work = estimate_workload(n=load_model(task).n, N=task.N, order=task.order, T=task.T, rate=task.rate, csv=1, mcap=1,
                             max_iter=task.max_iter)
    assert not work.heavy and work.seconds < 5 and work.bytes < 200e6


def test_the_heavy_runs_of_the_issue_are_heavy():
    """N = 100 000 on two_link (peak 11.8 GB, issue 24) and a 150-DOF chain at N = 8 (> 300 s)."""
    big_n = estimate_workload(n=2, N=100_000, order="quintic", T=1.5, rate=100)
    assert big_n.heavy and big_n.seconds > 30 and big_n.bytes > WARN_BYTES
    chain = estimate_workload(n=150, N=8, order="quintic", T=1.5, rate=100)
    assert chain.heavy and chain.seconds > 300
    # many output samples alone (measured: 150 001 samples to CSV and MCAP took 26 s)
    samples = estimate_workload(n=2, N=16, order="quintic", T=1.5, rate=100_000, csv=1, mcap=1)
    assert samples.heavy and samples.seconds > WARN_SECONDS
    assert not estimate_workload(n=2, N=16, order="quintic", T=1.5, rate=100_000).heavy  # -o none writes nothing


def test_the_estimate_grows_with_every_input():
    base = dict(n=7, N=64, order="quintic", T=2.0, rate=100, csv=1, mcap=1)
    w0 = estimate_workload(**base)
    for key, value in (("n", 14), ("N", 128), ("rate", 1000), ("mcap", 2), ("starts", 4)):
        w = estimate_workload(**base | {key: value})
        assert w.seconds > w0.seconds, key
    assert estimate_workload(**base | {"N": 128}).bytes > w0.bytes
    assert estimate_workload(**base | {"order": "cubic"}).seconds < w0.seconds  # fewer Gauss points
    # the iteration limit caps the work: --max-iter 1 on N = 100 000 is far lighter than the full solve
    capped = estimate_workload(n=2, N=100_000, order="quintic", T=1.5, rate=100, max_iter=1)
    assert capped.seconds < 0.6 * estimate_workload(n=2, N=100_000, order="quintic", T=1.5, rate=100).seconds


@pytest.fixture
def task(tmp_path, monkeypatch):
    shutil.copy(ROOT / "robots" / "two_link.urdf", tmp_path / "two_link.urdf")
    text = (ROOT / "configs" / "two_link.yaml").read_text().replace("../robots/two_link.urdf", "two_link.urdf")
    p = tmp_path / "arm.yaml"
    p.write_text(text)
    monkeypatch.chdir(tmp_path)
    return p


@pytest.fixture
def no_solve(monkeypatch):
    """``hoc plan`` stops where the solve would start (exit 2): the warning must come before it."""
    calls = []

    def stop(*args, **kwargs):
        calls.append(time.perf_counter())
        raise OutputError("stopped by the test before the solve")

    monkeypatch.setattr(plan_cmd, "solve", stop)
    return calls


def test_a_huge_task_is_announced_before_the_solve(task, no_solve):
    start = time.perf_counter()
    r = CliRunner().invoke(app, ["plan", str(task), "-N", "100000", "-o", "none"])
    assert r.exit_code == 2 and no_solve, r.output  # the solve was reached, after the warning
    assert no_solve[0] - start < 5
    warning = [line for line in r.stderr.splitlines() if line.startswith("hoc: warning: ")]
    assert len(warning) == 1 and "expected to take about" in warning[0] and "N = 100000 elements" in warning[0]
    assert "GB of memory" in warning[0]
    quiet = CliRunner().invoke(app, ["plan", str(task), "-N", "100000", "-o", "none", "-q"])
    assert quiet.exit_code == 2 and "warning" not in quiet.stderr


def test_a_small_task_is_not_announced(task, no_solve):
    r = CliRunner().invoke(app, ["plan", str(task), "-o", "none"])
    assert r.exit_code == 2 and no_solve and "warning" not in r.stderr


def test_a_small_task_runs_without_warning_and_reports_its_steps(task):
    r = CliRunner().invoke(app, ["plan", str(task), "-N", "8", "-o", "none", "--progress"])
    assert r.exit_code == 0 and "warning" not in r.stderr
    assert "estimating the error of J (solves on 16 elements)" in r.stderr


def _console() -> tuple[Console, io.StringIO]:
    out = io.StringIO()
    return Console(file=out, width=200, highlight=False), out


def test_heartbeat_reports_a_long_silent_step():
    console, out = _console()
    beat = Heartbeat(console, True, interval=0.2)
    with beat.phase("writing x.csv"):
        time.sleep(0.75)
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("writing x.csv ")
    assert 1 <= sum(line.startswith("still writing x.csv ") for line in lines) <= 4  # at 0.2, 0.4, 0.6 s
    assert not any(t.name == "hoc-heartbeat" for t in threading.enumerate())  # the thread ends with the block


def test_heartbeat_stays_quiet_while_other_progress_is_reported():
    console, out = _console()
    beat = Heartbeat(console, True, interval=1.0)
    with beat:
        for i in range(8):
            beat.tick(f"solving (after iteration {i})")
            time.sleep(0.05)
    assert out.getvalue() == ""


def test_heartbeat_disabled_starts_no_thread():
    console, out = _console()
    beat = Heartbeat(console, False, interval=0.01)
    with beat.phase("writing"):
        assert not any(t.name == "hoc-heartbeat" for t in threading.enumerate())
        time.sleep(0.05)
    assert out.getvalue() == ""


def test_a_run_that_outlasts_an_estimate_under_the_threshold_is_announced_once_when_it_does(task, monkeypatch):
    """Issue 24: runs of 12-88 s started silently (their iteration count is not predictable): the plan
    says so once it has run WARN_SECONDS (here lowered to 0.3 s) without a warning before it."""
    monkeypatch.setattr(plan_cmd, "WARN_SECONDS", 0.3)
    r = CliRunner().invoke(app, ["plan", str(task), "-N", "1000", "-o", "none"])  # about 1 s
    late = [line for line in r.stderr.splitlines() if "longer than its estimate" in line]
    assert r.exit_code == 0 and len(late) == 1 and late[0].startswith("hoc: warning: this run has taken")
    quick = CliRunner().invoke(app, ["plan", str(task), "-o", "none"])  # under 0.3 s of solving: nothing
    assert quick.exit_code == 0 and "warning" not in quick.stderr


def test_the_estimate_follows_the_issue_24_measurements():
    """Measured with /usr/bin/time -v (docs/design.md, "Work estimate"): 30-DOF Talos at N = 16 took
    20-23 s and 306 MB; two_link at N = 8000 11.9 s and 1034 MB; N = 100 000 peaked at 11.8 GB."""
    talos = estimate_workload(n=30, N=16, order="quintic", T=2.0, rate=100)
    assert talos.heavy and 20 <= talos.seconds <= 120 and 200e6 <= talos.bytes <= 400e6
    mid = estimate_workload(n=2, N=8000, order="quintic", T=1.5, rate=100)
    assert mid.heavy and 0.8e9 <= mid.bytes <= 1.3e9
    assert 9e9 <= estimate_workload(n=2, N=100_000, order="quintic", T=1.5, rate=100).bytes <= 14e9


def test_starts_on_a_local_cluster_are_estimated_in_parallel():
    base = dict(n=7, N=64, order="quintic", T=2.0, rate=100)
    one = estimate_workload(**base).seconds
    serial = estimate_workload(**base, starts=200, cores=1).seconds
    parallel = estimate_workload(**base, starts=200, cores=2).seconds
    assert serial == pytest.approx(200 * (one - 0.6) + 0.6) and parallel < 0.6 * serial
    assert "200 starts" in estimate_workload(**base, starts=200).describe()
