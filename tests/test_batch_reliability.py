"""Issue 24, sections 2 and 3: `hoc batch` and multi-start never hang, can always be stopped, never mix results.

- ``--scheduler`` at something that is not a Dask scheduler (a plain TCP listener that says
  nothing, an HTTP server, a service that sends its own banner, a closed port, not an address):
  one line, exit 2, within ``--connect-timeout``, nothing written.
- Absurd counts (``--workers``, ``--starts``, a spec's ``starts``) are refused before any process starts.
- Spec key mistakes are refused before a cluster starts; so are output folders that cannot be written.
- ``--resume`` refuses another spec's results and a table hoc did not write.
- One batch per results folder (a lock); two ``hoc plan`` runs writing the same files leave one run's set.
- SIGINT, SIGTERM and SIGHUP during a local cluster's start and during ``--starts``: the exit code
  of the signal, no worker process left, nothing written.
- The work estimate warns before a long batch.

Clusters are started only where the behaviour needs one (a few seconds each, one worker).
"""
from __future__ import annotations

import http.server
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from hoc_cli.cli import app

pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")
pytest.importorskip("distributed")
psutil = pytest.importorskip("psutil")

ROOT = Path(__file__).resolve().parent.parent
URDF = ROOT / "robots" / "two_link.urdf"


def hoc_command() -> list[str]:
    script = Path(sys.executable).with_name("hoc")
    if script.is_file() and os.access(script, os.X_OK):
        return [str(script)]
    return [sys.executable, "-c", "from hoc_cli.cli import app; app()"]


def run_hoc(*args, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run(hoc_command() + [str(a) for a in args], capture_output=True, text=True, timeout=timeout)


def invoke(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def write_base(d: Path, N: int = 6, T: float = 1.5) -> Path:
    base = d / "arm.yaml"
    base.write_text(f"robot: {URDF}\nx0: {{q: [0.0, 0.0]}}\nx1: {{q: [1.2, -0.6]}}\nT: {T}\nN: {N}\n"
                    "output: {rate: 20}\n")
    return base


def write_spec(d: Path, sweep: str = "T: [1.0, 1.5]", name: str = "sweep.yaml", extra: str = "") -> Path:
    write_base(d)
    spec = d / name
    spec.write_text(f"base: arm.yaml\nsweep:\n  {sweep}\n{extra}")
    return spec


def one_error_line(stderr: str) -> str:
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("hoc: error: "), stderr
    assert "Traceback" not in stderr and "Exception ignored" not in stderr
    return lines[0]


@pytest.fixture
def no_cluster(monkeypatch):
    """In-process runs: fail the test if a cluster or scheduler connection is attempted."""
    def refuse(*args, **kwargs):
        raise AssertionError("a cluster was started")

    monkeypatch.setattr("hoc_cli.batch.engine.connect", refuse)


# --- --scheduler: nothing hangs -----------------------------------------------------------------

class _Listener:
    """A TCP service on loopback: ``silent`` accepts and says nothing; ``banner`` sends a line first."""

    def __init__(self, banner: bytes | None = None) -> None:
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(8)
        self.banner, self.conns = banner, []
        self.address = f"tcp://127.0.0.1:{self.sock.getsockname()[1]}"
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.conns.append(conn)
            if self.banner:
                conn.sendall(self.banner)

    def close(self) -> None:
        for c in self.conns:
            c.close()
        self.sock.close()


@pytest.fixture(params=["silent", "banner", "http"])
def not_a_scheduler(request):
    if request.param == "http":
        server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), http.server.SimpleHTTPRequestHandler)
        threading.Thread(target=server.serve_forever, daemon=True).start()
        yield f"tcp://127.0.0.1:{server.server_address[1]}"
        server.shutdown()
        server.server_close()
        return
    listener = _Listener(b"SSH-2.0-OpenSSH_9.6\r\n" if request.param == "banner" else None)
    yield listener.address
    listener.close()


def test_a_scheduler_address_that_is_not_a_dask_scheduler_is_one_line_within_the_timeout(tmp_path, not_a_scheduler):
    spec = write_spec(tmp_path)
    start = time.monotonic()
    r = invoke("batch", spec, "-o", tmp_path / "out", "--scheduler", not_a_scheduler, "--connect-timeout", "1")
    took = time.monotonic() - start
    line = one_error_line(r.output)
    assert r.exit_code == 2 and "--scheduler: cannot connect" in line and not_a_scheduler in line
    assert took < 10 and not (tmp_path / "out").exists()


def test_the_scheduler_address_from_the_environment_is_named_so_and_checked_before_any_start(tmp_path, monkeypatch):
    monkeypatch.setenv("DASK_SCHEDULER_ADDRESS", "not a url")
    r = invoke("batch", write_spec(tmp_path), "-o", tmp_path / "out")
    assert r.exit_code == 2 and one_error_line(r.output).startswith("hoc: error: DASK_SCHEDULER_ADDRESS: expected")
    monkeypatch.setenv("DASK_SCHEDULER_ADDRESS", "tcp://127.0.0.1:1")
    monkeypatch.setattr("hoc_cli.commands.plan.solve", lambda *a, **k: pytest.fail("start 0 was solved"), raising=False)
    r = invoke("plan", tmp_path / "arm.yaml", "-o", "none", "--starts", "3")
    assert r.exit_code == 2 and "DASK_SCHEDULER_ADDRESS: cannot connect" in one_error_line(r.output)


@pytest.mark.parametrize("address,said", [("not a url", "expected a Dask scheduler address"),
                                          ("tcp://127.0.0.1:99999", "expected a Dask scheduler address"),
                                          ("http://127.0.0.1:8786", "expected a Dask scheduler address"),
                                          ("tcp://127.0.0.1:1", "Connection refused")])
def test_a_malformed_address_or_a_closed_port_is_one_line(tmp_path, address, said):
    r = invoke("batch", write_spec(tmp_path), "-o", tmp_path / "out", "--scheduler", address, "--connect-timeout", "1")
    assert r.exit_code == 2 and said in one_error_line(r.output) and not (tmp_path / "out").exists()


def test_the_connect_timeout_is_checked(tmp_path):
    r = invoke("batch", write_spec(tmp_path), "--scheduler", "tcp://127.0.0.1:1", "--connect-timeout", "0")
    assert r.exit_code == 2 and "--connect-timeout: expected a number of seconds > 0" in r.output


# --- absurd counts ------------------------------------------------------------------------------

def test_absurd_counts_are_refused_up_front(tmp_path, no_cluster):
    from hoc_cli.batch.engine import max_workers

    spec = write_spec(tmp_path)
    r = invoke("batch", spec, "-o", tmp_path / "out", "--workers", max_workers() + 1)
    assert r.exit_code == 2 and f"--workers: expected an integer from 1 to {max_workers()}" in r.output
    r = invoke("plan", tmp_path / "arm.yaml", "-o", "none", "--starts", 1_000_000)
    assert r.exit_code == 2 and "--starts: expected an integer from 1 to 1000" in r.output
    big = write_spec(tmp_path, name="big.yaml", extra="starts: 1000000\n")
    r = invoke("batch", big, "-o", tmp_path / "out")
    assert r.exit_code == 2 and "starts: expected an integer >= 1 and <= 1000" in r.output
    huge = write_spec(tmp_path, "x1.q: {random: {count: 1000000000, within: limits}}", name="huge.yaml")
    r = invoke("batch", huge, "-o", tmp_path / "out")  # refused before a billion draws are made
    assert r.exit_code == 2 and "sweep.x1.q.random.count: expected an integer >= 1 and <= 1000000" in r.output
    axes = write_spec(tmp_path, "T: {grid: {start: 1.0, stop: 2.0, num: 2000}}\n  N: {grid: {start: 4, stop: 8, num: 1000}}",
                      name="axes.yaml")
    r = invoke("batch", axes, "-o", tmp_path / "out")
    assert r.exit_code == 2 and "the sweep has more than 1000000 plans" in r.output
    (tmp_path / "many.yaml").write_text((tmp_path / "arm.yaml").read_text() + "solver: {starts: 5000}\n")
    r = invoke("plan", tmp_path / "many.yaml", "-o", "none")
    assert r.exit_code == 2 and "solver.starts: expected an integer from 1 to 1000" in r.output
    assert not (tmp_path / "out").exists()


# --- spec mistakes and output folders, before any cluster ---------------------------------------

@pytest.mark.parametrize("sweep,key", [
    ("foo: [1, 2]", "sweep.foo"),
    ("x1.qq: [[1.0, 2.0]]", "sweep.x1.qq"),
    ("t: [1.0, 2.0]", "sweep.t"),
    ("solver.tols: [1.0e-6]", "sweep.solver.tols"),
    ("x1: [{q: [1.0, 2.0]}, {q: [1.0, 2.0], ddq: [0, 0]}]", "sweep.x1"),
    ("limits.velocity.nojoint: [1.0]", "sweep.limits.velocity.nojoint"),
    ("x1.q: [{shoulder: 1.0, nojoint: 2.0}]", "sweep.x1.q"),
    ("locked.nojoint: [0.1]", "sweep.locked.nojoint"),
], ids=["top", "nested", "t-for-T", "solver", "in-a-value", "limit-joint", "goal-joint", "locked-joint"])
def test_a_swept_key_the_task_schema_does_not_know_is_refused_before_any_cluster(tmp_path, no_cluster, sweep, key):
    r = invoke("batch", write_spec(tmp_path, sweep), "-o", tmp_path / "out")
    assert r.exit_code == 2, r.output
    assert f"sweep.yaml: {key}: in the swept task" in r.output and r.output.count("\n") == 1
    assert not (tmp_path / "out").exists()


def test_an_invalid_swept_value_is_still_an_error_row_not_a_refusal(tmp_path):
    from hoc_cli.batch.spec import load_spec

    batch = load_spec(write_spec(tmp_path, "T: [-1.0, 1.0]"))
    assert len(batch.jobs) == 2


def _dangling(d: Path) -> Path:
    link = d / "dangling"
    link.symlink_to(d / "missing" / "folder")
    return link


def _a_file(d: Path) -> Path:
    (d / "file").write_text("x")
    return d / "file"


def _results_is_a_folder(d: Path) -> Path:
    (d / "out" / "results.parquet").mkdir(parents=True)
    return d / "out"


@pytest.mark.parametrize("make,said", [
    (_dangling, "is a symbolic link to"),
    (_a_file, "exists and is not a folder"),
    (_results_is_a_folder, "results.parquet is a folder"),
    (lambda d: Path("/proc/self"), "is not writable"),
    (lambda d: Path("/proc/hoc-batch-results"), "cannot be created"),
], ids=["dangling-link", "a-file", "results-a-folder", "read-only", "cannot-create"])
def test_an_output_folder_that_cannot_be_written_is_refused_before_any_plan(tmp_path, no_cluster, make, said):
    out = make(tmp_path)
    r = invoke("batch", write_spec(tmp_path), "-o", out)
    assert r.exit_code == 2 and said in r.output and r.output.count("\n") == 1, r.output


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_a_folder_without_write_permission_is_refused(tmp_path, no_cluster):
    out = tmp_path / "ro"
    out.mkdir()
    out.chmod(0o555)
    try:
        r = invoke("batch", write_spec(tmp_path), "-o", out)
    finally:
        out.chmod(0o755)
    assert r.exit_code == 2 and "is not writable" in r.output


# --- resume: never another spec's rows ----------------------------------------------------------

@pytest.fixture
def solved(tmp_path):
    """The results folder of a two-plan sweep, as hoc batch writes it (rows of every plan, the spec's identity)."""
    from hoc_cli.batch import results
    from hoc_cli.batch.spec import load_spec

    d = tmp_path / "first"
    d.mkdir()
    spec = write_spec(d, "T: [1.0, 1.5]")
    batch = load_spec(spec)
    rows = [{"id": job.id, "task": job.source, "T": job.swept["T"], "status": "converged", "converged": True,
             "cost": 1.0, "outputs": []} for job in batch.jobs]
    (d / "out").mkdir()
    results.write(d / "out", results.table(rows, ["T"]), batch.identity)
    return d / "out", spec


def test_resume_refuses_the_results_of_another_spec(solved, tmp_path, no_cluster):
    out, _ = solved
    other = write_spec(tmp_path, "T: [1.0, 2.5]")
    before = (out / "results.parquet").read_bytes()
    r = invoke("batch", other, "-o", out, "--resume")
    assert r.exit_code == 2 and "--resume: holds the results of another spec" in r.output
    assert (out / "results.parquet").read_bytes() == before


def test_resume_accepts_the_same_spec_written_differently(solved, tmp_path, no_cluster):
    out, spec = solved
    write_base(tmp_path)
    same = tmp_path / "same.yaml"  # other file, other key order and spelling, a comment: the same plans
    same.write_text(f"# the same sweep\nsweep: {{T: [1.5, 1.0]}}\nbase: {tmp_path / 'arm.yaml'}\noutputs: none\n")
    r = invoke("batch", same, "-o", out, "--resume", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["resumed"] == 2


def test_resume_refuses_a_parquet_hoc_did_not_write(tmp_path, no_cluster):
    out = tmp_path / "out"
    out.mkdir()
    pq.write_table(pa.table({"id": [1, 2], "value": [0.5, 0.25]}), out / "results.parquet")
    r = invoke("batch", write_spec(tmp_path), "-o", out, "--resume")
    assert r.exit_code == 2 and "was not written by 'hoc batch'" in r.output and "Traceback" not in r.output


# --- one run per folder -------------------------------------------------------------------------

def test_a_second_batch_into_a_folder_in_use_is_refused_and_a_dead_holder_s_lock_is_not_a_lock(tmp_path, no_cluster):
    from hoc_cli.report.locks import LOCK_NAME, FolderLock

    out = tmp_path / "out"
    out.mkdir()
    spec = write_spec(tmp_path)
    with FolderLock(out):  # another run holds the folder
        r = invoke("batch", spec, "-o", out)
        assert r.exit_code == 2 and f"is in use by another 'hoc batch' run (process {os.getpid()})" in r.output
    assert not (out / LOCK_NAME).exists()
    (out / LOCK_NAME).write_text("999999999\n")  # left by a run that was killed
    with FolderLock(out):
        assert (out / LOCK_NAME).read_text().strip() == str(os.getpid())


def test_two_batch_processes_into_one_folder_one_is_refused_the_other_keeps_every_row(tmp_path):
    from hoc_cli.report.locks import LOCK_NAME

    write_base(tmp_path, N=20)
    spec = tmp_path / "long.yaml"
    spec.write_text("base: arm.yaml\nsweep:\n  T: {grid: {start: 1.0, stop: 3.0, num: 20}}\n")
    out = tmp_path / "out"
    first = subprocess.Popen(hoc_command() + ["batch", str(spec), "-o", str(out), "--workers", "1", "--json"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 30
        while not (out / LOCK_NAME).exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        second = run_hoc("batch", spec, "-o", out, "--workers", "1")
        stdout, err = first.communicate(timeout=120)
    finally:
        first.kill()
    assert second.returncode == 2 and "is in use by another 'hoc batch' run" in one_error_line(second.stderr)
    assert first.returncode == 0, err
    assert json.loads(stdout)["solved"] == 20 and pq.read_table(out / "results.parquet").num_rows == 20


def test_two_plans_writing_the_same_files_leave_one_run_s_whole_set(tmp_path):
    from hoc_cli.report.locks import directories_locked

    write_base(tmp_path)
    outs = ["-o", tmp_path / "same.csv", "-o", tmp_path / "same.mcap"]
    with directories_locked([tmp_path / "same.csv"]):  # another run is renaming its files into this folder
        proc = subprocess.Popen(hoc_command() + ["plan", str(tmp_path / "arm.yaml"), *map(str, outs)],
                                stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 30
        while len(list(tmp_path.glob(".same.*.tmp"))) < 2 and time.monotonic() < deadline:
            time.sleep(0.02)
        time.sleep(0.3)
        assert proc.poll() is None and not (tmp_path / "same.csv").exists() and not (tmp_path / "same.mcap").exists()
    assert proc.wait(timeout=30) == 0, proc.stderr.read()
    # two runs at once (T = 1.0 and T = 2.0): the CSV and the MCAP come from the same one
    runs = [subprocess.Popen(hoc_command() + ["plan", str(tmp_path / "arm.yaml"), "-T", T, *map(str, outs)],
                             stderr=subprocess.DEVNULL) for T in ("1.0", "2.0")]
    assert [p.wait(timeout=60) for p in runs] == [0, 0]
    from hoc_cli.io.mcap import read_plan

    csv_T = float((tmp_path / "same.csv").read_text().strip().splitlines()[-1].split(",")[0])
    mcap_T = float(read_plan(tmp_path / "same.mcap").trajectory.t[-1])
    assert csv_T == pytest.approx(mcap_T) and not list(tmp_path.glob(".same.*.tmp"))


# --- signals in every phase ---------------------------------------------------------------------

def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _signal_when_children(args: list[str], sig: int, children: int, after: float = 0.0) -> tuple[int, str, list]:
    """Start hoc, send ``sig`` ``after`` seconds after it has ``children`` child processes; (exit code,
    stderr, the children)."""
    proc = subprocess.Popen(hoc_command() + args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_default_sigint)
    try:
        me = psutil.Process(proc.pid)
        deadline = time.monotonic() + 60
        kids: list = []
        while time.monotonic() < deadline and proc.poll() is None:
            try:
                kids = me.children(recursive=True)
            except psutil.NoSuchProcess:
                break
            if len(kids) >= children:
                break
            time.sleep(0.01)
        time.sleep(after)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    return proc.returncode, err, kids


def _alive(processes) -> list:
    time.sleep(0.5)
    return [p for p in processes if p.is_running() and p.status() != psutil.STATUS_ZOMBIE]


def test_sigint_while_the_local_cluster_starts_stops_it_and_leaves_nothing(tmp_path):
    out = tmp_path / "out"
    returncode, err, kids = _signal_when_children(["batch", str(write_spec(tmp_path)), "-o", str(out), "--workers", "2"],
                                                  signal.SIGINT, 2)
    assert kids, "no worker process was started"
    assert returncode == 130 and "interrupted; no output was changed" in one_error_line(err)
    assert not _alive(kids) and not (out / "results.parquet").exists()


def test_sighup_while_multi_start_runs_on_a_local_cluster_exits_129_quietly_and_writes_nothing(tmp_path):
    base = write_base(tmp_path, N=60)  # serially far above PARALLEL_STARTS_MIN_S even on a fast idle machine
    # the resource tracker and 2 workers, then the starts running on them
    returncode, err, kids = _signal_when_children(["plan", str(base), "-o", str(tmp_path / "p.csv"), "--starts", "1000"],
                                                  signal.SIGHUP, 3, after=4.0)
    lines = [line for line in err.splitlines() if line.strip()]
    assert kids and returncode == 129 and lines[-1] == "hoc: error: hung up (SIGHUP); no output was changed", err
    assert all(line.startswith("hoc: ") for line in lines), err  # no Dask log from the cluster's shutdown
    assert not _alive(kids) and not (tmp_path / "p.csv").exists()


# --- the work estimate of a batch ---------------------------------------------------------------

def test_a_long_batch_is_announced_before_its_cluster_starts_and_a_short_one_is_not(tmp_path, monkeypatch):
    started = []

    def connect(**kwargs):
        started.append(kwargs)
        raise KeyboardInterrupt  # stop here: the estimate came before

    monkeypatch.setattr("hoc_cli.batch.engine.connect", connect)
    spec = write_spec(tmp_path, "T: {grid: {start: 1.0, stop: 3.0, num: 1000}}", name="huge.yaml")
    r = invoke("batch", spec, "-o", tmp_path / "out", "--workers", "2")
    assert r.exit_code == 130 and started
    warning = [line for line in r.output.splitlines() if line.startswith("hoc: warning: this batch")]
    assert len(warning) == 1 and "1000 plans" in warning[0] and "on 2 workers" in warning[0]
    r = invoke("batch", write_spec(tmp_path), "-o", tmp_path / "out2", "--workers", "2")
    assert r.exit_code == 130 and "hoc: warning" not in r.output


def test_a_batch_that_outlasts_an_estimate_under_the_threshold_says_so_while_it_runs(tmp_path, monkeypatch):
    from hoc_cli.batch import execute_batch
    from hoc_cli.errors import HocWarning
    from hoc_cli.report.workload import BatchWorkload

    monkeypatch.setattr("hoc_cli.report.workload.WARN_SECONDS", 1e-3)  # the cluster's start alone is longer
    monkeypatch.setattr("hoc_cli.report.workload.plan_workloads", lambda jobs: BatchWorkload(len(jobs), 0.0, 0.0))
    monkeypatch.setattr("hoc_cli.report.workload.CLUSTER_START_S", (0.0, 0.0))  # an estimate of nothing
    with pytest.warns(HocWarning) as caught:
        result = execute_batch(write_spec(tmp_path), out_dir=tmp_path / "out", workers=1, estimate=True)
    said = [str(w.message) for w in caught]
    assert result.solved == 2 and len(said) == 1 and said[0].startswith("this run has taken") and "estimate" in said[0]


def test_a_batch_row_tells_the_truth_as_hoc_plan_does(tmp_path):
    """A plan proven infeasible before its solve is an `infeasible` row (velocity: 1.2 rad in 0.05 s at
    10 rad/s cannot be done), a feasible one `converged`; every row of a batch is ``hoc plan``'s summary."""
    from hoc_cli.batch.job import solve_job
    from hoc_cli.batch.spec import load_spec

    rows = [solve_job(job) for job in load_spec(write_spec(tmp_path, sweep="T: [0.05, 1.5]")).jobs]
    by_T = {row["T"]: row for row in rows}
    assert by_T[0.05]["status"] == "infeasible" and "T >=" in by_T[0.05]["error"] and not by_T[0.05]["converged"]
    assert by_T[1.5]["status"] == "converged" and by_T[1.5]["error"] is None


def test_a_worker_drops_only_its_lost_heartbeat_record_whose_text_is_dasks():
    """The local cluster's workers (worker_init) drop the lost-heartbeat record of a closing cluster, which Dask
    logs with its traceback after hoc's one line; any other record of theirs passes."""
    import inspect
    import io
    import logging

    import distributed.worker

    from hoc_cli.batch import worker_init

    assert worker_init.HEARTBEAT_LOST in inspect.getsource(distributed.worker.Worker.heartbeat)
    logger, buf = logging.getLogger("distributed.worker"), io.StringIO()
    handler = logging.StreamHandler(buf)
    logger.addHandler(handler)
    try:
        try:
            raise OSError("stream closed")
        except OSError:
            logger.error(worker_init.HEARTBEAT_LOST + ".", exc_info=True)
            logger.error("Unexpected exception during heartbeat. Closing worker.", exc_info=True)
    finally:
        logger.removeHandler(handler)
    assert worker_init.HEARTBEAT_LOST not in buf.getvalue() and "Unexpected exception" in buf.getvalue()
