"""Multi-start: solve one task from K initial guesses and keep the best local optimum.

The cost is not convex in the trajectory: from the minimum-jerk guess the coarse-to-fine solve
reaches one local optimum, other guesses may reach better ones. Start 0 is exactly ``plan``'s
default solve (minimum-jerk guess, coarse-to-fine). Start k >= 1 adds to the minimum-jerk guess a
smooth seeded perturbation of the interior of the path,

    δq_j(t) = Σ_{i=1..3} a_{ij} sin(iπs) sin²(πs),   s = t/T,   a_{ij} ~ N(0, (σ_j / i)²),
    σ_j = ``amplitude`` · max(|q1_j − q0_j|, 0.1 rad (or m)),

which vanishes with its first and second derivatives at both ends (so x0, x1 are kept), sets it
on the coarsest mesh of the same coarse-to-fine sequence and solves level by level. The draws of
start k come from ``numpy.random.default_rng([seed, k])``: start k is the same whatever K is, so
``K = 8`` repeats the 4 starts of ``K = 4`` and adds 4 more. The kept plan is the converged start
with the lowest J (ties: the lowest index); if no start converged, the lowest finite J.

The starts are independent: ``solve_starts`` runs them one after the other, or as tasks of a
``dask.distributed.Client`` when one is given; the outcome is the same either way.
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from hoc_cli.elements import HermiteMesh
from hoc_cli.errors import HocError
from hoc_cli.planner import PlanResult, continuation_levels, plan, resample
from hoc_cli.problem import ControlProblem
from hoc_cli.system import System

DEFAULT_AMPLITUDE = 0.5
MODES = 3  # sine modes of the perturbation


@dataclass(frozen=True)
class StartOutcome:
    """How one start ended: its index, cost J (nan after an error), convergence, status, iterations, error."""

    index: int
    J: float
    converged: bool
    status: str
    iterations: int
    error: str | None = None

    def as_dict(self) -> dict:
        return {"start": self.index, "cost": None if not math.isfinite(self.J) else self.J,
                "converged": self.converged, "status": self.status, "iterations": self.iterations,
                **({"error": self.error} if self.error else {})}


@dataclass(eq=False)
class MultiStartResult:
    """The kept plan (``best``, from start ``best_index``) and every start's outcome, by index."""

    best: PlanResult
    best_index: int
    outcomes: list[StartOutcome]


def perturbation(mesh: HermiteMesh, sigma: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Coefficients (N+1, m, n) of the smooth perturbation δq at the mesh nodes (q, q̇[, q̈] columns).

    sigma : (n,) amplitude scale per joint [rad or m].
    """
    sigma = np.asarray(sigma, float)
    a = rng.standard_normal((MODES, sigma.size)) * sigma / np.arange(1, MODES + 1)[:, None]  # (MODES, n)
    w = np.pi / mesh.T
    t = mesh.nodes
    k = np.arange(1, MODES + 1)[:, None] * w  # (MODES, 1)
    # φ = sin(k t) · b with b = sin²(w t); derivatives by the product rule.
    s, c = np.sin(k * t), np.cos(k * t)  # (MODES, N+1)
    b = np.sin(w * t) ** 2
    db = w * np.sin(2 * w * t)
    ddb = 2 * w**2 * np.cos(2 * w * t)
    phi = s * b
    dphi = k * c * b + s * db
    ddphi = -(k**2) * s * b + 2 * k * c * db + s * ddb
    cols = [phi.T @ a, dphi.T @ a, ddphi.T @ a][: mesh.m]  # each (N+1, n)
    return np.stack(cols, axis=1)


def start_guess(system: System, mesh: HermiteMesh, q0, dq0, q1, dq1, index: int, seed: int, *,
                cost: str = "covariant", amplitude: float = DEFAULT_AMPLITUDE) -> np.ndarray:
    """The initial coefficients (N+1, m, n) of start ``index`` >= 1: minimum-jerk guess plus perturbation."""
    problem = ControlProblem(system, mesh, q0, dq0, q1, dq1, cost=cost)
    C = problem.coefficients(problem.initial_guess())
    sigma = amplitude * np.maximum(np.abs(np.asarray(q1, float) - np.asarray(q0, float)), 0.1)
    rng = np.random.default_rng([int(seed), int(index)])
    return C + perturbation(mesh, sigma, rng)


def solve_start(system: System, mesh: HermiteMesh, q0, dq0, q1, dq1, index: int, seed: int, *,
                amplitude: float = DEFAULT_AMPLITUDE, **options: Any) -> PlanResult:
    """Solve start ``index``: ``plan``'s default for 0; else the perturbed guess, coarse to fine.

    ``options`` are ``plan``'s keywords (cost, method, tol, max_iter, G, precondition). The
    intermediate levels are solved to max(tol, 1e-6), as ``plan`` does; the returned result's
    iteration and evaluation counts are the totals over the levels.
    """
    if index == 0:
        return plan(system, mesh, q0, dq0, q1, dq1, **options)
    levels = continuation_levels(mesh.N)
    tol = options.pop("tol", 1e-10)
    cost = options.get("cost", "covariant")
    level = HermiteMesh(mesh.order, mesh.T, levels[0])
    C = start_guess(system, level, q0, dq0, q1, dq1, index, seed, cost=cost, amplitude=amplitude)
    its = evals = 0
    for i, N in enumerate(levels):
        if N != level.N:
            nxt = HermiteMesh(mesh.order, mesh.T, N)
            C, level = resample(level, C, nxt), nxt
        last = i == len(levels) - 1
        result = plan(system, level, q0, dq0, q1, dq1, tol=tol if last else max(tol, 1e-6), C_init=C, **options)
        its += result.optimizer.iterations
        evals += result.optimizer.n_evals
        C = result.coeffs
    return dataclasses.replace(result, optimizer=dataclasses.replace(result.optimizer, iterations=its, n_evals=evals))


def _outcome(index: int, result: PlanResult | None, error: str | None) -> StartOutcome:
    if result is None:
        return StartOutcome(index, math.nan, False, "error", 0, error)
    o = result.optimizer
    status = result.limits.status if result.limits is not None else o.status.value  # limits enforced: theirs
    return StartOutcome(index, float(result.J), result.converged, status, o.iterations)


def _run_start(system: System, mesh: HermiteMesh, boundary: Sequence, index: int, seed: int,
               options: dict) -> tuple[PlanResult | None, str | None]:
    """One start, its failure (a ``HocError``: bad guess, NaN) as a message instead of an exception."""
    with np.errstate(all="ignore"):
        try:
            return solve_start(system, mesh, *boundary, index, seed, **dict(options)), None
        except HocError as exc:
            return None, str(exc)


def choose(outcomes: Sequence[StartOutcome]) -> int:
    """Index of the kept start: lowest J among the converged, else lowest finite J, else 0."""
    ok = [o for o in outcomes if o.converged and math.isfinite(o.J)]
    pool = ok or [o for o in outcomes if math.isfinite(o.J)]
    if not pool:
        return 0
    return min(pool, key=lambda o: (o.J, o.index)).index


def solve_starts(system: System, mesh: HermiteMesh, q0, dq0, q1, dq1, *, starts: int, seed: int = 0,
                 client: Any = None, on_start: Callable[[StartOutcome], None] | None = None,
                 **options: Any) -> MultiStartResult:
    """Solve ``starts`` starts (serially, or on ``client``) and keep the best; see the module docstring.

    client : None (serial), a ``dask.distributed.Client``, or a callable ``(t0, remaining)`` that is
        called after start 0 was solved here in t0 seconds and returns a context manager yielding a
        Client (or None: serial) for the ``remaining`` starts.
    on_start : called with each start's outcome as it finishes (any order).

    Raises the first start's error when every start failed with an error.
    """
    if starts < 1:
        raise ValueError("starts must be >= 1")
    boundary = (q0, dq0, q1, dq1)
    results: dict[int, tuple[PlanResult | None, str | None]] = {}

    def done(k: int, res: tuple[PlanResult | None, str | None]) -> None:
        results[k] = res
        if on_start is not None:
            on_start(_outcome(k, *res))

    rest = list(range(starts))
    if callable(client):  # decide after start 0, from its solve time
        t0 = time.perf_counter()
        done(0, _run_start(system, mesh, boundary, 0, seed, options))
        rest = rest[1:]
        with client(time.perf_counter() - t0, len(rest)) as pool:
            _run_all(system, mesh, boundary, rest, seed, options, pool, done)
    else:
        _run_all(system, mesh, boundary, rest, seed, options, client, done)
    outcomes = [_outcome(k, *results[k]) for k in range(starts)]
    if all(results[k][0] is None for k in range(starts)):
        raise _first_error(system, mesh, boundary, seed, options)
    best = choose(outcomes)
    return MultiStartResult(best=results[best][0], best_index=best, outcomes=outcomes)  # type: ignore[arg-type]


def _run_all(system: System, mesh: HermiteMesh, boundary: Sequence, indices: list[int], seed: int, options: dict,
             client: Any, done: Callable) -> None:
    """Solve the starts ``indices``: serially when ``client`` is None, else as tasks on it."""
    if client is None or len(indices) <= 1:
        for k in indices:
            done(k, _run_start(system, mesh, boundary, k, seed, options))
        return
    from distributed import as_completed

    sys_f = client.scatter(system, broadcast=True)
    futures = {client.submit(_run_start, sys_f, mesh, boundary, k, seed, options, pure=False): k for k in indices}
    try:
        for fut in as_completed(list(futures), loop=client.loop):
            done(futures[fut], fut.result())
    except BaseException:
        client.cancel(list(futures))
        raise


def _first_error(system: System, mesh: HermiteMesh, boundary: Sequence, seed: int, options: dict) -> HocError:
    """Start 0's exception, re-raised in this process (with its type) for the caller to report."""
    try:
        with np.errstate(all="ignore"):
            solve_start(system, mesh, *boundary, 0, seed, **dict(options))
    except HocError as exc:
        return exc
    return HocError("every start failed")
