"""The augmented-Lagrangian driver (``constraints.auglag``) on a problem whose answer is known in closed form.

min ½|x − a|² subject to A x = b: x* = a − Aᵀλ*, λ* = (AAᵀ)⁻¹(A a − b) (the KKT conditions, solved by numpy
here, independently of the driver). The inner solve is one exact Newton step (the penalised problem is
quadratic), so the test sees the outer loop alone: the multiplier update, ρ's growth, its cap and the
infeasible verdict.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from hoc_cli.constraints import auglag
from hoc_cli.constraints.auglag import Measure, Penalized


@dataclass
class _Ev:
    x: np.ndarray
    J: float
    grad: np.ndarray | None


class _Layout:
    @staticmethod
    def pack(g: np.ndarray) -> np.ndarray:
        return g


class _Chol:
    def __init__(self, H: np.ndarray) -> None:
        self.H = H

    def solve(self, g: np.ndarray) -> np.ndarray:
        return np.linalg.solve(self.H, g)


class Distance:
    """½|x − a|² with the evaluate/newton/coefficients interface of a ControlProblem (C = x)."""

    mesh = None
    layout = _Layout()

    def __init__(self, a) -> None:
        self.a = np.asarray(a, float)

    def coefficients(self, x: np.ndarray) -> np.ndarray:
        return x

    def evaluate(self, x: np.ndarray, grad: bool = True) -> _Ev:
        d = x - self.a
        return _Ev(x, 0.5 * float(d @ d), d.copy() if grad else None)

    def newton(self, ev: _Ev, extra: np.ndarray | None = None) -> _Chol:
        return _Chol(np.eye(self.a.size) + (0.0 if extra is None else extra))


@dataclass(frozen=True)
class _Status:
    value: str


@dataclass(frozen=True)
class _Result:
    x: np.ndarray
    converged: bool = True
    status: _Status = _Status("converged")
    iterations: int = 1
    n_evals: int = 1
    message: str = "one Newton step"


def newton_solve(problem, x: np.ndarray, tol: float) -> _Result:
    """The exact minimiser of a quadratic: one Newton step."""
    ev = problem.evaluate(x)
    return _Result(x - problem.newton(ev).solve(ev.grad))


class LinearRows:
    """The equality rows A x = b as an ``auglag.Term``: Φ = λᵀc + ½ρ|c|², c = A x − b, met to ``eq``."""

    stop_on_failure = False
    imposed = True

    def __init__(self, A, b, rho: float, rho0: float | None, rho_cap: float = np.inf, eq: float = 1e-12) -> None:
        self.A, self.b = np.atleast_2d(np.asarray(A, float)), np.asarray(b, float)
        self.lam = np.zeros(self.b.size)
        self.rho, self.rho0, self.rho_cap, self.eq = rho, rho0, rho_cap, eq
        self.updates = 0

    def evaluate(self, C: np.ndarray, grad: bool = True):
        c = self.A @ C - self.b
        value = float(self.lam @ c) + 0.5 * self.rho * float(c @ c)
        return value, (self.A.T @ (self.lam + self.rho * c) if grad else None)

    def newton_blocks(self, C: np.ndarray) -> np.ndarray:
        return self.rho * self.A.T @ self.A

    def begin(self, base, x: np.ndarray) -> None:
        pass

    def problem(self, base):
        return Penalized(base, (self,))

    def measure(self, base, x: np.ndarray, res, tol: float) -> Measure:
        v = float(np.max(np.abs(self.A @ x - self.b)))
        return Measure(v, v <= self.eq, v <= self.eq and res.converged)

    def update(self, base, x: np.ndarray, measure: Measure) -> None:
        self.lam = self.lam + self.rho * (self.A @ x - self.b)
        self.updates += 1

    def feasible_start(self, base, x: np.ndarray) -> bool:
        return float(np.max(np.abs(self.A @ x - self.b))) <= self.eq


def test_the_driver_meets_linear_equality_rows_at_the_kkt_point():
    a = np.array([0.3, -1.2, 2.0])
    A = np.array([[1.0, 1.0, 1.0], [1.0, -2.0, 0.5]])
    b = np.array([1.0, 0.25])
    lam_star = np.linalg.solve(A @ A.T, A @ a - b)
    x_star = a - A.T @ lam_star
    term = LinearRows(A, b, rho=1.0, rho0=1.0)
    out = auglag.minimize(Distance(a), (term,), np.zeros(3), 1e-12, newton_solve, max_outer=40)
    assert (out.status, out.stop) == ("converged", "met")
    np.testing.assert_allclose(out.x, x_star, atol=1e-12)
    np.testing.assert_allclose(term.lam, lam_star, rtol=1e-9)
    assert out.iterations == out.outer == term.updates + 1  # one inner solve each; no update after the last
    assert term.rho > 1.0  # a violation falling more slowly than to a quarter makes ρ grow (here 1/(1+ρ|A|²))


def test_two_terms_share_one_loop_and_meet_the_kkt_point_of_all_their_rows():
    """One row per term: one inner solve per outer iteration for both, each term's multiplier the KKT one."""
    a = np.array([0.3, -1.2, 2.0])
    A = np.array([[1.0, 1.0, 1.0], [1.0, -2.0, 0.5]])
    b = np.array([1.0, 0.25])
    lam_star = np.linalg.solve(A @ A.T, A @ a - b)
    first, second = LinearRows(A[:1], b[:1], 1.0, 1.0), LinearRows(A[1:], b[1:], 1.0, 1.0)
    out = auglag.minimize(Distance(a), (first, second), np.zeros(3), 1e-12, newton_solve, max_outer=40)
    assert (out.status, out.stop) == ("converged", "met")
    np.testing.assert_allclose(out.x, a - A.T @ lam_star, atol=1e-12)
    np.testing.assert_allclose(np.concatenate([first.lam, second.lam]), lam_star, rtol=1e-9)
    assert out.iterations == out.outer == first.updates + 1 == second.updates + 1


def test_rows_that_cannot_be_met_are_infeasible_once_rho_has_grown_out_of_range():
    """x0 = 0 and x0 = 1: the violation stays at 1/2, ρ grows ×10 an iteration until past RHO_RANGE·ρ0."""
    term = LinearRows([[1.0, 0.0], [1.0, 0.0]], [0.0, 1.0], rho=1.0, rho0=1.0)
    out = auglag.minimize(Distance([0.2, 0.0]), (term,), np.zeros(2), 1e-12, newton_solve, max_outer=40)
    assert (out.status, out.stop) == ("infeasible", "infeasible")
    assert auglag.RHO_RANGE < term.rho <= auglag.RHO_RANGE * auglag.RHO_GROWTH
    assert abs(out.x[0] - 0.5) < 1e-6  # the least-violating plan


def test_a_term_without_a_penalty_range_stops_at_its_cap_and_is_never_called_infeasible():
    term = LinearRows([[1.0, 0.0], [1.0, 0.0]], [0.0, 1.0], rho=1.0, rho0=None, rho_cap=1e3)
    out = auglag.minimize(Distance([0.2, 0.0]), (term,), np.zeros(2), 1e-12, newton_solve, max_outer=12)
    assert (out.status, out.stop, out.outer) == ("not_converged", "outer", 12)
    assert term.rho == 1e3


def test_the_inner_solve_running_out_of_iterations_ends_the_loop():
    def spent(problem, x, tol):
        return dataclasses.replace(newton_solve(problem, x, tol), converged=False, status=_Status("max_iter"))

    term = LinearRows([[1.0, 1.0]], [1.0], rho=1.0, rho0=1.0)
    out = auglag.minimize(Distance([0.0, 0.0]), (term,), np.zeros(2), 1e-12, spent, max_outer=40)
    assert (out.status, out.stop, out.outer, term.updates) == ("not_converged", "max_iter", 1, 0)


class CountedDistance(Distance):
    """``Distance`` counting its evaluations."""

    def __init__(self, a) -> None:
        super().__init__(a)
        self.evals = 0

    def evaluate(self, x: np.ndarray, grad: bool = True) -> _Ev:
        self.evals += 1
        return super().evaluate(x, grad)


def test_the_polish_steps_from_the_inner_solves_last_evaluation_without_a_second_one_there():
    """An inner solve that ends with the gradient at its point (as a line search's accepted step does): the polish
    (``auglag.solve``) takes its Newton step from that evaluation; its only evaluation is the trial point's."""
    def accepted(problem, x, tol):
        res = newton_solve(problem, x, tol)
        problem.evaluate(res.x)  # the accepted point's gradient
        return res

    a = np.array([0.3, -1.2, 2.0])
    A = np.array([[1.0, 1.0, 1.0], [1.0, -2.0, 0.5]])
    b = np.array([1.0, 0.25])
    base = CountedDistance(a)
    out = auglag.minimize(base, (LinearRows(A, b, rho=1.0, rho0=1.0),), np.zeros(3), 1e-12, accepted, max_outer=40)
    assert (out.status, out.stop) == ("converged", "met")
    np.testing.assert_allclose(out.x, a - A.T @ np.linalg.solve(A @ A.T, A @ a - b), atol=1e-12)
    assert base.evals == 3 * out.outer  # each outer iteration: the Newton step's, the accepted point's, the trial's


def test_the_polish_at_the_evaluation_of_the_inner_solves_last_newton_matrix_takes_that_matrix():
    """A second Newton matrix without ``extra`` at the same evaluation (the polish after an inner solve whose last
    iteration built one there) is the first: the base's is not built again; another evaluation or ``extra`` builds."""
    calls = []

    class Counted(Distance):
        def newton(self, ev, extra=None):
            calls.append(extra)
            return super().newton(ev, extra)

    A, b = np.array([[1.0, 2.0, 0.0]]), np.array([0.5])
    problem = Penalized(Counted(np.array([0.3, -1.2, 2.0])), (LinearRows(A, b, rho=3.0, rho0=1.0),))
    ev = problem.evaluate(np.zeros(3))
    P = problem.newton(ev)
    assert problem.newton(ev) is P and len(calls) == 1
    x = auglag.polish(problem, np.zeros(3), ev)
    assert len(calls) == 1
    np.testing.assert_allclose(x, -np.linalg.solve(np.eye(3) + 3.0 * A.T @ A, ev.grad), atol=1e-14)
    problem.newton(ev, extra=np.eye(3))
    problem.newton(problem.evaluate(np.zeros(3)))
    assert len(calls) == 3
