"""``hoc batch``: many plans on Dask, tabulated. ``run`` is the Python API.

Example (a notebook with its own cluster)::

    from dask.distributed import Client
    import hoc_cli.batch
    table = hoc_cli.batch.run("sweep.yaml", client=Client("tcp://host:8786"), out_dir="sweep_results")
    table.to_pandas()  # if pandas is installed

Dask, distributed and pyarrow are imported only when a batch runs.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["run", "execute_batch", "BatchRun"]

CHECKPOINT_S = 10.0  # completed rows are written to the results files at least this often
MAX_CHUNK = 8  # plans per Dask task at most; a chunk is one task, so Dask's per-task cost is shared


def chunk_sizes(plans: int, threads: int) -> list[int]:
    """Plans per Dask task, in submission order: guided self-scheduling, summing to ``plans``.

    Each chunk takes ``remaining // (8 * threads)`` plans, between 1 and MAX_CHUNK: large chunks
    while much work remains spread the engine's fixed cost per task (scheduling, transfer: a few ms)
    over several plans; the chunks shrink to single plans towards the end, so that no worker sits
    idle while another finishes a long chunk (with equal chunks of 8 that idle tail cost 13 ms per
    plan on a 200-plan sweep, benchmarks/bench_batch.py). Batches under ``16 * threads`` plans go
    one plan per task.
    """
    sizes: list[int] = []
    remaining = plans
    while remaining > 0:
        size = max(1, min(MAX_CHUNK, remaining // (8 * max(threads, 1))))
        sizes.append(size)
        remaining -= size
    return sizes


@dataclass(eq=False)
class BatchRun:
    """What a batch did. ``table``: every row (resumed and new), sorted by id; ``interrupted``: the
    KeyboardInterrupt or SIGTERM (``Terminated``) that stopped it, after which the rows done were kept.
    """

    table: Any
    total: int
    solved: int
    skipped: int
    failed: int
    not_converged: int
    interrupted: BaseException | None
    wall_time_s: float
    paths: list[Path] = field(default_factory=list)
    duplicates: int = 0


def run(spec: Any, client: Any = None, *, out_dir: str | Path | None = None, resume: bool = False,
        workers: int | None = None, scheduler: str | None = None, connect_timeout: float | None = None):
    """Solve every plan of ``spec`` and return the results as a ``pyarrow.Table`` (one row per plan, by id).

    Parameters
    ----------
    spec : a batch spec file, a parsed spec (mapping or list of task files, paths relative to the
        current directory) or a task file; see ``hoc_cli.batch.spec``.
    client : a ``dask.distributed.Client`` to use; default: an embedded local cluster with
        ``workers`` processes (or ``scheduler``'s cluster), closed at the end.
    out_dir : directory for results.parquet, results.csv and the per-plan outputs; None writes
        nothing (and a spec asking for per-plan outputs is then refused).
    resume : keep the rows already in ``out_dir``'s results (written from the same spec) and solve only the others.
    connect_timeout : seconds to wait for ``scheduler`` to answer (default 10).

    Raises the KeyboardInterrupt after writing the completed rows when interrupted.
    """
    result = execute_batch(spec, client, out_dir=out_dir, resume=resume, workers=workers, scheduler=scheduler,
                           connect_timeout=connect_timeout)
    if result.interrupted is not None:
        raise result.interrupted
    return result.table


def execute_batch(spec: Any, client: Any = None, *, out_dir: str | Path | None = None, resume: bool = False,
                  workers: int | None = None, scheduler: str | None = None, reporter: Any = None,
                  checkpoint_s: float = CHECKPOINT_S, connect_timeout: float | None = None,
                  estimate: bool = False, scheduler_key: str = "--scheduler") -> BatchRun:
    """``run`` with the details: counts, interruption, written paths; ``reporter`` follows progress.

    ``reporter`` (optional) has ``begin(total, skipped, threads)`` and ``row(row)``; ``scheduler_key``
    names where ``scheduler`` came from in messages. Everything that
    can be checked is checked before a cluster starts or a plan is solved, with nothing written:
    the spec (every swept task's keys), the worker count, the scheduler address (it must answer as
    a Dask scheduler within ``connect_timeout`` seconds), the results folder (writable; not in use by
    another batch: it is locked for the run, ``hoc_cli.report.locks.FolderLock``) and, with
    ``resume``, that its results come from this spec. ``estimate`` warns (``hoc: warning:``) when
    the batch is expected to take long (``hoc_cli.report.workload.check_batch_workload``), or
    when it was not and still runs after ``WARN_SECONDS``.
    """
    from contextlib import ExitStack, nullcontext

    from hoc_cli.batch import results
    from hoc_cli.batch.engine import available_cores, check_timeout, check_workers, connect, execute, probe_scheduler, threads
    from hoc_cli.batch.folder import check_folder
    from hoc_cli.batch.job import error_row, solve_jobs
    from hoc_cli.batch.spec import load_spec
    from hoc_cli.errors import OutputError
    from hoc_cli.report.locks import FolderLock
    from hoc_cli.report.status import Status

    start = time.perf_counter()
    batch = load_spec(spec)
    out = Path(out_dir) if out_dir is not None else None
    if out is None and batch.outputs:
        raise OutputError("per-plan outputs need a results directory (out_dir / -o DIR)", key="outputs")
    if out is None and resume:
        raise OutputError("--resume needs a results directory (out_dir / -o DIR)", key="--resume")
    if client is None:
        if scheduler:
            connect_timeout = check_timeout(connect_timeout)
        else:
            check_workers(workers)
    if out is not None:
        check_folder(out, plans=bool(batch.outputs), names=(results.PARQUET, results.CSV))
    identity = batch.identity
    with ExitStack() as held:
        if out is not None and out.is_dir():
            held.enter_context(FolderLock(out))  # before its results are read: no other run changes them
        kept = results.read(out, identity) if (resume and out is not None) else []
        done = {r["id"] for r in kept}
        todo = [job for job in batch.jobs if job.id not in done]
        work = None
        warned = False
        if todo and estimate:
            from hoc_cli.report.workload import WARN_SECONDS, Heartbeat, check_batch_workload, plan_workloads

            work = plan_workloads(todo)
            if client is None and not scheduler:
                warned = check_batch_workload(work, workers or available_cores(), local=True)
        if todo and client is None and scheduler:
            probe_scheduler(scheduler, connect_timeout, scheduler_key)  # a wrong address is refused before anything is written
        if out is not None and not out.is_dir():
            try:
                out.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise OutputError(f"cannot be created ({exc.strerror or type(exc).__name__})", file=out,
                                  key="--output") from None
            held.enter_context(FolderLock(out))
        new: list[dict] = []
        last_write = [time.perf_counter()]

        def save() -> list[Path]:
            if out is None:
                return []
            last_write[0] = time.perf_counter()
            return results.write(out, results.table(kept + new, _sweep_columns(batch)), identity)

        def on_row(job, row: dict) -> None:
            new.append(row)
            if reporter is not None:
                reporter.row(row)
            if out is not None and time.perf_counter() - last_write[0] > checkpoint_s:
                save()

        def on_chunk(chunk, rows: list[dict]) -> None:
            for job, row in zip(chunk, rows):
                on_row(job, row)

        def on_error(chunk, exc: BaseException) -> None:
            for job in chunk:
                on_row(job, error_row(job, f"the Dask task failed ({type(exc).__name__}: {str(exc)[:200]})"))

        interrupted = None
        if todo:
            args = (os.path.abspath(out) if out is not None else None, batch.outputs)
            cm = (_borrowed(client) if client is not None
                  else connect(workers=workers, scheduler=scheduler, timeout=connect_timeout, key=scheduler_key))
            with cm as c:
                n_threads = threads(c)
                if work is not None and (client is not None or scheduler):
                    warned = check_batch_workload(work, n_threads, local=False)
                # a batch the estimate did not announce says so if it still runs after WARN_SECONDS
                overdue = Heartbeat(None, False, start=start, overdue=WARN_SECONDS) if work is not None and not warned else None
                if reporter is not None:
                    reporter.begin(len(todo), len(kept), n_threads)
                chunks, i = [], 0
                for size in chunk_sizes(len(todo), n_threads):
                    chunks.append(todo[i:i + size])
                    i += size
                with overdue or nullcontext():
                    interrupted = execute(c, solve_jobs, chunks, key=lambda ch: ch[0].id, args=args,
                                          on_result=on_chunk, on_error=on_error)
        elif reporter is not None:
            reporter.begin(0, len(kept), 0)
        paths = save()
    rows = kept + new
    return BatchRun(
        table=results.table(rows, _sweep_columns(batch)), total=len(batch.jobs), solved=len(new), skipped=len(kept),
        failed=sum(r.get("status") == Status.ERROR.value for r in rows),
        not_converged=sum(r.get("status") != Status.ERROR.value and not r.get("converged") for r in rows),
        interrupted=interrupted, wall_time_s=time.perf_counter() - start, paths=paths,
        duplicates=batch.duplicates)


def _sweep_columns(batch) -> list[str]:
    from hoc_cli.batch.results import column_name

    return [column_name(k) for k in batch.sweep_keys]


class _borrowed:
    """A caller's client as a context manager that does not close it."""

    def __init__(self, client: Any) -> None:
        self.client = client

    def __enter__(self) -> Any:
        return self.client

    def __exit__(self, *exc: Any) -> None:
        return None
