"""`hoc batch` on real Dask clusters, and multi-start (`hoc plan --starts`).

Clusters: a LocalCluster with 2 worker processes (shared by the tests of this module), one with
1 worker, and a scheduler and a worker started here as separate processes on 127.0.0.1
(`dask scheduler --port 0`, `dask worker ADDRESS`), shut down at the end. Every batch row is
checked against a single `hoc plan` of the same task; the robot is the planar two-link arm with
few elements so that the whole module stays within a few tens of seconds.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from hoc_cli.cli import app

#: the `dask` command of this interpreter's environment (on PATH only when the venv is activated)
DASK = str(Path(sys.executable).with_name("dask"))

pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")
pytest.importorskip("distributed")

ROOT = Path(__file__).resolve().parent.parent
URDF = ROOT / "robots" / "two_link.urdf"
TIMING = ["solve_time_s"]


def invoke(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def hoc_command() -> list[str]:
    script = Path(sys.executable).with_name("hoc")
    if script.is_file() and os.access(script, os.X_OK):
        return [str(script)]
    return [sys.executable, "-c", "from hoc_cli.cli import app; app()"]


def write_base(d: Path, N: int = 6) -> Path:
    base = d / "arm.yaml"
    base.write_text(f"robot: {URDF}\nx0: {{q: [0.0, 0.0]}}\nx1: {{q: [1.2, -0.6]}}\nT: 1.5\nN: {N}\n"
                    "output: {rate: 20}\n")
    return base


def write_spec(d: Path, outputs: str = "[csv]", extra: str = "") -> Path:
    base = write_base(d)
    spec = d / "sweep.yaml"
    spec.write_text(f"base: {base.name}\nsweep:\n  T: [1.0, 1.5, -1.0]\n"
                    "  x1.q: {random: {count: 2, within: limits, seed: 3}}\n"
                    f"outputs: {outputs}\n{extra}")
    return spec


def without_timing(table):
    return table.drop_columns([c for c in TIMING if c in table.column_names])


@pytest.fixture(scope="module")
def client2():
    from hoc_cli.batch.engine import connect

    with connect(workers=2) as client:
        yield client


@pytest.fixture(scope="module")
def sweep2(tmp_path_factory, client2):
    """The sweep solved on the 2-worker local cluster: (spec path, results dir, BatchRun)."""
    from hoc_cli.batch import execute_batch

    d = tmp_path_factory.mktemp("sweep")
    spec = write_spec(d)
    return spec, d / "out", execute_batch(spec, client2, out_dir=d / "out")


# --- lazy imports -------------------------------------------------------------------------------

def test_the_cli_and_a_single_plan_do_not_import_dask_or_pyarrow():
    code = ("import sys, hoc_cli.cli, hoc_cli.commands.plan, hoc_cli.multistart; "
            "bad = sorted({m.split('.')[0] for m in sys.modules} & {'dask', 'distributed', 'pyarrow'}); "
            "print(bad); sys.exit(1 if bad else 0)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr


# --- the spec -----------------------------------------------------------------------------------

def test_a_sweep_is_the_cartesian_product_of_its_axes_with_reproducible_random_values(tmp_path):
    from hoc_cli.batch.spec import load_spec
    from hoc_cli.io.robot import load_model
    from hoc_cli.io.task import load_task

    base = write_base(tmp_path)
    spec = {"base": str(base), "sweep": {"T": [1.0, 2.0], "N": {"grid": {"start": 4, "stop": 10, "step": 3}},
                                         "x1.q[1]": {"random": {"count": 3, "within": [-0.5, 0.5], "seed": 1}},
                                         "x0.q": {"random": {"count": 2, "within": "limits", "seed": 2}}}}
    b = load_spec(spec)
    assert len(b.jobs) == 2 * 3 * 3 * 2 and b.sweep_keys == ["T", "N", "x1.q[1]", "x0.q"]
    assert sorted({j.swept["N"] for j in b.jobs}) == [4, 7, 10]
    assert all(isinstance(j.doc["N"], int) for j in b.jobs)
    assert all(-0.5 <= j.doc["x1"]["q"][1] <= 0.5 and j.doc["x1"]["q"][0] == 1.2 for j in b.jobs)
    model = load_model(load_task(base))
    q0 = np.array([j.doc["x0"]["q"] for j in b.jobs])
    assert np.all(q0 >= model.lower) and np.all(q0 <= model.upper) and len({tuple(q) for q in q0}) == 2
    again = load_spec(spec)
    assert [j.id for j in again.jobs] == [j.id for j in b.jobs] and len({j.id for j in b.jobs}) == len(b.jobs)
    other = load_spec(spec | {"sweep": spec["sweep"] | {"x0.q": {"random": {"count": 2, "within": "limits",
                                                                            "seed": 3}}}})
    assert {j.id for j in other.jobs}.isdisjoint({j.id for j in b.jobs})


def test_the_id_is_a_hash_of_the_task_content_not_of_its_file(tmp_path):
    from hoc_cli.batch.spec import load_spec

    a = write_base(tmp_path)
    (tmp_path / "sub").mkdir()
    b = tmp_path / "sub" / "renamed.yaml"
    b.write_text("# a comment\n" + a.read_text())
    ids = [j.id for j in load_spec({"tasks": [str(a), str(b)]}).jobs + load_spec({"tasks": [str(b)]}).jobs]
    assert ids[0] == ids[-1]
    assert len(load_spec({"tasks": [str(a), str(b)]}).jobs) == 1  # the same plan twice is solved once
    c = tmp_path / "c.yaml"
    c.write_text(a.read_text().replace("T: 1.5", "T: 1.25"))
    assert load_spec({"tasks": [str(c)]}).jobs[0].id != ids[0]


@pytest.mark.parametrize("sweep,key", [
    ({"T": {"grid": {"start": 1, "stop": 2}}}, "sweep.T"),
    ({"T": {"random": {"count": 2, "within": "limits"}}}, "sweep.T.random.within"),
    ({"x1.q": {"random": {"count": 0, "within": [0, 1]}}}, "sweep.x1.q.random.count"),
    ({"x1.q": []}, "sweep.x1.q"),
    ({"x1..q": [1]}, "sweep.x1..q"),
], ids=["grid-without-num", "limits-on-T", "count-0", "empty-list", "bad-path"])
def test_a_malformed_spec_is_one_line_naming_the_file_and_key_exit_2(tmp_path, sweep, key):
    base = write_base(tmp_path)
    spec = tmp_path / "bad.yaml"
    spec.write_text(yaml.safe_dump({"base": base.name, "sweep": sweep}))
    r = invoke("batch", spec, "-o", tmp_path / "out")
    assert r.exit_code == 2, r.output
    line = r.output.strip()
    assert "\n" not in line and str(spec) in line and f": {key}: expected" in line
    assert not (tmp_path / "out").exists()


def test_unknown_spec_key_and_missing_task_file_are_input_errors(tmp_path):
    spec = tmp_path / "s.yaml"
    spec.write_text("tasks: [nothere/*.yaml]\n")
    r = invoke("batch", spec)
    assert r.exit_code == 2 and "tasks[0]: expected" in r.output
    spec.write_text("base: x.yaml\nsweeps: {}\n")
    r = invoke("batch", spec)
    assert r.exit_code == 2 and "unknown key 'sweeps'" in r.output


# --- batches on real clusters -------------------------------------------------------------------

def test_every_row_equals_a_single_hoc_plan_and_invalid_plans_are_error_rows(sweep2, tmp_path):
    spec, out, run = sweep2
    rows = run.table.to_pylist()
    assert run.total == 6 and run.solved == 6 and len(rows) == 6
    assert [r["id"] for r in rows] == sorted(r["id"] for r in rows)
    errors = [r for r in rows if r["status"] == "error"]
    assert len(errors) == 2 and all(r["T"] == -1.0 and ": T: expected a duration" in r["error"] for r in errors)
    assert all(r["cost"] is None and r["outputs"] == [] for r in errors)
    ok = [r for r in rows if r["status"] != "error"]
    jobs = {j.id: j for j in __import__("hoc_cli.batch.spec", fromlist=["x"]).load_spec(spec).jobs}
    for r in ok:
        task = tmp_path / f"{r['id']}.yaml"
        task.write_text(jobs[r["id"]].yaml_text())
        p = invoke("plan", task, "-o", tmp_path / "single.csv", "--json")
        assert p.exit_code == 0, p.output
        single = json.loads(p.stdout)
        assert abs(r["cost"] - single["cost"]) <= 1e-12 * abs(single["cost"])
        assert r["converged"] is single["converged"] is True and r["iterations"] == single["iterations"]
        assert r["outputs"] == [f"plans/{r['id']}.csv"]
        assert (out / r["outputs"][0]).read_bytes() == (tmp_path / "single.csv").read_bytes()
        assert r["x1.q"] == jobs[r["id"]].doc["x1"]["q"] and r["T"] == jobs[r["id"]].doc["T"]
    # the CSV holds the same table
    text = (out / "results.csv").read_text().splitlines()
    assert len(text) == 7 and text[0].startswith("id,task,T,x1.q,status,converged,cost,")
    assert [line.split(",")[0] for line in text[1:]] == [r["id"] for r in rows]
    assert [r["cost"] for r in pq.read_table(out / "results.parquet").to_pylist()] == [r["cost"] for r in rows]


def test_chunks_shrink_to_single_plans_at_the_end_and_never_exceed_8_plans():
    from hoc_cli.batch import chunk_sizes

    assert chunk_sizes(6, 2) == [1] * 6 and chunk_sizes(31, 2) == [1] * 31
    assert chunk_sizes(30, 1)[:3] == [3, 3, 3] and chunk_sizes(200, 2)[:9] == [8] * 9
    for n in (0, 1, 15, 16, 17, 100, 1000, 10**5):
        for t in (1, 2, 8):
            sizes = chunk_sizes(n, t)
            assert sum(sizes) == n and all(1 <= s <= 8 for s in sizes)
            assert sizes == sorted(sizes, reverse=True)  # largest first
            assert sizes[-min(n, 8 * t):] == [1] * min(n, 8 * t)  # the last 8 per thread go one by one


def test_resume_recomputes_nothing_and_keeps_every_row_and_file(sweep2, client2):
    from hoc_cli.batch import execute_batch

    spec, out, run = sweep2
    files = {p: p.stat().st_mtime_ns for p in (out / "plans").iterdir()}
    again = execute_batch(spec, client2, out_dir=out, resume=True)
    assert again.solved == 0 and again.skipped == 6
    assert again.table.equals(run.table)  # including the solve times of the first run
    assert {p: p.stat().st_mtime_ns for p in (out / "plans").iterdir()} == files


def test_local_workers_run_without_dask_malloc_trim_setting(client2):
    # Dask's default MALLOC_TRIM_THRESHOLD_=65536 for workers makes hoc's solves about 2x slower
    envs = client2.run(lambda: (os.environ.get("MALLOC_TRIM_THRESHOLD_"), os.environ.get("OMP_NUM_THREADS")))
    assert len(envs) == 2 and set(envs.values()) == {(None, "1")}
    assert os.environ.get("MALLOC_TRIM_THRESHOLD_") is None  # nor is it left in hoc's own environment


def test_one_worker_gives_the_same_table_as_two(sweep2, tmp_path):
    import hoc_cli.batch

    spec, _, run = sweep2
    one = hoc_cli.batch.run(spec, out_dir=tmp_path / "one", workers=1)
    assert without_timing(one).equals(without_timing(run.table))


def test_a_scheduler_and_a_worker_started_as_processes_give_the_same_table(sweep2, tmp_path):
    spec, _, run = sweep2
    sched_file = tmp_path / "scheduler.json"
    env = dict(os.environ, DASK_DISTRIBUTED__WORKER__DAEMON="False")
    procs = [subprocess.Popen([DASK, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                               "--scheduler-file", str(sched_file)], stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, env=env)]
    try:
        deadline = time.monotonic() + 60
        address = None
        while address is None and time.monotonic() < deadline:  # the scheduler writes the file in pieces
            try:
                address = json.loads(sched_file.read_text())["address"]
            except (OSError, ValueError, KeyError):
                time.sleep(0.1)
        assert address is not None, "the scheduler wrote no address in 60 s"
        assert address.startswith("tcp://127.0.0.1:")
        # issue 24: a scheduler without workers is refused once --connect-timeout has passed, not waited on
        r = invoke("batch", spec, "-o", tmp_path / "idle", "--scheduler", address, "--connect-timeout", "1")
        assert r.exit_code == 2 and "has no workers (none joined within 1 s" in r.output
        procs.append(subprocess.Popen([DASK, "worker", address, "--host", "127.0.0.1", "--nthreads", "1",
                                       "--no-dashboard"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                      env=env))
        r = subprocess.run(hoc_command() + ["batch", str(spec), "-o", str(tmp_path / "remote"), "--json"],
                           capture_output=True, text=True, env=dict(env, DASK_SCHEDULER_ADDRESS=address), timeout=120)
        assert r.returncode == 1, r.stderr  # exit 1: two plans are error rows
        summary = json.loads(r.stdout)
        assert summary["scheduler"] == address and summary["solved"] == 6 and summary["errors"] == 2
        remote = pq.read_table(tmp_path / "remote" / "results.parquet")
        assert without_timing(remote).equals(without_timing(run.table))
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in reversed(procs):
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def test_an_unreachable_scheduler_is_an_input_error(tmp_path, monkeypatch):
    monkeypatch.setattr("hoc_cli.batch.engine.CONNECT_TIMEOUT_S", 1)
    spec = write_spec(tmp_path)
    r = invoke("batch", spec, "-o", tmp_path / "out", "--scheduler", "tcp://127.0.0.1:1")
    assert r.exit_code == 2 and "--scheduler: cannot connect" in r.output


def test_task_files_and_globs_with_broken_ones_as_error_rows(client2, tmp_path):
    import hoc_cli.batch

    write_base(tmp_path)
    (tmp_path / "b.yaml").write_text((tmp_path / "arm.yaml").read_text().replace("T: 1.5", "T: 2.0"))
    (tmp_path / "c.yaml").write_text("robot: [unclosed\n")
    (tmp_path / "d.yaml").write_text((tmp_path / "arm.yaml").read_text().replace(str(URDF), "missing.urdf"))
    tab = hoc_cli.batch.run({"tasks": [str(tmp_path / "*.yaml")]}, client2).to_pylist()
    by_task = {Path(r["task"]).name: r for r in tab}
    assert sorted(by_task) == ["arm.yaml", "b.yaml", "c.yaml", "d.yaml"]
    assert by_task["arm.yaml"]["converged"] and by_task["b.yaml"]["converged"]
    assert "invalid YAML" in by_task["c.yaml"]["error"] and "URDF file not found" in by_task["d.yaml"]["error"]


def test_ctrl_c_cancels_keeps_the_completed_rows_exits_130_and_resume_finishes(tmp_path):
    base = write_base(tmp_path, N=12)
    spec = tmp_path / "long.yaml"
    spec.write_text(f"base: {base.name}\nsweep:\n  T: {{grid: {{start: 1.0, stop: 3.0, num: 30}}}}\noutputs: csv\n")
    out = tmp_path / "out"
    # its own process group, signalled as a whole: what Ctrl-C on a terminal does (workers included)
    proc = subprocess.Popen(hoc_command() + ["batch", str(spec), "-o", str(out), "--workers", "1"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 60
        # 30 plans on 1 worker go as Dask tasks of 3, 3, 3, 2... (chunk_sizes): after 7 files, 2 tasks have surely returned
        while time.monotonic() < deadline and len(list((out / "plans").glob("*.csv")) if out.exists() else []) < 7:
            time.sleep(0.05)
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    assert "interrupted; the" in err and "--resume" in err and "Traceback" not in err
    first = pq.read_table(out / "results.parquet").to_pylist()
    assert 1 <= len(first) < 30 and all((out / r["outputs"][0]).is_file() for r in first)
    r = invoke("batch", spec, "-o", out, "--resume", "--workers", "2", "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["resumed"] == len(first) and s["solved"] == 30 - len(first)
    final = {r["id"]: r for r in pq.read_table(out / "results.parquet").to_pylist()}
    assert len(final) == 30 and all(final[r["id"]] == r for r in first)


# --- multi-start --------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def arm():
    from hoc_cli.elements import HermiteMesh
    from hoc_cli.io.robot import load_model
    from hoc_cli.io.task import load_task, resolve
    from hoc_cli.system import RobotSystem

    task = load_task(ROOT / "configs" / "two_link.yaml")
    model = load_model(task)
    s = resolve(task, model.joint_names)
    return RobotSystem(model), HermiteMesh("quintic", 1.5, 8), (s.q0, s.dq0, s.q1, s.dq1)


def test_the_perturbation_keeps_both_ends_and_its_derivative_columns_are_its_derivatives():
    from hoc_cli.elements import HermiteMesh
    from hoc_cli.multistart import perturbation

    mesh = HermiteMesh("quintic", 2.0, 400)
    P = perturbation(mesh, np.array([0.3, 1.0]), np.random.default_rng(0))
    assert P.shape == (401, 3, 2)
    assert np.abs(P[[0, -1]]).max() < 1e-13 and np.abs(P).max() > 0.05
    h = mesh.h
    for r in (0, 1):  # central differences of column r against column r+1, error O(h²)
        fd = (P[2:, r] - P[:-2, r]) / (2 * h)
        assert np.abs(fd - P[1:-1, r + 1]).max() < 1e-3 * np.abs(P[:, r + 1]).max()


def test_start_0_is_the_plain_plan_and_starts_are_deterministic_per_seed(arm):
    from hoc_cli.multistart import solve_start, solve_starts
    from hoc_cli.planner import plan

    system, mesh, bc = arm
    plain = plan(system, mesh, *bc)
    three = solve_starts(system, mesh, *bc, starts=3, seed=5)
    assert three.outcomes[0].J == plain.J and three.outcomes[0].status == "converged"
    assert solve_starts(system, mesh, *bc, starts=3, seed=5).outcomes == three.outcomes
    assert solve_starts(system, mesh, *bc, starts=2, seed=5).outcomes == three.outcomes[:2]
    conv = [o for o in three.outcomes if o.converged]
    assert three.best.J == min(o.J for o in conv) and three.outcomes[three.best_index].J == three.best.J
    # a start differs with the seed, and its result is what solve_start gives alone
    assert solve_start(system, mesh, *bc, 1, 5).J == three.outcomes[1].J
    g5 = __import__("hoc_cli.multistart", fromlist=["x"]).start_guess(system, mesh, *bc, 1, 5)
    g6 = __import__("hoc_cli.multistart", fromlist=["x"]).start_guess(system, mesh, *bc, 1, 6)
    assert np.abs(g5 - g6).max() > 1e-3


def test_starts_on_a_cluster_give_the_same_outcome_as_serially(arm, client2):
    from hoc_cli.multistart import solve_starts

    system, mesh, bc = arm
    serial = solve_starts(system, mesh, *bc, starts=3, seed=2)
    parallel = solve_starts(system, mesh, *bc, starts=3, seed=2, client=client2)
    assert parallel.outcomes == serial.outcomes and parallel.best_index == serial.best_index
    assert np.array_equal(parallel.best.coeffs, serial.best.coeffs)


def test_hoc_plan_starts_reports_every_start_and_keeps_the_lowest_converged(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    base = write_base(tmp_path, N=8)
    r = invoke("plan", base, "--starts", "3", "--seed", "4", "-o", "a.csv", "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert [o["start"] for o in s["starts"]] == [0, 1, 2] and s["seed"] == 4
    best = min((o for o in s["starts"] if o["converged"]), key=lambda o: o["cost"])
    assert s["cost"] == best["cost"] and s["best_start"] == best["start"]
    plain = json.loads(invoke("plan", base, "-o", "b.csv", "--json").stdout)
    assert s["starts"][0]["cost"] == plain["cost"] and s["cost"] <= plain["cost"]
    r = invoke("plan", base, "--starts", "2", "--init", "a.csv")
    assert r.exit_code == 2 and "--starts" in r.output


def test_hoc_plan_runs_the_other_starts_on_a_local_cluster_when_worth_it_with_the_same_result(tmp_path,
                                                                                               monkeypatch):
    from hoc_cli.commands import starts

    monkeypatch.chdir(tmp_path)
    base = write_base(tmp_path, N=8)
    serial = json.loads(invoke("plan", base, "--starts", "3", "--seed", "4", "-o", "a.csv", "--json").stdout)
    used = []
    real_connect = __import__("hoc_cli.batch.engine", fromlist=["x"]).connect

    def connect(**kw):
        used.append(kw)
        return real_connect(**kw)

    monkeypatch.setattr(starts, "PARALLEL_STARTS_MIN_S", 0.0)
    monkeypatch.setattr("hoc_cli.batch.engine.connect", connect)
    monkeypatch.setattr("hoc_cli.batch.engine.available_cores", lambda: 2)
    r = invoke("plan", base, "--starts", "3", "--seed", "4", "-o", "b.csv", "--json")
    assert r.exit_code == 0, r.output
    parallel = json.loads(r.stdout)
    assert [(kw["workers"], kw["scheduler"]) for kw in used] == [(2, None)]
    assert parallel["starts"] == serial["starts"] and parallel["cost"] == serial["cost"]
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()


def test_a_batch_with_starts_stores_every_start_cost(client2, tmp_path):
    import hoc_cli.batch

    base = write_base(tmp_path, N=8)
    rows = hoc_cli.batch.run({"base": str(base), "sweep": {"T": [1.5]}, "starts": 3, "seed": 4},
                             client2).to_pylist()
    r = invoke("plan", base, "--starts", "3", "--seed", "4", "-o", tmp_path / "a.csv", "--json")
    s = json.loads(r.stdout)
    assert rows[0]["start_costs"] == [o["cost"] for o in s["starts"]] and rows[0]["cost"] == s["cost"]
    assert rows[0]["best_start"] == s["best_start"]


def test_solver_starts_in_the_task_is_the_same_as_the_option_which_overrides_it(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    base = write_base(tmp_path, N=8)
    option = json.loads(invoke("plan", base, "--starts", "3", "--seed", "4", "-o", "none", "--json").stdout)
    keyed = tmp_path / "keyed.yaml"
    keyed.write_text(base.read_text() + "solver: {starts: 3, seed: 4}\n")
    s = json.loads(invoke("plan", keyed, "-o", "none", "--json").stdout)
    assert s["starts"] == option["starts"] and s["cost"] == option["cost"] and s["seed"] == 4
    one = json.loads(invoke("plan", keyed, "--starts", "1", "-o", "none", "--json").stdout)
    assert "starts" not in one and one["cost"] == option["starts"][0]["cost"]
    for bad, key in (("{starts: 0}", "solver.starts"), ("{seed: -1}", "solver.seed"), ("{starts: 2.5}", "solver.starts")):
        keyed.write_text(base.read_text() + f"solver: {bad}\n")
        r = invoke("plan", keyed, "-o", "none")
        assert r.exit_code == 2 and key in r.output and "Traceback" not in r.output
    keyed.write_text(base.read_text() + "solver: {starts: 2}\n")
    r = invoke("plan", keyed, "--init", "x.csv", "-o", "none")
    assert r.exit_code == 2 and "solver.starts" in r.output


def test_a_batch_uses_each_task_s_solver_starts_unless_the_spec_sets_starts(client2, tmp_path):
    import hoc_cli.batch

    base = write_base(tmp_path, N=8)
    base.write_text(base.read_text() + "solver: {starts: 3, seed: 4}\n")
    rows = hoc_cli.batch.run({"base": str(base), "sweep": {"T": [1.5]}}, client2).to_pylist()
    s = json.loads(invoke("plan", base, "-o", "none", "--json").stdout)
    assert rows[0]["start_costs"] == [o["cost"] for o in s["starts"]] and len(s["starts"]) == 3
    single = hoc_cli.batch.run({"base": str(base), "sweep": {"T": [1.5]}, "starts": 1}, client2).to_pylist()
    assert single[0]["id"] != rows[0]["id"] and single[0]["cost"] == s["starts"][0]["cost"]


def test_tasks_with_goals_are_planned_as_hoc_plan_plans_them(tmp_path):
    """A free T, a link goal and a via (the shipped goal tasks) in one batch: each row's cost equals ``hoc plan``'s
    (1e-12), a free T's row has its optimal duration in ``T_optimal`` (the task's guess is not the plan's T)."""
    from hoc_cli.batch import execute_batch
    from hoc_cli.batch.engine import connect

    configs = [ROOT / "configs" / f"{name}.yaml" for name in ("two_link_free_time", "two_link_pose", "two_link_via")]
    with connect(workers=1) as client:
        run = execute_batch([str(c) for c in configs], client, out_dir=tmp_path / "out")
    rows = {Path(r["task"]).name: r for r in run.table.to_pylist()}
    assert run.solved == 3 and all(r["status"] == "converged" for r in rows.values())
    for config in configs:
        p = invoke("plan", config, "-o", tmp_path / "single.csv", "--json", "-q")
        assert p.exit_code == 0, p.output
        single = json.loads(p.stdout)
        r = rows[config.name]
        assert abs(r["cost"] - single["cost"]) <= 1e-12 * abs(single["cost"])
        assert r["T_optimal"] == (single["T"] if "dJ_dT" in single else None)
    assert abs(rows["two_link_free_time.yaml"]["T_optimal"] - 1.5) > 0.1
