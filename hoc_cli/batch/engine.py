"""Dask plumbing: a client (embedded local cluster or a running scheduler) and the job loop.

Imported only by batch code and multi-start, so that ``hoc plan`` does not pay for importing Dask.
"""
from __future__ import annotations

import logging
import os
import signal
import uuid
from contextlib import contextmanager
from typing import Any, Callable, Iterator, Sequence

from hoc_cli.errors import HocError

CONNECT_TIMEOUT_S = 10


class SchedulerError(HocError):
    """The Dask scheduler given by --scheduler (or DASK_SCHEDULER_ADDRESS) cannot be reached."""


def available_cores() -> int:
    """Cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


@contextmanager
def connect(workers: int | None = None, scheduler: str | None = None) -> Iterator[Any]:
    """A ``distributed.Client``: to ``scheduler`` if given, else to an embedded ``LocalCluster``.

    The local cluster has ``workers`` worker processes (default: one per core) of one thread each
    (the solver is single-threaded numpy; Dask's nanny sets OMP/MKL/OpenBLAS threads to 1), listens
    on 127.0.0.1 only and has no dashboard (its HTTP endpoint takes a free port, so that a cluster
    already running on 8787 is no conflict). Both are closed on exit.
    """
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT_S, set_as_default=False)
        except (OSError, TimeoutError, ValueError) as exc:
            raise SchedulerError(f"cannot connect to the Dask scheduler at {scheduler!r} ({type(exc).__name__}; "
                                 "expected a running 'dask scheduler', e.g. tcp://host:8786)",
                                 key="--scheduler") from None
        try:
            yield client
        finally:
            client.close()
        return
    import dask

    # Dask's nanny starts workers with MALLOC_TRIM_THRESHOLD_=65536, which fixes glibc's mmap threshold
    # at 128 KiB: every larger numpy temporary is then mmapped and faulted in afresh, and hoc's solves
    # run about 2x slower (measured: benchmarks/bench_batch.py). Unset it for hoc's workers.
    with _sigint_ignored(), dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}):
        # SIGINT ignored: the workers inherit it, so Ctrl-C on a terminal reaches only hoc, which cancels
        cluster = LocalCluster(n_workers=workers or available_cores(), threads_per_worker=1, processes=True,
                               host="127.0.0.1", dashboard_address=None, silence_logs=logging.ERROR,
                               scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"})
    try:
        with Client(cluster, set_as_default=False) as client:
            yield client
    finally:
        cluster.close()


@contextmanager
def _sigint_ignored() -> Iterator[None]:
    """SIGINT ignored while worker processes start (a child started with SIGINT ignored keeps ignoring it).

    A Ctrl-C on a terminal goes to the whole foreground process group; without this every worker
    would print a KeyboardInterrupt traceback. The cost: a Ctrl-C during the cluster's start-up is lost.
    """
    try:
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:  # not the main thread: nothing to do
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def threads(client: Any) -> int:
    """Worker threads of the cluster (what can run at once)."""
    return max(sum(client.nthreads().values()), 1)


def execute(client: Any, fn: Callable, items: Sequence, *, key: Callable[[Any], str], args: tuple = (),
            on_result: Callable[[Any, Any], None], on_error: Callable[[Any, BaseException], None]) -> bool:
    """Run ``fn(item, *args)`` for every item on the cluster; call back as each finishes, in any order.

    ``on_result(item, value)``, or ``on_error(item, exception)`` when the task itself failed (a
    worker died, the result could not be sent back...). Returns the KeyboardInterrupt (or hoc's
    SIGTERM ``Terminated``) that stopped the loop, None when every task finished: the outstanding
    tasks are then cancelled; the completed ones were all reported.
    """
    from distributed import as_completed

    from hoc_cli.commands.common import Terminated

    run_id = uuid.uuid4().hex[:8]
    futures = client.map(fn, list(items), *[[a] * len(items) for a in args],
                         key=[f"hoc-{run_id}-{key(item)}" for item in items], pure=False)
    owner = dict(zip((f.key for f in futures), items))
    pending = set(futures)
    try:
        for fut in as_completed(futures, loop=client.loop):
            pending.discard(fut)
            item = owner[fut.key]
            if fut.status == "finished":
                on_result(item, fut.result())
            else:
                on_error(item, fut.exception())
            fut.release()
    except (KeyboardInterrupt, Terminated) as exc:
        client.cancel(list(pending))
        return exc
    except BaseException:
        client.cancel(list(pending))
        raise
    return None
