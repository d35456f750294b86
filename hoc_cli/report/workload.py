"""How heavy a ``hoc plan`` run is, before it starts; progress lines while a long step runs.

``estimate_workload`` predicts the wall time and peak memory of a run from the number of
elements N, the Gauss points per element G, the joints n, the multi-start count and the output
samples (T·rate per output file). The formula and the measurements it was fitted to are in
docs/design.md ("Work estimate"); ``benchmarks/bench_workload.py`` repeats them. It is an
order-of-magnitude estimate: the iteration count depends on the task (the shipped 7-DOF tasks
differ by 8× at equal N and n), the per-iteration cost does not.

``check_workload`` warns (one ``hoc: warning:`` line on standard error, silenced by ``-q``) when
a run is expected to take more than ``WARN_SECONDS`` or ``WARN_BYTES``. ``Heartbeat`` prints a
progress line whenever nothing else was reported for ``interval`` seconds (``--progress``).
"""
from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from hoc_cli.report.console import warn

WARN_SECONDS = 10.0  # warn when a run is expected to take longer [s]
WARN_BYTES = 2 * 2**30  # or to need more memory [B]

# Calibration (docs/design.md, "Work estimate"; measured with BLAS on one thread, as hoc runs).
STARTUP_S = 0.6  # interpreter, imports, URDF and task [s]
NEWTON_S = (14e-6, 8e-8)  # one Newton matrix, per element at G_h = 6 points: a·n² + b·n³ [s]
EVAL_S = (8e-6, 0.5e-6)  # one cost + gradient, per element at G = 8 points: a·n + b·n² [s]
EVALS_PER_ITERATION = 3.5  # line-search evaluations per iteration (measured 2.3 to 3.7)
CALL_S = 1.5e-3  # per iteration and joint: the per-link Python loops of the batched dynamics [s]
WORK_ITERATIONS = (16.0, 0.25)  # iteration-equivalents on the finest mesh, solve and error estimate: a + b·n²
BASE_BYTES = 100e6  # resident memory of a small run [B]
ELEMENT_BYTES = (18e3, 5.6e3)  # peak per element of the error estimate's 2N-element solve: a·n + b·n² [B]
SAMPLE_S = {"csv": (6e-6, 6e-6), "mcap": (140e-6, 10e-6)}  # per output sample: a + b·n [s]
SAMPLE_BYTES = {"csv": 120.0, "mcap": 370.0}  # per output sample and value (1 + 4n values) [B]
#: multi-start in ``hoc plan``: the remaining starts go to a local Dask cluster only when they would
#: take longer than this serially (the cluster costs about 2-3 s to start) and there is more than one core
PARALLEL_STARTS_MIN_S = 5.0


@dataclass(frozen=True)
class Workload:
    """The expected cost of one run.

    seconds : wall time [s]; bytes : peak resident memory [B]; N, G, n : elements, Gauss points per
    element, joints; samples : output samples per file (T·rate + 1).
    """

    seconds: float
    bytes: float
    N: int
    G: int
    n: int
    samples: int
    starts: int = 1

    @property
    def heavy(self) -> bool:
        """Whether the run is expected to take more than ``WARN_SECONDS`` or ``WARN_BYTES``."""
        return self.seconds > WARN_SECONDS or self.bytes > WARN_BYTES

    def describe(self) -> str:
        """One line: what is expected and what makes it heavy."""
        starts = f"{self.starts} starts, " if self.starts > 1 else ""
        fewer = "fewer starts (--starts), " if self.starts > 1 else ""
        return (f"this plan is expected to take about {duration(self.seconds)} and {size(self.bytes)} of memory "
                f"({starts}N = {self.N} elements × G = {self.G} Gauss points, n = {self.n} joints, {self.samples} "
                f"output samples; a rough estimate, see docs/design.md); {fewer}fewer elements (-N), joints (locked:) "
                "or a lower output.rate make it lighter")


def gauss_points(order: str) -> tuple[int, int]:
    """(G, G_h): Gauss points per element of the cost and of the Newton matrix (``hoc_cli.problem``)."""
    from hoc_cli.problem import default_gauss_points

    m = 3 if order == "quintic" else 2
    G = default_gauss_points(order)
    return G, min(G, m + 3)


def estimate_workload(*, n: int, N: int, order: str, T: float, rate: float, csv: int = 0, mcap: int = 0,
                      max_iter: int = 5000, starts: int = 1, cores: int = 1) -> Workload:
    """The expected wall time and peak memory of ``hoc plan`` (docs/design.md, "Work estimate").

    Parameters
    ----------
    n : joints; N : elements (the finest mesh); order : "quintic" or "cubic"
    T : duration [s]; rate : output sample rate [Hz]
    csv, mcap : how many CSV and MCAP outputs are written
    max_iter : the iteration limit (caps the iteration count); starts : multi-start solves
    cores : cores available to the starts after the first (``hoc_cli.commands.starts.starts_pool`` runs
        them on a local cluster of min(cores, starts − 1) workers when that pays off)

    Returns
    -------
    Workload
    """
    G, G_h = gauss_points(order)
    newton = (NEWTON_S[0] * n**2 + NEWTON_S[1] * n**3) * G_h / 6
    evaluation = (EVAL_S[0] * n + EVAL_S[1] * n**2) * G / 8
    per_iteration = N * (newton + EVALS_PER_ITERATION * evaluation) + CALL_S * n
    iterations = min(WORK_ITERATIONS[0] + WORK_ITERATIONS[1] * n**2, 3.0 * max_iter + 4.0)
    samples = int(T * rate) + 1
    writing = {kind: count * samples for kind, count in (("csv", csv), ("mcap", mcap))}
    one = iterations * per_iteration
    seconds = (STARTUP_S + one + starts_seconds(one, starts, cores)
               + sum(k * (SAMPLE_S[kind][0] + SAMPLE_S[kind][1] * n) for kind, k in writing.items()))
    solve_bytes = 2 * N * (ELEMENT_BYTES[0] * n + ELEMENT_BYTES[1] * n**2) * G_h / 6
    output_bytes = sum(k * SAMPLE_BYTES[kind] * (1 + 4 * n) for kind, k in writing.items())
    return Workload(seconds=seconds, bytes=BASE_BYTES + max(solve_bytes, output_bytes), N=N, G=G, n=n,
                    samples=samples, starts=max(starts, 1))


def starts_seconds(one: float, starts: int, cores: int) -> float:
    """Wall time [s] of the starts after the first, each taking ``one`` seconds: serial, or on a local
    cluster of min(cores, starts − 1) workers (plus its start-up) when they would take longer than
    ``PARALLEL_STARTS_MIN_S`` serially, as ``hoc plan`` decides.
    """
    rest = max(starts, 1) - 1
    serial = rest * one
    if cores < 2 or rest < 2 or serial < PARALLEL_STARTS_MIN_S:
        return serial
    workers = min(cores, rest)
    return CLUSTER_START_S[0] + CLUSTER_START_S[1] * workers + serial / workers


def check_workload(task, n: int, targets, *, N: int, starts: int = 1, cores: int = 1) -> Workload:
    """Estimate a task's run before the solve; warn (``hoc: warning:``, silenced by ``-q``) when it is heavy.

    ``task`` a loaded Task, ``n`` its joints, ``targets`` the OutputTargets, ``N`` the elements (for
    ``N: auto`` the first mesh, so the estimate is a lower bound), ``cores`` those available to the
    starts after the first.
    """
    kinds = [t.kind for t in targets]
    work = estimate_workload(n=n, N=N, order=task.order, T=task.T, rate=task.rate, csv=kinds.count("csv"),
                             mcap=kinds.count("mcap"), max_iter=task.max_iter, starts=starts, cores=cores)
    if work.heavy:
        warn(work.describe())
    return work


def duration(seconds: float) -> str:
    """'8 s', '4 min', '2.5 h', '3 days'."""
    if seconds < 100:
        return f"{seconds:.0f} s"
    if seconds < 6000:
        return f"{seconds / 60:.0f} min"
    if seconds < 2 * 86400:
        return f"{seconds / 3600:.2g} h"
    return f"{seconds / 86400:.2g} days"


def size(nbytes: float) -> str:
    """'120 MB', '2.4 GB' (powers of 1000)."""
    return f"{nbytes / 1e6:.0f} MB" if nbytes < 1e9 else f"{nbytes / 1e9:.2g} GB"


class Heartbeat:
    """Progress lines on ``console`` while a long step runs: after ``interval`` seconds without any
    (``tick`` or ``say``), one line saying what is still running, then one every ``interval`` seconds.

    Disabled (no thread, no output) unless ``enabled`` or ``overdue``. ``with beat:`` or ``with
    beat.phase(text):`` runs the watcher thread for the block; ``tick(status)`` records other progress
    (an iteration line). ``overdue`` [s]: once the run has lasted that long (since ``start``), one
    ``hoc: warning:`` line says so, progress lines or not: for a run whose estimate promised less
    (``check_workload`` did not warn), so that no run goes on past ``WARN_SECONDS`` unannounced.
    """

    def __init__(self, console, enabled: bool, *, start: float | None = None, interval: float = 3.0,
                 overdue: float | None = None) -> None:
        self.console, self.enabled, self.interval, self.overdue = console, enabled, interval, overdue
        self.start = time.perf_counter() if start is None else start
        self.status = "solving"
        self.last = time.perf_counter()
        self._stop: threading.Event | None = None
        self._thread: threading.Thread | None = None

    def tick(self, status: str | None = None) -> None:
        """Other progress was reported now; ``status`` says what runs (shown by the next heartbeat)."""
        self.last = time.perf_counter()
        if status is not None:
            self.status = status

    def say(self, status: str) -> None:
        """A progress line now (when enabled): ``status`` and the time since ``start``."""
        self.tick(status)
        if self.enabled:
            self._print(status)

    @contextlib.contextmanager
    def phase(self, status: str | None) -> Iterator[None]:
        """Announce ``status`` (unless None) and watch the block."""
        if status is not None:
            self.say(status)
        with self:
            yield

    def __enter__(self) -> Heartbeat:
        if (self.enabled or self.overdue is not None) and self._thread is None:
            self._stop = threading.Event()
            self._thread = threading.Thread(target=self._watch, args=(self._stop,), name="hoc-heartbeat",
                                            daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        if self._thread is not None:
            self._stop.set()
            self._thread.join()
            self._thread = self._stop = None

    def _watch(self, stop: threading.Event) -> None:
        while True:  # checked at once (a phase entered late may already be overdue), then every half second
            if self.overdue is not None and time.perf_counter() - self.start >= self.overdue:
                self.overdue = None
                warn(f"this run has taken {duration(time.perf_counter() - self.start)} so far, longer than its "
                     f"estimate (the iteration count depends on the task; --progress shows it); Ctrl-C stops it")
            if self.enabled and time.perf_counter() - self.last >= self.interval:
                self.last = time.perf_counter()
                self._print(f"still {self.status}")
            if stop.wait(min(0.5, self.interval / 2)):
                return

    def _print(self, text: str) -> None:
        try:
            self.console.print(f"{text} {time.perf_counter() - self.start:6.2f}s", highlight=False, markup=False,
                               soft_wrap=True)
        except (OSError, ValueError):  # a closed terminal or pipe is not a failure of the plan
            pass


# --- hoc batch ----------------------------------------------------------------------------------

CLUSTER_START_S = (1.0, 0.5)  # a local cluster's start: a + b per worker process [s]
WORKER_BYTES = 150e6  # resident memory of one idle worker process [B]


@dataclass(frozen=True)
class BatchWorkload:
    """The expected cost of the plans of a batch, before the cluster is known.

    plans : how many; seconds : their solve times summed (each without the interpreter's start-up) [s];
    bytes : the largest peak of one plan [B]; invalid : plans whose task could not be parsed here (their
    worker reports why; counted as nothing).
    """

    plans: int
    seconds: float
    bytes: float
    invalid: int = 0

    def on(self, workers: int, *, local: bool) -> tuple[float, float]:
        """(wall time [s], peak memory [B]) of the batch on ``workers`` single-threaded workers."""
        workers = max(int(workers), 1)
        wall = self.seconds / min(workers, max(self.plans, 1))
        if local:
            wall += CLUSTER_START_S[0] + CLUSTER_START_S[1] * workers
        return wall, BASE_BYTES + workers * (WORKER_BYTES + max(self.bytes - BASE_BYTES, 0.0))


def plan_workloads(jobs, sample: int = 2000) -> BatchWorkload:
    """The summed estimate of batch jobs (``hoc_cli.batch.spec.Job``), each as ``estimate_workload``
    would give for ``hoc plan`` of its task; the URDF of each robot is read once. Of more than
    ``sample`` jobs, ``sample`` evenly spaced ones are estimated and the sums scaled (a sweep's
    jobs differ only in their swept values).
    """
    jobs = list(jobs)
    if len(jobs) > sample:
        picked = [jobs[i * len(jobs) // sample] for i in range(sample)]
        part = plan_workloads(picked, sample)
        scale = len(jobs) / sample
        return BatchWorkload(plans=len(jobs), seconds=part.seconds * scale, bytes=part.bytes,
                             invalid=round(part.invalid * scale))
    from hoc_cli.accuracy import AUTO_START
    from hoc_cli.errors import HocError
    from hoc_cli.io.task import parse_task

    joints: dict = {}
    seconds = peak = 0.0
    invalid = 0
    for job in jobs:
        try:
            task = parse_task(job.doc, path=Path(job.source), text="", purpose="plan")
            key = (str(task.robot), task.joints, tuple(sorted(task.locked.items())) if task.locked else ())
            if key not in joints:
                from hoc_cli.io.robot import load_model

                joints[key] = load_model(task).n
        except (HocError, TypeError, ValueError, AttributeError):
            invalid += 1
            continue
        starts = job.starts if job.starts is not None else task.solver.starts
        T = task.T if task.time.free is None else task.time.free.max
        work = estimate_workload(n=joints[key], N=task.N or AUTO_START, order=task.order, T=T, rate=task.rate,
                                 max_iter=task.max_iter, starts=starts)
        seconds += work.seconds - STARTUP_S
        peak = max(peak, work.bytes)
    return BatchWorkload(plans=len(jobs), seconds=seconds, bytes=peak, invalid=invalid)


def check_batch_workload(work: BatchWorkload, workers: int, *, local: bool) -> bool:
    """Warn (``hoc: warning:``, silenced by ``-q``) when a batch is expected to take more than
    ``WARN_SECONDS`` or ``WARN_BYTES`` on ``workers`` workers; returns whether it warned.
    """
    seconds, nbytes = work.on(workers, local=local)
    heavy = seconds > WARN_SECONDS or nbytes > WARN_BYTES
    if heavy:
        each = work.seconds / max(work.plans - work.invalid, 1)
        warn(f"this batch is expected to take about {duration(seconds)} and {size(nbytes)} of memory ({work.plans} "
             f"plans of about {duration(each) if each >= 1 else f'{each:.2g} s'} each on {workers} worker"
             f"{'s' if workers != 1 else ''}; a rough estimate, see docs/design.md); Ctrl-C stops it and keeps "
             "the plans done (then --resume)")
    return heavy
