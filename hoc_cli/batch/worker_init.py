"""Imported by every worker process of hoc's local Dask cluster as it starts (a Dask worker preload).

Makes the worker ignore SIGINT: a Ctrl-C on a terminal goes to the whole foreground process
group, and only hoc should act on it (it cancels the plans, keeps the rows done and closes the
workers); a worker would otherwise die with a KeyboardInterrupt traceback.

Drops the worker's "Failed to communicate with scheduler during heartbeat" record: the scheduler of hoc's
local cluster lives and closes with hoc, so a heartbeat that finds it gone is only the cluster closing
(e.g. after a signal), and its traceback would follow hoc's one-line message on the shared standard error.
"""
from __future__ import annotations

import logging
import signal

HEARTBEAT_LOST = "Failed to communicate with scheduler during heartbeat"


def _not_a_lost_heartbeat(record: logging.LogRecord) -> bool:
    """False for the worker's lost-heartbeat record (a closing cluster), True for any other."""
    return not str(record.msg).startswith(HEARTBEAT_LOST)


logging.getLogger("distributed.worker").addFilter(_not_a_lost_heartbeat)

try:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
except ValueError:  # not the main thread of the worker process: nothing to do
    pass


def dask_setup(worker) -> None:
    """Dask's preload hook (nothing more to do once the module is imported)."""
