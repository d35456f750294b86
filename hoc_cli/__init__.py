"""hoc: covariant optimal control of jointed robot arms with Hermite finite elements.

The public Python API (no CLI, terminal or file-format imports here):

- ``HermiteMesh``, ``QuadratureOperator``: cubic/quintic Hermite elements (``hoc_cli.elements``)
- ``HocError`` and its subclasses (``hoc_cli.errors``)
"""
from hoc_cli.elements import HermiteMesh, QuadratureOperator
from hoc_cli.errors import HocError, InputFileError, ModelError, NumericalError, OutputError, TaskError

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
