"""Signals held during the renames and the making of a temporary file, even when another thread takes them.

A process signal goes to any thread that does not block it; Python then runs its handler in the main
thread at once, whatever the main thread's mask. ``report.files`` holds the handlers it installs
(``signal_handlers``) for the length of a ``_signals_blocked`` block and runs the first one at its end.
"""
from __future__ import annotations

import os
import signal
import threading
import time

import pytest

from hoc_cli.report import files

pytestmark = pytest.mark.skipif(not hasattr(signal, "pthread_sigmask"), reason="POSIX signal masks needed")


class Stop(BaseException):
    pass


def _raise(signum, frame):
    raise Stop(signum)


def test_a_signal_taken_by_another_thread_is_handled_at_the_end_of_the_block():
    go, sent = threading.Event(), threading.Event()

    def sender():  # started before the block: this thread does not block SIGTERM
        go.wait(5)
        os.kill(os.getpid(), signal.SIGTERM)
        sent.set()

    thread = threading.Thread(target=sender)
    thread.start()
    reached_end = False
    with files.signal_handlers([signal.SIGTERM], _raise):
        with pytest.raises(Stop):
            with files._signals_blocked():
                go.set()
                assert sent.wait(5)
                for _ in range(200):  # Python code runs on: the handler would have fired by now
                    time.sleep(0.001)
                reached_end = True
    thread.join()
    assert reached_end


def test_a_signal_outside_a_block_is_handled_at_once():
    with files.signal_handlers([signal.SIGTERM], _raise):
        with pytest.raises(Stop):
            os.kill(os.getpid(), signal.SIGTERM)
            for _ in range(1000):
                time.sleep(0.001)


class _RaisesInDel:
    """Sends SIGHUP to this process from ``__del__``: its handler runs there, where Python swallows exceptions
    (as in Dask's garbage-collection callback, where ``hoc plan --starts`` once lost a SIGHUP and ran on)."""

    def __del__(self):
        signal.raise_signal(signal.SIGHUP)


def test_a_signal_whose_exception_python_swallowed_is_raised_again_and_ends_the_run(capfd):
    from hoc_cli.commands.common import EXIT_SIGHUP, run_guarded

    ran_on = []

    def body() -> int:
        obj = _RaisesInDel()
        del obj  # the handler raises Terminated inside __del__: swallowed, then redelivered
        start = time.monotonic()
        while time.monotonic() - start < 5.0:
            time.sleep(0.001)
        ran_on.append(True)  # reached only if the signal was lost
        return 0

    import sys

    hook, handler = sys.unraisablehook, signal.getsignal(signal.SIGHUP)
    start = time.monotonic()
    assert run_guarded(body) == EXIT_SIGHUP
    assert not ran_on and time.monotonic() - start < 2.0
    err = capfd.readouterr().err
    assert "hung up (SIGHUP)" in err and "Exception ignored" not in err and "Traceback" not in err
    assert sys.unraisablehook is hook and signal.getsignal(signal.SIGHUP) is handler  # both restored


def test_a_redelivery_still_pending_when_the_block_ends_is_cancelled():
    """A signal swallowed in the block's last moment is not simulated after it, where other handlers are set."""
    lost, after = [], []
    old = signal.signal(signal.SIGUSR1, lambda signum, frame: after.append(signum))
    try:
        with files.redelivered_when_swallowed(lost.append):
            class Swallowed:
                def __del__(self):
                    raise files.Terminated(signal.SIGUSR1)

            obj = Swallowed()
            del obj  # the exception goes to the hook, which schedules the redelivery REDELIVER_S later
        time.sleep(10 * files.REDELIVER_S)
    finally:
        signal.signal(signal.SIGUSR1, old)
    assert lost == [signal.SIGUSR1] and after == []
