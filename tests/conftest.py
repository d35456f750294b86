"""Test-session set-up: one BLAS thread, as ``hoc_cli`` sets for itself (hoc_cli/__init__.py).

pytest imports this file before the test modules, most of which import numpy before hoc_cli; numpy reads the
setting once, when it loads its BLAS. Without it the tests would run hoc's many small dense and banded solves
on competing BLAS threads (on a busy two-core machine a replan's steps took ten times as long). A value the
user exported wins.
"""
import os

for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
