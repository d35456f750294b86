"""``hoc plan --check-gradient`` on a task with goals: every derivative the goal solvers use, against central
differences at the initial trajectory.

Parts (each must stay within ``rtol`` relative to its largest entry):

- ``cost``: ∂J/∂x of the cost with the goal's free final state (``GoalProblem``), x the free coefficients;
- ``goal_rows``: the Jacobian ∂c/∂x of every goal row c (link pose, target, link vias), row by row;
- ``dJ_dT`` (a free T): ∂J/∂T along the scaled family (s-domain coefficients fixed, x0 kept in the t domain),
  the derivative the free-T steps and the search use, against J of the rescaled coefficients at T ± h;
- ``goal_rows_dT`` (a free T with goal rows): Σᵢ wᵢ ∂cᵢ/∂T the same way (w: fixed weights 1/(1 + i)).

``report`` prints them (one line to the console, or the JSON object) and gives the exit code.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hoc_cli.commands.common import EXIT_OK, EXIT_UNMET
from hoc_cli.free_time import cost_time_derivative, fixed_coefficient_correction, rescale
from hoc_cli.goals.mesh import scaled_mesh
from hoc_cli.goals.plan import GoalProblem, Goals
from hoc_cli.goals.terms import GoalTerms
from hoc_cli.optimize import check_gradient
from hoc_cli.report.jsonio import print_json
from hoc_cli.system import RobotSystem

T_STEP = 1e-5  # relative step of the central difference in T


@dataclass(frozen=True)
class PartCheck:
    """One derivative against central differences: the largest relative error, coordinates checked of how many."""

    name: str
    max_rel_error: float
    coordinates: int
    of: int


def checked_coordinates(size: int, most: int) -> np.ndarray | None:
    """The coordinates a gradient check compares: None (all ``size``) up to ``most``, else a fixed random
    subset of ``most`` (sorted; seed 0, so a check is repeatable).
    """
    if size <= most:
        return None
    return np.sort(np.random.default_rng(0).choice(size, most, replace=False))


def goal_gradient_checks(model, order: str, T: float, N: int, fractions, q0, dq0, goals: Goals, *,
                         cost: str, free_time: bool, max_coordinates: int) -> list[PartCheck]:
    """The checks of the module docstring at the initial trajectory on N elements of [0, T] [s] (nodes at
    ``fractions`` · T, None: equal elements); at most ``max_coordinates`` coefficients (a fixed random subset).
    """
    system = RobotSystem(model)

    def problem_at(T_: float) -> GoalProblem:
        return GoalProblem(system, scaled_mesh(order, T_, N, fractions), q0, dq0, goals, cost=cost)

    problem = problem_at(T)
    x = problem.initial_guess()
    C = problem.coefficients(x)
    coordinates = checked_coordinates(x.size, max_coordinates)
    n_checked = x.size if coordinates is None else coordinates.size
    out = []
    with np.errstate(all="ignore"):
        c = check_gradient(problem.value, x, problem.evaluate(x).grad, coordinates=coordinates)
        out.append(PartCheck("cost", c.max_rel_error, n_checked, x.size))
        terms = GoalTerms(problem.mesh, problem.points, [np.zeros(p.residual.size) for p in problem.points], 0.0)
        if problem.points:
            free = problem.layout.free
            values, jac = terms.jacobian(C)

            def rows(y: np.ndarray) -> np.ndarray:
                return np.concatenate([r[0] for r in terms.residuals(problem.coefficients(y))])

            c = check_gradient(rows, x, jac.reshape(values.size, -1)[:, free], coordinates=coordinates)
            out.append(PartCheck("goal_rows", c.max_rel_error, n_checked, x.size))
        if free_time:
            h = T_STEP * T
            dT, G = cost_time_derivative(problem, C)
            dT += fixed_coefficient_correction(problem.layout.free, C, G, T)
            out.append(_time_check("dJ_dT", dT, lambda T_: problem_at(T_).value(problem_at(T_).layout.pack(rescale(C, T, T_))),
                                   T, h))
            if problem.points:
                weights = [1.0 / (1.0 + np.arange(p.residual.size)) for p in problem.points]
                weighted = GoalTerms(problem.mesh, problem.points, weights, 0.0)
                dg, Gg = weighted.time_derivative(C, T)
                dg += fixed_coefficient_correction(problem.layout.free, C, Gg, T)

                def rows_at(T_: float) -> float:
                    p = problem_at(T_)
                    Ct = p.coefficients(p.layout.pack(rescale(C, T, T_)))
                    return GoalTerms(p.mesh, p.points, weights, 0.0).evaluate(Ct, grad=False)[0]

                out.append(_time_check("goal_rows_dT", dg, rows_at, T, h))
    return out


def _time_check(name: str, analytic: float, fun, T: float, h: float) -> PartCheck:
    numeric = (fun(T + h) - fun(T - h)) / (2 * h)
    scale = max(abs(analytic), abs(numeric))
    return PartCheck(name, abs(analytic - numeric) / scale if scale > 0 else 0.0, 1, 1)


def report(checks: list[PartCheck], rtol: float, console, as_json: bool, *, cost: str, order: str, N: int) -> int:
    """Print the checks (one line to ``console``; with ``as_json`` the ``gradient_check`` object on stdout) and
    return the exit code: ``EXIT_OK`` when every part is within ``rtol``, else ``EXIT_UNMET``.
    """
    worst = max(checks, key=lambda c: c.max_rel_error)
    passed = worst.max_rel_error <= rtol
    if as_json:
        print_json({"gradient_check": {
            "max_rel_error": worst.max_rel_error, "rtol": rtol, "passed": passed, "worst": worst.name,
            "parts": {c.name: {"max_rel_error": c.max_rel_error, "coordinates": c.coordinates, "of": c.of}
                      for c in checks},
            "cost_type": cost, "N": N, "order": order}})
    parts = ", ".join(f"{c.name} {c.max_rel_error:.2e}" for c in checks)
    console.print(f"hoc: gradient check of a task with goals ({cost} cost, {order} N = {N}, at the initial trajectory): "
                  f"max relative error {parts}; {'passed' if passed else 'FAILED'} (threshold {rtol:g})",
                  highlight=False, markup=False, soft_wrap=True)
    return EXIT_OK if passed else EXIT_UNMET
