"""Unconstrained minimisation: strong-Wolfe line search, preconditioned Polak-Ribière (PR+) CG, derivative checks."""
from hoc_cli.optimize.cg import minimize
from hoc_cli.optimize.check import GradientCheck, check_gradient
from hoc_cli.optimize.result import IterLog, OptimizeResult, Status, StopTest

__all__ = ["minimize", "check_gradient", "GradientCheck", "IterLog", "OptimizeResult", "Status", "StopTest"]
