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

from hoc_cli.errors import HocError, TaskError
from hoc_cli.report.files import TERMINATING, signal_handlers

CONNECT_TIMEOUT_S = 10.0  # default of --connect-timeout [s]
WORKERS_PER_CORE = 4  # --workers at most this many worker processes per available core
#: the first message a Dask scheduler sends on a new connection (its handshake) is a few hundred bytes
MAX_HANDSHAKE_BYTES = 1 << 20
SCHEMES = ("tcp", "tls")


class SchedulerError(HocError):
    """The Dask scheduler given by --scheduler (or DASK_SCHEDULER_ADDRESS) cannot be reached."""


def available_cores() -> int:
    """Cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def max_workers() -> int:
    """The largest --workers accepted: ``WORKERS_PER_CORE`` per available core (more only slows every plan)."""
    return WORKERS_PER_CORE * available_cores()


def check_workers(workers: int | None, key: str = "--workers") -> None:
    """TaskError (exit 2) for a worker count < 1 or above ``max_workers()``, before any process starts."""
    if workers is None:
        return
    top = max_workers()
    if isinstance(workers, bool) or not isinstance(workers, int) or not 1 <= workers <= top:
        raise TaskError(f"expected an integer from 1 to {top} ({WORKERS_PER_CORE} per core on the "
                        f"{available_cores()} cores available), got {workers!r}", key=key)


def check_timeout(seconds: float | None, key: str = "--connect-timeout") -> float:
    """The connection timeout [s]: ``seconds`` (0 < seconds <= 1 day), default ``CONNECT_TIMEOUT_S``."""
    if seconds is None:
        return CONNECT_TIMEOUT_S
    if isinstance(seconds, bool) or not isinstance(seconds, (int, float)) or not 0 < seconds <= 86400:
        raise TaskError(f"expected a number of seconds > 0 and at most 86400, got {seconds!r}", key=key)
    return float(seconds)


def parse_address(address: str, key: str = "--scheduler") -> tuple[str, str, int]:
    """(scheme, host, port) of a scheduler address ``tcp://host:port``, ``tls://host:port`` or ``host:port``.

    Raises SchedulerError (exit 2) naming ``key`` for anything else.
    """
    expected = "expected a Dask scheduler address such as tcp://host:8786"
    text = address.strip() if isinstance(address, str) else ""
    scheme, sep, rest = text.partition("://")
    if not sep:
        scheme, rest = "tcp", text
    host, colon, port = rest.rpartition(":")
    if host.startswith("[") and host.endswith("]"):  # an IPv6 literal
        host = host[1:-1]
    bad = (scheme not in SCHEMES or not colon or not host or not port.isdigit() or not 0 < int(port) < 65536
           or any(c.isspace() or c in "/?#@" for c in host))
    if bad:
        shown = repr(address) if len(repr(address)) <= 60 else repr(address)[:57] + "..."
        raise SchedulerError(f"{expected}, got {shown}", key=key)
    return scheme, host, int(port)


def probe_scheduler(address: str, timeout: float, key: str = "--scheduler") -> None:
    """Check, within ``timeout`` seconds, that a Dask scheduler listens at ``address``; SchedulerError if not.

    A Dask scheduler speaks first: on a new connection it sends its handshake, an 8-byte
    little-endian length and a small msgpack message naming its ``pickle-protocol``. Anything else
    (an HTTP server waiting for a request, a service sending its own banner, a closed port, nothing
    within ``timeout``) is refused here, so that Dask itself never waits on it or reads a banner
    as a message length. For ``tls://`` only the TCP connection is checked (the handshake is encrypted).
    """
    import socket
    import struct
    import time

    scheme, host, port = parse_address(address, key)
    deadline = time.monotonic() + timeout
    where = f"the Dask scheduler at {address!r}"

    def fail(what: str) -> SchedulerError:
        return SchedulerError(f"cannot connect to {where}: {what} (expected a running 'dask scheduler', "
                              f"e.g. tcp://host:8786; --connect-timeout sets the wait)", key=key)

    try:
        sock = socket.create_connection((host, port), timeout=timeout)
    except socket.timeout:
        raise fail(f"no answer within {timeout:g} s") from None
    except OSError as exc:
        raise fail(exc.strerror or type(exc).__name__) from None
    try:
        if scheme != "tcp":
            return
        head = _receive(sock, 8, deadline)
        if head is None:
            raise fail(f"no Dask handshake within {timeout:g} s")
        if len(head) < 8:
            raise fail("it closed the connection without a Dask handshake")
        (length,) = struct.unpack("<Q", head)
        if not 0 < length <= MAX_HANDSHAKE_BYTES:
            shown = head.decode("ascii", "replace").strip()
            raise fail(f"it is not a Dask scheduler (it answered {shown!r}...)")
        body = _receive(sock, length, deadline)
        if body is None or len(body) < length or b"pickle-protocol" not in body:
            raise fail("it is not a Dask scheduler (its first message is not a Dask handshake)")
    finally:
        sock.close()


def _receive(sock, size: int, deadline: float) -> bytes | None:
    """Up to ``size`` bytes from ``sock`` before ``deadline`` (monotonic); fewer if it closes; None on time-out."""
    import socket
    import time

    data = b""
    while len(data) < size:
        left = deadline - time.monotonic()
        if left <= 0:
            return None
        sock.settimeout(left)
        try:
            chunk = sock.recv(size - len(data))
        except socket.timeout:
            return None
        except OSError:
            break
        if not chunk:
            break
        data += chunk
    return data


@contextmanager
def connect(workers: int | None = None, scheduler: str | None = None, *, timeout: float | None = None,
            key: str = "--scheduler") -> Iterator[Any]:
    """A ``distributed.Client``: to ``scheduler`` if given, else to an embedded ``LocalCluster``.

    The scheduler is probed first (``probe_scheduler``) within ``timeout`` seconds (default
    ``CONNECT_TIMEOUT_S``); ``key`` names where the address came from in messages. The local
    cluster has ``workers`` worker processes (default: one per core; at most ``max_workers()``) of
    one thread each (the solver is single-threaded numpy; Dask's nanny sets OMP/MKL/OpenBLAS
    threads to 1), listens on 127.0.0.1 only and has no dashboard (its HTTP endpoint takes a free
    port, so that a cluster already running on 8787 is no conflict). Both are closed on exit.
    A SIGINT, SIGTERM or SIGHUP while the cluster starts takes effect once it has started (it is
    then closed and the signal's exception raised): see ``_signals_deferred``.
    """
    timeout = check_timeout(timeout)
    if scheduler:
        probe_scheduler(scheduler, timeout, key)
        from distributed import Client

        try:
            client = Client(scheduler, timeout=timeout, set_as_default=False)
        except Exception as exc:  # noqa: BLE001 - whatever Dask raises is one line
            raise SchedulerError(f"cannot connect to the Dask scheduler at {scheduler!r} ({type(exc).__name__}: "
                                 f"{str(exc)[:120]})", key=key) from None
        with _closing(client):
            if not client.nthreads():
                try:
                    client.wait_for_workers(1, timeout=timeout)
                except Exception:  # noqa: BLE001 - dask's TimeoutError (or the scheduler went away)
                    raise SchedulerError(f"the Dask scheduler at {scheduler!r} has no workers (none joined within "
                                         f"{timeout:g} s; expected workers started with 'dask worker {scheduler}'; "
                                         "--connect-timeout sets the wait)", key=key) from None
            yield client
        return
    check_workers(workers)
    import dask
    from distributed import Client, LocalCluster

    # Dask's nanny starts workers with MALLOC_TRIM_THRESHOLD_=65536, which fixes glibc's mmap threshold
    # at 128 KiB: every larger numpy temporary is then mmapped and faulted in afresh, and hoc's solves
    # run about 2x slower (measured: benchmarks/bench_batch.py). Unset it for hoc's workers.
    cluster = None
    preloads = list(dask.config.get("distributed.worker.preload", None) or [])
    try:
        # The workers ignore SIGINT (hoc_cli.batch.worker_init): a Ctrl-C on a terminal reaches the whole
        # process group, and only hoc acts on it (it cancels, keeps the rows done and closes the workers).
        with _signals_deferred(), dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
                                                   "distributed.worker.preload": [*preloads, "hoc_cli.batch.worker_init"]}):
            cluster = LocalCluster(n_workers=workers or available_cores(), threads_per_worker=1, processes=True,
                                   host="127.0.0.1", dashboard_address=None, silence_logs=logging.ERROR,
                                   scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"})
        with _closing(Client(cluster, set_as_default=False)) as client:
            yield client
    finally:
        if cluster is not None:
            with _dask_quiet():
                cluster.close()


@contextmanager
def _dask_quiet() -> Iterator[None]:
    """No log records of Dask's while a client or cluster closes (every handler on the way raised above
    CRITICAL): closing after cancelled work, e.g. on Ctrl-C, makes its scheduler log every message it can
    no longer send; what hoc has to say about the run is its own one line.
    """
    handlers = [*logging.getLogger("distributed").handlers, *logging.getLogger().handlers]
    levels = [h.level for h in handlers]
    last_resort = logging.lastResort
    for h in handlers:
        h.setLevel(logging.CRITICAL + 1)
    logging.lastResort = None
    try:
        yield
    finally:
        for h, level in zip(handlers, levels):
            h.setLevel(level)
        logging.lastResort = last_resort


@contextmanager
def _closing(client: Any) -> Iterator[Any]:
    """``client`` for the block, closed after it without Dask's closing chatter."""
    try:
        yield client
    finally:
        with _dask_quiet():
            client.close()


@contextmanager
def _signals_deferred() -> Iterator[None]:
    """SIGINT, SIGTERM and SIGHUP held back while the worker processes start, then delivered.

    A signal that arrives in the block is recorded and sent again to this process once the block
    is left, with the handlers it had before (``run_guarded``'s: KeyboardInterrupt or
    ``Terminated``), so that a half-started cluster is never left behind: ``connect`` then closes
    it. The cluster starts in a few seconds (``max_workers`` bounds the count).
    """
    held = (signal.SIGINT, *TERMINATING)
    caught: list[int] = []

    def record(signum: int, frame: Any) -> None:
        caught.append(signum)

    try:
        with signal_handlers(held, record):  # not the main thread: nothing to do
            yield
    finally:
        for sig in dict.fromkeys(caught):
            signal.raise_signal(sig)


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

    from hoc_cli.report.files import Terminated

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
