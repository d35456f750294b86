"""``hoc plan --starts K --seed S``: option checks, where the starts run, and their summary keys.

The starts themselves are ``hoc_cli.multistart``. ``hoc plan`` solves start 0 in its own process,
then the other K−1 serially, or on a local Dask cluster (min(cores, K−1) single-threaded worker
processes) when they would take more than ``PARALLEL_STARTS_MIN_S`` serially (judged from start
0's time) and there are 2 cores or more; with ``DASK_SCHEDULER_ADDRESS`` set, on that cluster. The
result is the same either way (each start is deterministic).
"""
from __future__ import annotations

import os
from contextlib import contextmanager
from pathlib import Path

from hoc_cli.errors import TaskError


def starts_summary(multi, seed: int) -> dict:
    """Summary keys of a multi-start solve: the kept start and every start's J and status ({} for one start)."""
    if multi is None:
        return {}
    return {"seed": seed, "best_start": multi.best_index, "starts": [o.as_dict() for o in multi.outcomes]}


#: the most starts of one multi-start solve (each is a whole solve; beyond a few dozen they rarely find a
#: better optimum, and a count like 10^6 would only keep the machine busy for days)
MAX_STARTS = 1000


def check_starts(starts: int, seed: int, init: Path | None, key: str = "--starts", *, scheduler: bool = True) -> None:
    """Refuse a starts count < 1 or > MAX_STARTS, a seed < 0, and multi-start with --init; ``key`` names where
    ``starts`` came from. With ``scheduler`` and more than one start, a ``DASK_SCHEDULER_ADDRESS`` (where
    the starts would run) must answer as a Dask scheduler (``hoc_cli.batch.engine.probe_scheduler``).
    """
    if isinstance(starts, bool) or not isinstance(starts, int) or not 1 <= starts <= MAX_STARTS:
        raise TaskError(f"expected an integer from 1 to {MAX_STARTS}, got {starts!r}", key=key)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise TaskError(f"expected an integer >= 0, got {seed!r}", key="--seed")
    if starts > 1 and init is not None:
        raise TaskError("multi-start cannot be combined with --init (a warm start is a single start)", key=key)
    address = os.environ.get("DASK_SCHEDULER_ADDRESS")
    if scheduler and starts > 1 and address:
        from hoc_cli.batch.engine import CONNECT_TIMEOUT_S, probe_scheduler

        probe_scheduler(address, CONNECT_TIMEOUT_S, "DASK_SCHEDULER_ADDRESS")  # before start 0 is solved


#: multi-start in ``hoc plan``: the remaining starts go to a local Dask cluster only when they would
#: take longer than this serially (the cluster costs about 2-3 s to start) and there is more than one core
PARALLEL_STARTS_MIN_S = 5.0


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
