"""The optimiser on its own: strong-Wolfe line search, PR+ CG, stopping tests, derivative checks.

Evaluation counts are pinned: a change in the line search or the iteration shows up here first.
"""
import dataclasses
import math

import numpy as np
import pytest

from hoc_cli.optimize import OptimizeResult, Status, StopTest, cg, check_gradient, minimize
from hoc_cli.optimize.linesearch import strong_wolfe


class Dense:
    """An SPD preconditioner given as a dense matrix."""

    def __init__(self, A):
        self.A = A

    def solve(self, g):
        return np.linalg.solve(self.A, g)


class Counted:
    """An objective x -> (J, g, payload) counting its calls independently of the optimiser."""

    def __init__(self, fun):
        self.fun, self.calls = fun, 0

    def __call__(self, x):
        self.calls += 1
        return self.fun(x)


def quadratic(n, seed, cond=1e2):
    """½ xᵀAx − bᵀx with eigenvalues logarithmically spaced in [1, cond]; returns (evaluate, A, x*)."""
    rng = np.random.default_rng(seed)
    Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    A = Q @ np.diag(np.logspace(0, np.log10(cond), n)) @ Q.T
    b = rng.normal(size=n)
    return (lambda x: (0.5 * x @ A @ x - b @ x, A @ x - b, None)), A, np.linalg.solve(A, b)


def rosenbrock(x):
    """Extended Rosenbrock Σ 100 (x_{i+1} − x_i²)² + (1 − x_i)², minimum 0 at (1, …, 1)."""
    r = x[1:] - x[:-1] ** 2
    f = float(np.sum(100 * r**2 + (1 - x[:-1]) ** 2))
    g = np.zeros_like(x)
    g[:-1] += -400 * x[:-1] * r - 2 * (1 - x[:-1])
    g[1:] += 200 * r
    return f, g, x


def rosenbrock_residuals(x):
    """r(x) = (10 (y − x²), 1 − x) with f = |r|², and its Jacobian (2, 2)."""
    return np.array([10 * (x[1] - x[0] ** 2), 1 - x[0]]), np.array([[-20 * x[0], 10.0], [-1.0, 0.0]])


# --------------------------------------------------------------------------- line search
@pytest.mark.parametrize("seed", range(20))
def test_strong_wolfe_conditions_hold_on_every_accepted_step(seed):
    """Random 1-D quadratics and quartics, first trials from 1e-3 to 1e3 times the minimiser."""
    rng = np.random.default_rng(seed)
    a, s, c = rng.uniform(0.1, 10), -rng.uniform(0.1, 10), rng.uniform(0, 1) * (seed % 2)
    calls = []

    def phi(t):
        calls.append(t)
        return s * t + 0.5 * a * t**2 + c * t**4, s + a * t + 4 * c * t**3, t

    alpha0 = (-s / a) * 10 ** rng.uniform(-3, 3)
    c1, c2 = 1e-4, 0.1
    r = strong_wolfe(phi, 0.0, s, alpha0=alpha0, c1=c1, c2=c2)
    assert r.ok and r.n_evals == len(calls) and r.payload == r.alpha
    assert r.phi <= c1 * r.alpha * s  # sufficient decrease
    assert abs(r.dphi) <= c2 * abs(s)  # strong curvature


@pytest.mark.parametrize("alpha0,evals", [(3.0, 1), (10.0, 2), (1.0, 3), (0.01, 8)])
def test_line_search_on_a_parabola_takes_the_pinned_number_of_evaluations(alpha0, evals):
    """φ(α) = (α − 3)²: the cubic interpolation of a parabola is exact, so the zoom lands on α = 3."""
    r = strong_wolfe(lambda a: ((a - 3) ** 2, 2 * (a - 3), None), 9.0, -6.0, alpha0=alpha0)
    assert r.ok and r.n_evals == evals and r.alpha == pytest.approx(3.0, abs=1e-14)


def test_line_search_refuses_an_ascent_direction_without_evaluating():
    r = strong_wolfe(lambda a: pytest.fail("evaluated"), 1.0, 0.5)
    assert not r.ok and r.n_evals == 0 and r.payload is None


def test_line_search_returns_the_best_decrease_when_the_function_ends_before_the_wolfe_region():
    """φ = (α − 3)² is undefined (inf) from α = 2 on: no step satisfies the curvature condition,
    and the result is the lowest φ found (with its payload), as the CG restart logic expects."""
    def phi(a):
        return ((a - 3) ** 2, 2 * (a - 3), a) if a < 2 else (math.inf, math.nan, None)

    r = strong_wolfe(phi, 9.0, -6.0, alpha0=4.0)
    assert not r.ok and r.n_evals == 40
    assert r.phi < 9.0 and r.payload == r.alpha and 1.99 < r.alpha < 2


# --------------------------------------------------------------------------- conjugate gradient
@pytest.mark.parametrize("seed,evals", [(0, 18), (1, 20), (2, 26), (3, 19)])
def test_pr_cg_with_exact_line_searches_solves_a_quadratic_in_n_iterations(seed, evals):
    """With P = I and a near-exact line search (c2 = 1e-6) PR+ on a quadratic is linear CG:
    x_n = x* to rounding, while x_{n−1} is still far off."""
    n = 8
    f, _, xs = quadratic(n, seed)
    err = []
    for k in (n - 1, n):
        res = minimize(f, np.zeros(n), tol=1e-300, max_iter=k, c1=1e-8, c2=1e-6)
        assert res.status is Status.MAX_ITER and res.iterations == k
        err.append(np.linalg.norm(res.x - xs) / np.linalg.norm(xs))
    assert err[0] > 1e-3 and err[1] < 1e-10
    assert res.n_evals == evals


def test_the_exact_hessian_as_preconditioner_takes_one_newton_step():
    f, A, xs = quadratic(8, 0)
    res = minimize(f, np.zeros(8), precondition=lambda payload: Dense(A))
    assert res.converged and res.stop_test is StopTest.DECREMENT
    assert (res.iterations, res.n_evals, res.n_precond) == (1, 2, 1)  # at x* the old matrix passes the test
    np.testing.assert_allclose(res.x, xs, rtol=1e-12)


def test_pr_cg_converges_on_rosenbrock_with_pinned_counts():
    f = Counted(rosenbrock)
    res = minimize(f, np.array([-1.2, 1.0]), tol=1e-8)
    assert res.converged and res.stop_test is StopTest.GRADIENT
    assert (res.iterations, res.n_evals, res.n_precond, res.restarts) == (23, 84, 0, 2)
    assert f.calls == res.n_evals == res.history[-1].n_evals
    assert [h.iteration for h in res.history] == list(range(1, 24))
    np.testing.assert_allclose(res.x, [1.0, 1.0], atol=1e-9)


def test_gauss_newton_preconditioned_newton_converges_on_rosenbrock_with_pinned_counts():
    builds = Counted(lambda x: Dense(2 * rosenbrock_residuals(x)[1].T @ rosenbrock_residuals(x)[1]))
    f = Counted(rosenbrock)
    res = minimize(f, np.array([-1.2, 1.0]), precondition=builds, method="newton", tol=1e-14)
    assert res.converged and res.stop_test is StopTest.DECREMENT
    assert (res.iterations, res.n_evals, res.n_precond) == (15, 43, 15)
    assert f.calls == res.n_evals and builds.calls == res.n_precond
    np.testing.assert_allclose(res.x, [1.0, 1.0], atol=1e-12)


def _descent_ratios(monkeypatch) -> list:
    """−gᵀd / gᵀg of every direction the line search is given (P = I), recorded by a spy on ``strong_wolfe``."""
    ratios = []
    search = cg.strong_wolfe

    def spy(phi, J, dphi0, **kwargs):
        g = phi(0.0)[2][1]  # the gradient at x (one more evaluation, the path unchanged)
        ratios.append(-dphi0 / float(g @ g))
        return search(phi, J, dphi0, **kwargs)

    monkeypatch.setattr(cg, "strong_wolfe", spy)
    return ratios


def test_the_sufficient_descent_restart_keeps_every_pr_cg_direction_a_sufficient_descent(monkeypatch):
    """Extended Rosenbrock (n = 5) with c2 = 0.9 from its standard start and 5 seeded ones: the PR+ direction now
    and then fails Gilbert & Nocedal's sufficient-descent test gᵀd ≤ −σ gᵀg; the restart replaces it by −g, so
    every direction the line search takes passes it (and the standard start converges). With σ = 0 (restart only
    on ascent) such directions are taken: 14 over the 6 runs, at least one in each. (The iteration counts of these
    2000-iteration runs depend on rounding, e.g. numpy's and SciPy's versions, so they are not pinned.)"""
    rng = np.random.default_rng(0)
    starts = [np.tile([-1.2, 1.0], 3)[:5]] + [rng.uniform(-2.0, 2.0, 5) for _ in range(5)]
    ratios = _descent_ratios(monkeypatch)
    res = minimize(rosenbrock, starts[0], tol=1e-8, c2=0.9)
    assert res.converged and res.restarts > 10
    np.testing.assert_allclose(res.x, np.ones(5), atol=1e-7)
    for x0 in starts[1:]:
        minimize(rosenbrock, x0, tol=1e-8, c2=0.9)
    assert min(ratios) >= cg.SUFFICIENT_DESCENT * (1 - 1e-12)
    ratios.clear()
    monkeypatch.setattr(cg, "SUFFICIENT_DESCENT", 0.0)
    for x0 in starts:
        minimize(rosenbrock, x0, tol=1e-8, c2=0.9)
    assert sum(r < 0.01 for r in ratios) >= 5


# --------------------------------------------------------------------------- stopping tests and results
def test_the_result_says_which_stopping_test_held():
    f, A, _ = quadratic(4, 1)
    far = np.full(4, 10.0)
    # the rounding level of J is above the decrement (tol·|J| is not): the rounding-level test
    res = minimize(f, far, precondition=lambda p: Dense(A), tol=1e-300, noise=lambda p: 1e6)
    assert res.converged and res.iterations == 0 and res.stop_test is StopTest.ROUNDING
    assert res.message.startswith("the rounding-level test held")
    # both hold: the decrement test is reported
    res = minimize(f, far, precondition=lambda p: Dense(A), tol=1e6, noise=lambda p: 1e6)
    assert res.stop_test is StopTest.DECREMENT and res.message == "the stopping test held: ½ gᵀP⁻¹g <= tol·|J|"
    res = minimize(f, far, max_iter=0)
    assert res.status is Status.MAX_ITER and res.stop_test is None and "maximum number" in res.message


def test_results_are_frozen_and_the_planner_style_update_makes_a_new_one():
    res = minimize(quadratic(3, 0)[0], np.zeros(3))
    with pytest.raises(dataclasses.FrozenInstanceError):
        res.iterations = 7  # type: ignore[misc]
    new = dataclasses.replace(res, iterations=7)
    assert isinstance(new, OptimizeResult) and new.iterations == 7 and res.iterations != 7


@pytest.mark.parametrize("kwargs", [dict(c2=1e-5), dict(c1=0.5, c2=0.4), dict(tol=0.0), dict(method="bfgs")])
def test_bad_optimiser_parameters_are_refused(kwargs):
    with pytest.raises(ValueError):
        minimize(quadratic(3, 0)[0], np.zeros(3), **kwargs)


# --------------------------------------------------------------------------- derivative checks
def test_check_gradient_passes_an_exact_gradient_and_finds_a_wrong_component():
    x = np.array([-1.2, 1.0, 0.3, 0.8])
    _, g, _ = rosenbrock(x)
    ok = check_gradient(lambda y: rosenbrock(y)[0], x, g)
    assert ok.passed(1e-8) and ok.n_evals == 8 and ok.analytic.shape == ok.numeric.shape == (4,)
    bad = g.copy()
    bad[2] *= 1 + 1e-3
    chk = check_gradient(lambda y: rosenbrock(y)[0], x, bad)
    assert not chk.passed(1e-6) and chk.worst == (0, 2)
    assert chk.max_rel_error == pytest.approx(1e-3 * abs(g[2]) / np.abs(bad).max(), rel=1e-6)  # scale: max(|A|, |D|)
    part = check_gradient(lambda y: rosenbrock(y)[0], x, bad, coordinates=[0, 1, 3])
    assert part.passed(1e-8) and part.n_evals == 6


def test_check_gradient_checks_a_residual_jacobian_row_by_row():
    x = np.array([0.7, -0.4])
    _, Jr = rosenbrock_residuals(x)
    assert check_gradient(lambda y: rosenbrock_residuals(y)[0], x, Jr).passed(1e-8)
    wrong = Jr.copy()
    wrong[1, 0] = -1.01  # row 1 has scale 1: a 1 % error there, although row 0 is ten times larger
    chk = check_gradient(lambda y: rosenbrock_residuals(y)[0], x, wrong)
    assert chk.worst == (1, 0) and chk.max_rel_error == pytest.approx(0.01 / 1.01, rel=1e-6)
