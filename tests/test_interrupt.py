"""Nothing is lost: a ``hoc plan`` interrupted by SIGINT or SIGTERM exits 130 or 143, leaves every
existing output file as it was and no temporary file (``.<name>.*.tmp``) behind.

The plan runs as a real process (signals cannot be sent into CliRunner): the 7-DOF reach with
N = 128 and a tight tolerance, which takes several seconds. The signal is sent once the process
has printed its first iteration (``--progress``), so it arrives while the optimiser works.
"""
from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
KEEP = {"reach.csv": b"KEEP: an earlier CSV\n", "reach.mcap": b"KEEP: an earlier MCAP\n"}
STARTUP_TIMEOUT_S = 30.0

pytestmark = pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="POSIX signals needed")


def hoc_command() -> list[str]:
    """The ``hoc`` console script of this interpreter's environment, else the same entry point via -c."""
    script = Path(sys.executable).with_name("hoc")
    if script.is_file() and os.access(script, os.X_OK):
        return [str(script)]
    return [sys.executable, "-c", "from hoc_cli.cli import app; app()"]


def _default_sigint() -> None:
    # A process started in the background may inherit SIGINT ignored; Python then installs no
    # KeyboardInterrupt handler. Restore the default so the child behaves as on a terminal.
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start_long_plan(d: Path) -> tuple[subprocess.Popen, "queue.Queue[str]"]:
    text = (ROOT / "configs" / "lbr7_swing.yaml").read_text()  # the long, non-convex task
    (d / "reach.yaml").write_text(text.replace("../robots/lbr7.urdf", str(ROOT / "robots" / "lbr7.urdf")))
    for name, data in KEEP.items():
        (d / name).write_bytes(data)
    args = hoc_command() + ["plan", "reach.yaml", "-N", "128", "--tol", "1e-15", "--progress",
                            "-o", "reach.csv", "-o", "reach.mcap"]
    proc = subprocess.Popen(args, cwd=d, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_default_sigint)
    lines: "queue.Queue[str]" = queue.Queue()

    def pump() -> None:
        for line in proc.stderr:
            lines.put(line)
        lines.put("")  # end of stream

    threading.Thread(target=pump, daemon=True).start()
    return proc, lines


def wait_until_planning(proc: subprocess.Popen, lines: "queue.Queue[str]") -> None:
    deadline = time.monotonic() + STARTUP_TIMEOUT_S
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=0.1)
        except queue.Empty:
            continue
        if line == "":
            pytest.fail(f"hoc plan ended (exit {proc.wait()}) before its first iteration")
        if "iter" in line:
            return
    proc.kill()
    pytest.fail(f"no iteration on stderr within {STARTUP_TIMEOUT_S} s")


def rest_of(lines: "queue.Queue[str]") -> str:
    out = []
    while True:
        line = lines.get(timeout=10)
        if line == "":
            return "".join(out)
        out.append(line)


@pytest.mark.parametrize("sig,code,word", [(signal.SIGINT, 130, "interrupted"), (signal.SIGTERM, 143, "terminated")],
                         ids=["SIGINT", "SIGTERM"])
def test_a_signal_during_planning_exits_with_its_code_and_leaves_every_file_as_it_was(tmp_path, sig, code, word):
    proc, lines = start_long_plan(tmp_path)
    try:
        wait_until_planning(proc, lines)
        before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
        proc.send_signal(sig)
        assert proc.wait(timeout=20) == code
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    tail = rest_of(lines)
    assert f"hoc: error: {word}; no output was changed" in tail
    assert "Traceback" not in tail
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    for name, data in KEEP.items():
        assert (tmp_path / name).read_bytes() == data
    assert not list(tmp_path.glob(".*.tmp")), "a temporary output file was left behind"
