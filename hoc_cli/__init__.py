"""hoc: covariant optimal control of jointed robot arms with Hermite finite elements.

The public Python API (no CLI, terminal or file-format imports here):

- ``HermiteMesh``, ``QuadratureOperator``: cubic/quintic Hermite elements (``hoc_cli.elements``)
- ``load_robot`` (URDF → ``RobotModel``), ``RobotSystem``, ``LinearOscillator``, ``System`` (``hoc_cli.system``)
- ``solve(problem, options, warm=None)`` → ``Plan``: plans an ``OptimalControlProblem`` (time ``Fixed`` or
  ``Free``; goals ``link_goal``, ``joint_via``, ``link_via``; ``JointLimits``), choosing the solver (docs/api.md)
- ``plan`` → ``PlanResult``, ``ControlProblem`` (cost, gradient, banded Newton matrix): the fixed-T solver itself
- ``simulate_hermite`` (``hoc_cli.simulate``), ``simulate_reference`` (``hoc_cli.reference_integrator``)
- ``HocError`` and its subclasses (``hoc_cli.errors``)
"""
import os as _os

# hoc's linear algebra is many small (n × n, banded) problems: BLAS threads only add overhead
# (a banded Cholesky of the 7-DOF Newton matrix takes 0.13 ms on one thread, 6 ms on two busy
# ones). Set before numpy loads its BLAS; a value the user exported wins.
for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")


def _keep_freed_memory() -> None:
    """Glibc returns freed blocks over 128 kB to the kernel (mmap/munmap), so every batched dynamics call
    page-faults its (6, n, K) temporaries anew: inverse dynamics at K = 1000 took 1.5 µs per sample
    instead of 0.75. Raising the mmap and trim thresholds keeps such blocks in the heap. Linux/glibc
    only; skipped when the user set MALLOC_MMAP_THRESHOLD_ or MALLOC_TRIM_THRESHOLD_.
    """
    if any(v in _os.environ for v in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")):
        return
    try:
        import ctypes

        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc
        return
    M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
    mallopt(M_MMAP_THRESHOLD, 256 * 2**20)
    mallopt(M_TRIM_THRESHOLD, 512 * 2**20)


_keep_freed_memory()

from hoc_cli.elements import HermiteMesh, QuadratureOperator  # noqa: E402
from hoc_cli.errors import (  # noqa: E402
    HocError,
    InputFileError,
    ModelError,
    NumericalError,
    OutputError,
    TaskError,
)
from hoc_cli.planner import PlanResult, plan  # noqa: E402
from hoc_cli.problem import ControlProblem  # noqa: E402
from hoc_cli.system import LinearOscillator, RobotSystem, System  # noqa: E402

__version__ = "0.1.0"


_LAZY = {  # imported on first use: ``import hoc_cli`` stays light
    "load_robot": "hoc_cli.model",
    "solve": "hoc_cli.strategy",
    "SolveOptions": "hoc_cli.strategy",
    "Plan": "hoc_cli.strategy",
    "WarmStart": "hoc_cli.strategy",
    "OptimalControlProblem": "hoc_cli.ocp",
    "Fixed": "hoc_cli.ocp",
    "Free": "hoc_cli.ocp",
    "link_goal": "hoc_cli.ocp",
    "joint_via": "hoc_cli.ocp",
    "link_via": "hoc_cli.ocp",
    "JointLimits": "hoc_cli.constraints",
    "simulate_hermite": "hoc_cli.simulate",
    "simulate_reference": "hoc_cli.reference_integrator",
}


def __getattr__(name: str):
    """The names of ``_LAZY``, imported on first use."""
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'hoc_cli' has no attribute {name!r}")


__all__ = [
    "OptimalControlProblem",
    "Fixed",
    "Free",
    "JointLimits",
    "link_goal",
    "joint_via",
    "link_via",
    "solve",
    "SolveOptions",
    "Plan",
    "WarmStart",
    "ControlProblem",
    "HermiteMesh",
    "LinearOscillator",
    "PlanResult",
    "QuadratureOperator",
    "RobotSystem",
    "System",
    "load_robot",
    "plan",
    "simulate_hermite",
    "simulate_reference",
    "HocError",
    "InputFileError",
    "ModelError",
    "NumericalError",
    "OutputError",
    "TaskError",
    "__version__",
]
