"""Unconstrained minimisation: strong-Wolfe line search and preconditioned Polak-Ribière (PR+) CG."""
from hoc_cli.optimize.cg import minimize
from hoc_cli.optimize.result import IterLog, OptimizeResult, Status

__all__ = ["minimize", "IterLog", "OptimizeResult", "Status"]
