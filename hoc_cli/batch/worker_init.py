"""Imported by every worker process of hoc's local Dask cluster as it starts (a Dask worker preload).

Makes the worker ignore SIGINT: a Ctrl-C on a terminal goes to the whole foreground process
group, and only hoc should act on it (it cancels the plans, keeps the rows done and closes the
workers); a worker would otherwise die with a KeyboardInterrupt traceback.
"""
from __future__ import annotations

import signal

try:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
except ValueError:  # not the main thread of the worker process: nothing to do
    pass


def dask_setup(worker) -> None:
    """Dask's preload hook (nothing more to do once the module is imported)."""
