"""Start-up: a whole `hoc plan configs/lbr7_reach.yaml -o none -q` process beside `python -c 'import numpy,
scipy.linalg, yaml'` (the libraries any such tool loads), best of R runs each, interleaved.

    python benchmarks/bench_startup.py [--runs R]

Prints both times and their ratio (the target: at most 1.8), and the imports that cost most in the
hoc process (`python -X importtime`). hoc's modules are byte-compiled first (`compileall`), as installing
a wheel does and as any run does when Python may write bytecode: with PYTHONDONTWRITEBYTECODE set and
no `__pycache__`, every run would compile hoc's 86 modules from source (about 0.1 s), which numpy,
scipy and yaml, installed with their bytecode, never pay.
"""
from __future__ import annotations

import argparse
import platform
import re
import shutil
import subprocess
import sys
import time
from datetime import date
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def timed(cmd: list[str]) -> float:
    t = time.perf_counter()
    subprocess.run(cmd, check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10)
    runs = ap.parse_args().runs
    subprocess.run([sys.executable, "-m", "compileall", "-q", str(ROOT / "hoc_cli")], check=True,
                   stdout=subprocess.DEVNULL)
    hoc = shutil.which("hoc") or str(Path(sys.executable).with_name("hoc"))
    base_cmd = [sys.executable, "-c", "import numpy, scipy.linalg, yaml"]
    hoc_cmd = [hoc, "plan", "configs/lbr7_reach.yaml", "-o", "none", "-q"]
    base, plan = [], []
    for _ in range(runs):
        base.append(timed(base_cmd))
        plan.append(timed(hoc_cmd))
    b, h = min(base), min(plan)
    print(f"{platform.processor() or platform.machine()}, Python {platform.python_version()}, {date.today()}")
    print(f"import numpy, scipy.linalg, yaml: {b:.3f} s   hoc plan lbr7_reach -o none: {h:.3f} s   "
          f"ratio {h / b:.2f} (target <= 1.8; best of {runs})")
    out = subprocess.run([sys.executable, "-X", "importtime", "-c",
                          "from hoc_cli.cli import app\ntry:\n    app(['plan', 'configs/lbr7_reach.yaml', '-o', 'none', '-q'])\n"
                          "except SystemExit:\n    pass"], cwd=ROOT, capture_output=True, text=True).stderr
    rows = []
    for line in out.splitlines():
        m = re.match(r"import time:\s+(\d+) \|\s+(\d+) \|( +)(\S+)", line)
        if m and len(m.group(3)) <= 3:  # top-level imports of the process
            rows.append((int(m.group(2)), m.group(4)))
    print("largest top-level imports (cumulative):")
    for us, name in sorted(rows, reverse=True)[:8]:
        print(f"  {us / 1e3:7.1f} ms  {name}")


if __name__ == "__main__":
    main()
