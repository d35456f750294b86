"""``hoc batch``: solve a sweep (or a list of task files) on Dask and write the results table."""
from __future__ import annotations

import glob
import logging
import os
from pathlib import Path

from hoc_cli.commands.common import EXIT_OK, EXIT_SIGINT, EXIT_SIGTERM, EXIT_UNMET
from hoc_cli.report.console import report_error, stderr_console
from hoc_cli.report.files import Terminated
from hoc_cli.report.jsonio import print_json
from hoc_cli.report.status import MESSAGES, Status


def run(specs: list[Path], *, out_dir: Path | None = None, workers: int | None = None, scheduler: str | None = None,
        resume: bool = False, as_json: bool = False, quiet: bool = False, progress: bool = False,
        connect_timeout: float | None = None) -> int:
    from hoc_cli.batch import execute_batch

    spec, stem = _spec_argument(specs)
    out = out_dir if out_dir is not None else Path(f"{stem}_batch")
    from hoc_cli.batch.engine import check_timeout, parse_address

    check_timeout(connect_timeout)  # given without --scheduler too: a wrong value is still an error
    key = "--scheduler" if scheduler is not None else "DASK_SCHEDULER_ADDRESS"
    if scheduler is not None:
        parse_address(scheduler, key)  # '' or '  ' is not an address either
    scheduler = scheduler or os.environ.get("DASK_SCHEDULER_ADDRESS") or None
    logging.getLogger("distributed").setLevel(logging.ERROR)  # the client's own chatter; errors are rows
    console = stderr_console(quiet=quiet, progress=progress)
    reporter = _Reporter(console) if not quiet and (progress or console.is_terminal) else None
    try:
        result = execute_batch(spec, out_dir=out, resume=resume, workers=workers, scheduler=scheduler,
                               reporter=reporter, connect_timeout=connect_timeout, estimate=True,
                               scheduler_key=key)
    finally:
        if reporter is not None:
            reporter.close()
    summary = {
        "plans": result.total, "solved": result.solved, "resumed": result.skipped, "errors": result.failed,
        "not_converged": result.not_converged, "interrupted": result.interrupted is not None,
        "duplicates_dropped": result.duplicates, "results": [str(p) for p in result.paths],
        "scheduler": scheduler or "local", "wall_time_s": result.wall_time_s,
    }
    if as_json:
        print_json(summary)
    if not quiet:
        console.print(f"hoc batch: {result.total} plans: {result.solved} solved, {result.skipped} resumed, "
                      f"{result.failed} {MESSAGES[Status.ERROR].counted}, {result.not_converged} "
                      f"{MESSAGES[Status.NOT_CONVERGED].counted}; results in {out} "
                      f"({result.wall_time_s:.1f} s)", highlight=False, markup=False, soft_wrap=True)
    if result.interrupted is not None:
        term = isinstance(result.interrupted, Terminated)
        report_error(f"{'terminated' if term else 'interrupted'}; the {result.solved} plans completed are kept in "
                     f"{out} (rerun with --resume)")
        return EXIT_SIGTERM if term else EXIT_SIGINT
    return EXIT_OK if result.failed == 0 and result.not_converged == 0 else EXIT_UNMET


def _spec_argument(specs: list[Path]) -> tuple[object, str]:
    """One spec file, or task files / globs (expanded here for shells that pass them quoted)."""
    if len(specs) == 1 and not glob.has_magic(str(specs[0])):
        return specs[0], specs[0].stem
    return [str(p) for p in specs], "batch"


class _Reporter:
    """A rich progress bar on standard error: done/total, failed, running, elapsed, ETA."""

    def __init__(self, console) -> None:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

        self.progress = Progress(TextColumn("hoc batch"), BarColumn(), MofNCompleteColumn(),
                                 TextColumn("failed {task.fields[failed]}  running {task.fields[running]}"),
                                 TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(), console=console)
        self.task = None
        self.failed = self.done = self.total = self.threads = 0

    def begin(self, total: int, skipped: int, threads: int) -> None:
        self.total, self.threads = total, threads
        self.progress.start()
        self.task = self.progress.add_task("plans", total=total, failed=0, running=min(total, threads))

    def row(self, row: dict) -> None:
        self.done += 1
        self.failed += row.get("status") == Status.ERROR.value
        self.progress.update(self.task, advance=1, failed=self.failed,
                             running=min(self.total - self.done, self.threads))

    def close(self) -> None:
        self.progress.stop()
