"""``hoc plan --starts K --seed S``: option checks and where the starts run.

The starts themselves are ``hoc_cli.multistart``. ``hoc plan`` solves start 0 in its own process,
then the other K−1 serially, or on a local Dask cluster (min(cores, K−1) single-threaded worker
processes) when they would take more than ``PARALLEL_STARTS_MIN_S`` serially (judged from start
0's time) and there are 2 cores or more; with ``DASK_SCHEDULER_ADDRESS`` set, on that cluster. The
result is the same either way (each start is deterministic). Their summary keys are
``hoc_cli.report.summary.starts_summary``.
"""
from __future__ import annotations

import os
from contextlib import contextmanager
from pathlib import Path

from hoc_cli.report.inputs import check_starts
from hoc_cli.report.workload import PARALLEL_STARTS_MIN_S


def check_plan_starts(starts: int, seed: int, init: Path | None, key: str = "--starts") -> None:
    """``check_starts``; with more than one start, a ``DASK_SCHEDULER_ADDRESS`` (where the starts would
    run) must also answer as a Dask scheduler (``hoc_cli.batch.engine.probe_scheduler``).
    """
    check_starts(starts, seed, init, key)
    address = os.environ.get("DASK_SCHEDULER_ADDRESS")
    if starts > 1 and address:
        from hoc_cli.batch.engine import CONNECT_TIMEOUT_S, probe_scheduler

        probe_scheduler(address, CONNECT_TIMEOUT_S, "DASK_SCHEDULER_ADDRESS")  # before start 0 is solved


@contextmanager
def starts_pool(t0: float, remaining: int):
    """A Dask client for the remaining starts, or None (serial); see ``PARALLEL_STARTS_MIN_S``."""
    from hoc_cli.batch.engine import available_cores, connect

    cores = available_cores()
    scheduler = os.environ.get("DASK_SCHEDULER_ADDRESS")
    if not scheduler and (cores < 2 or remaining < 2 or t0 * remaining < PARALLEL_STARTS_MIN_S):
        yield None
        return
    with connect(workers=min(cores, remaining), scheduler=scheduler, key="DASK_SCHEDULER_ADDRESS") as client:
        yield client
