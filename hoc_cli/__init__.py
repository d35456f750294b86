"""hoc: covariant optimal control of jointed robot arms with Hermite finite elements.

The public Python API (no CLI, terminal or file-format imports here):

- ``HermiteMesh``, ``QuadratureOperator``: cubic/quintic Hermite elements (``hoc_cli.elements``)
- ``HocError`` and its subclasses (``hoc_cli.errors``)
"""
import os as _os

# hoc's linear algebra is many small (n × n, banded) problems: BLAS threads only add overhead
# (a banded Cholesky of the 7-DOF Newton matrix takes 0.13 ms on one thread, 6 ms on two busy
# ones). Set before numpy loads its BLAS; a value the user exported wins.
for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")

from hoc_cli.elements import HermiteMesh, QuadratureOperator  # noqa: E402
from hoc_cli.errors import HocError  # noqa: E402, InputFileError, ModelError, NumericalError, OutputError, TaskError

__version__ = "0.1.0"

__all__ = [
    "HermiteMesh",
    "QuadratureOperator",
    "HocError",
    "InputFileError",
    "ModelError",
    "NumericalError",
    "OutputError",
    "TaskError",
    "__version__",
]
