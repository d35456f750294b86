"""Calibrate ``hoc_cli.report.workload``: wall time and peak memory of ``hoc plan`` against the estimate.

Run:  python benchmarks/bench_workload.py                 (about 2-4 minutes on 2 cores)
      python benchmarks/bench_workload.py --cases two_link:4000 chain:40:8

Each case runs ``hoc plan`` in a fresh process (``-o none --json --limits report``) and reads its wall
time and peak resident memory (``os.wait4``: ru_maxrss of that process alone). Cases:

- ``two_link:N``   configs/two_link.yaml with N elements (n = 2; G = 8, quintic);
- ``chain:n:N``    a planar-ish serial chain of n revolute joints (unit links, 1 kg each), rest to
                   rest from 0 to 0.3 rad per joint in T = 1.5 s, N elements;
- ``samples:R[:csv|:mcap]``  two_link at N = 16 with ``output.rate`` R Hz and CSV and/or MCAP outputs
                   (default both): the sampling and writing.

The estimate (``estimate_workload``) is printed beside each measurement; docs/design.md ("Work
estimate") gives the formula and the measurements it was fitted to.
"""
from __future__ import annotations

# isort: off
import _blas_threads  # noqa: F401  (before numpy: one BLAS thread, as hoc_cli sets)
# isort: on
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

from hoc_cli.report.workload import estimate_workload

ROOT = Path(__file__).resolve().parent.parent
DEFAULT = ["two_link:1000", "two_link:4000", "two_link:16000", "chain:10:8", "chain:20:8", "chain:40:8",
           "samples:20000"]


def chain_urdf(n: int) -> str:
    """n revolute joints in series, alternating z and y axes, each link 0.3 m along x with 1 kg."""
    links = ['<link name="l0"/>']
    joints = []
    for k in range(1, n + 1):
        links.append(f'<link name="l{k}"><inertial><origin xyz="0.15 0 0"/><mass value="1"/>'
                     '<inertia ixx="0.001" ixy="0" ixz="0" iyy="0.0085" iyz="0" izz="0.0085"/></inertial></link>')
        axis = "0 0 1" if k % 2 else "0 1 0"
        x = 0.0 if k == 1 else 0.3
        joints.append(f'<joint name="j{k}" type="revolute"><parent link="l{k - 1}"/><child link="l{k}"/>'
                      f'<origin xyz="{x} 0 0"/><axis xyz="{axis}"/>'
                      '<limit lower="-3" upper="3" effort="1000" velocity="100"/></joint>')
    return '<?xml version="1.0"?>\n<robot name="chain">' + "".join(links + joints) + "</robot>"


def make_task(case: str, folder: Path) -> tuple[Path, dict, list[str]]:
    """(task file, the numbers the estimate needs, extra CLI arguments) of one case."""
    kind, *args = case.split(":")
    if kind == "two_link":
        task = yaml.safe_load((ROOT / "configs" / "two_link.yaml").read_text())
        task["robot"] = str(ROOT / "robots" / "two_link.urdf")
        task["N"] = int(args[0])
        outputs = ["-o", "none"]
    elif kind == "chain":
        n, N = int(args[0]), int(args[1])
        (folder / "chain.urdf").write_text(chain_urdf(n))
        task = {"robot": "chain.urdf", "gravity": [0, 0, -9.81], "x0": {"q": [0.0] * n, "dq": [0.0] * n},
                "x1": {"q": [0.3] * n, "dq": [0.0] * n}, "T": 1.5, "N": N, "order": "quintic",
                "output": {"rate": 100}}
        outputs = ["-o", "none"]
    elif kind == "samples":
        task = yaml.safe_load((ROOT / "configs" / "two_link.yaml").read_text())
        task["robot"] = str(ROOT / "robots" / "two_link.urdf")
        task["output"] = {"rate": float(args[0])}
        kinds = args[1:] or ["csv", "mcap"]
        outputs = [a for kind in kinds for a in ("-o", str(folder / f"out.{kind}"))]
    else:
        raise SystemExit(f"unknown case {case!r}")
    path = folder / "task.yaml"
    path.write_text(yaml.safe_dump(task))
    return path, task, outputs


def run(case: str) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        path, task, outputs = make_task(case, folder)
        n = len(task["x0"]["q"])
        est = estimate_workload(n=n, N=task["N"], order=task.get("order", "quintic"), T=task["T"],
                                rate=task["output"]["rate"], csv=sum(o.endswith(".csv") for o in outputs),
                                mcap=sum(o.endswith(".mcap") for o in outputs))
        cmd = [sys.executable, "-c", "from hoc_cli.cli import app; app()", "plan", str(path), "--json", "--limits", "report", *outputs]
        start = time.perf_counter()
        proc = subprocess.Popen(cmd, cwd=folder, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
        out = proc.stdout.read()
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - start
        proc.returncode = os.waitstatus_to_exitcode(status)
        summary = json.loads(out) if out.strip() else {}
    return {"case": case, "wall_s": wall, "solve_s": summary.get("wall_time_s"),
            "estimate_s": summary.get("J_error_wall_time_s"), "iterations": summary.get("iterations"),
            "evaluations": summary.get("evaluations"), "peak_MB": usage.ru_maxrss / 1024,
            "est_s": est.seconds, "est_MB": est.bytes / 2**20}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="*", default=DEFAULT)
    args = parser.parse_args()
    print(f"{'case':16s} {'wall s':>8s} {'solve s':>8s} {'error s':>8s} {'iter':>5s} {'evals':>6s} "
          f"{'peak MB':>8s} | {'est. s':>8s} {'est. MB':>8s}")
    for case in args.cases:
        r = run(case)
        print(f"{r['case']:16s} {r['wall_s']:8.2f} {r['solve_s'] or 0:8.2f} {r['estimate_s'] or 0:8.2f} "
              f"{r['iterations'] or 0:5d} {r['evaluations'] or 0:6d} {r['peak_MB']:8.0f} | {r['est_s']:8.2f} "
              f"{r['est_MB']:8.0f}",
              flush=True)


if __name__ == "__main__":
    main()
