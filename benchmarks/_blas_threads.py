"""One BLAS thread, as ``hoc_cli`` sets for itself (hoc_cli/__init__.py): imported by each benchmark before numpy,
which reads the setting once when it loads its BLAS (a script that imports numpy before hoc_cli would
otherwise time hoc's many small dense and banded solves on competing BLAS threads). A value the user
exported wins.
"""
import os

for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
