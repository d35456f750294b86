"""How far a plan's J is from the continuous optimum, and ``N: auto`` (refine until it is close enough).

The estimate (``estimate``) compares the plan on N elements with the same problem solved on 2N
elements, warm-started from the plan itself: the N-element trajectory is exactly representable
on 2N elements, so the solve follows the same local optimum and J(2N) <= J(N). With the plan on
N/2 elements (the plan's own coarser level when it was reached by doubling, else a solve on N/2
elements started from the plan's values at those nodes), the differences d₁ = J(N/2) − J(N) and
d₂ = J(N) − J(2N) measure the order p = log₂(d₁/d₂) of J(N) − J* ≈ C·N⁻ᵖ, and Richardson
extrapolation gives

    |J(N) − J*| ≈ d₂ · 2ᵖ / (2ᵖ − 1),

with p capped at the order of a smooth problem (8 for quintic elements, 4 for cubic: J is a
squared norm of a residual that converges like h⁴, resp. h²). When p cannot be measured (N odd,
or d₁ and d₂ of different signs or not decreasing: not yet in the asymptotic range) the factor 2
is used, the largest for any order p >= 1. The estimate is reported relative to |J(N)| and is
never below the solver's tolerance ``tol`` (J itself is only known to about tol·|J|).

Per-element indicators (``element_indicators``): the hierarchical residual of the plan on 2N
elements. The 2N-element space is the N-element space plus one node in the middle of each
element; at the plan, the cost's gradient with respect to the middle node's coefficients g_e
and the Hessian's block there H_e give η_e = ½ g_eᵀ H_e⁻¹ g_e, the decrease of J one Newton step
on that node alone would bring. The middle nodes of different elements do not share an element,
so Σ η_e is the decrease of the quadratic model when only the new nodes move (a lower estimate of
J(N) − J(2N)). Limit terms are not included, so ``N: auto`` splits elements by another indicator,
``correction_indicators`` (the energy of the correction C(2N) − C(N) per element, which limits
shape), with Dörfler marking (``marked``): its meshes become non-uniform (``HermiteMesh.split``).
On a non-uniform mesh the 2N elements are its elements bisected, and the order is the one measured
on the last uniform mesh of the run.

Pure maths: no I/O.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from hoc_cli.banded import element_blocks
from hoc_cli.constraints import JointLimits
from hoc_cli.elements import HermiteMesh
from hoc_cli.planner import PlanResult, plan, resample
from hoc_cli.problem import ControlProblem
from hoc_cli.system import System

#: the order of J(N) − J* for a smooth problem: J is the squared norm of a residual of order h^(degree − 1)
SMOOTH_ORDER = {"quintic": 8.0, "cubic": 4.0}
#: the factor of d₂ when the order is not measured: 2ᵖ/(2ᵖ − 1) for p = 1, the largest for any p >= 1
UNMEASURED_FACTOR = 2.0
DEFAULT_ACCURACY = 1e-8
AUTO_START = 16  # N: auto starts here (the plan on 16 elements, then 32, 64, …)
AUTO_MAX_ELEMENTS = 1024
#: N: auto stops when the estimate is below accuracy / AUTO_SAFETY: the estimate is within a factor 2
#: of the true error on the problems tested (docs/accuracy.md), so the true error is then below accuracy
AUTO_SAFETY = 2.0
#: h-refinement: split the fewest elements holding this share of the correction indicators' sum ...
AUTO_SPLIT_SHARE = 0.8
#: ... and every element (reusing the estimate's solve on the bisected mesh) when that is this share of them
AUTO_SPLIT_ALL = 0.75


@dataclass(frozen=True, eq=False)
class ErrorEstimate:
    """The estimate of |J(N) − J*| / |J(N)| and what it is based on.

    relative : the estimate, or None when the plan (or the solve on 2N elements) did not converge;
    basis : JSON-ready description (method, N, J at each, measured and used order, factor);
    indicators : (N,) per-element indicators η_e / |J(N)|, or None; refined : the plan on 2N
    elements (warm-started from this one); wall_time_s, iterations : the estimate's own cost.
    """

    relative: float | None
    basis: dict
    indicators: np.ndarray | None = field(default=None, repr=False)
    refined: PlanResult | None = field(default=None, repr=False)
    wall_time_s: float = 0.0
    iterations: int = 0


def richardson(J_coarse: float | None, J: float, J_fine: float, *, order: str, tol: float,
               order_hint: float | None = None) -> tuple[float, dict]:
    """(relative estimate of |J − J*|, basis) from J on N/2 (or None), N and 2N elements.

    See the module docstring. ``tol`` is the solver's relative tolerance: the floor of the estimate.
    ``order_hint``: the order measured on an earlier mesh of the same run, used when J_coarse is None
    (a non-uniform mesh has no mesh of half its elements' lengths to measure it on).
    """
    scale = max(abs(J), 1e-300)
    floor = tol * scale
    d2 = J - J_fine
    d1 = None if J_coarse is None else J_coarse - J
    info: dict = {"order_measured": None, "order_used": None, "factor": None}
    if abs(d2) <= floor:
        info["note"] = "J(N) and J(2N) agree to the solver tolerance"
        return max(UNMEASURED_FACTOR * abs(d2), floor) / scale, info
    if d1 is not None and d1 * d2 > 0 and abs(d1) > abs(d2) and abs(d1) > floor:
        p = math.log2(d1 / d2)
        p_used = min(p, SMOOTH_ORDER[order])
        factor = 2.0**p_used / (2.0**p_used - 1.0)
        info.update(order_measured=p, order_used=p_used, factor=factor)
    elif d1 is None and order_hint is not None and d2 > 0:
        p_used = min(order_hint, SMOOTH_ORDER[order])
        factor = 2.0**p_used / (2.0**p_used - 1.0)
        info.update(order_used=p_used, factor=factor, note="order measured on an earlier (coarser) mesh of N: auto")
    else:
        factor = UNMEASURED_FACTOR
        info.update(factor=factor, note="order not measured (no J on N/2 elements, or J(N/2), J(N), J(2N) "
                    "not yet decreasing geometrically): factor 2, the largest for any order >= 1")
    return max(factor * abs(d2), floor) / scale, info


def element_indicators(system: System, result: PlanResult, cost: str) -> np.ndarray:
    """η_e (N,) of the plan on N elements: ½ g_eᵀ H_e⁻¹ g_e at the middle node of each element (absolute, as J).

    g_e (m·n,) is the gradient of I on 2N elements, at the plan, with respect to the coefficients
    of the node added in the middle of element e; H_e the Hessian's diagonal block there (its
    positive semi-definite part where the block is not positive definite).
    """
    mesh = result.mesh
    fine = bisected(mesh)
    problem = ControlProblem(system, fine, *result.problem.boundary, cost=cost, G=result.G)
    C = resample(mesh, result.coeffs, fine)
    ev = problem.evaluate(problem.layout.pack(C))
    q, dq, ddq = problem.op.apply(C)
    s = problem.sample_gradients(q, dq, ddq, jacobians=False)
    W = problem.op.w[:, None]
    g = problem.op.transpose(W * s.gq, W * s.gdq, W * s.gddq)  # (2N+1, m, n)
    mn = fine.m * problem.n
    g_mid = g[1::2].reshape(mesh.N, mn)
    Hs, GNs = problem.hessian_samples(ev)

    def middle_blocks(samples: np.ndarray) -> np.ndarray:  # node 2e+1: right end of element 2e, left of 2e+1
        B = element_blocks(problem.op_h, samples)
        return B[0::2, mn:, mn:] + B[1::2, :mn, :mn]

    H = middle_blocks(Hs)
    eta = np.empty(mesh.N)
    psd = None
    for e in range(mesh.N):  # N small (mn × mn) solves; once per plan, not in the solver's loop
        try:
            L = np.linalg.cholesky(H[e])
        except np.linalg.LinAlgError:
            psd = middle_blocks(GNs) if psd is None else psd
            L = np.linalg.cholesky(psd[e] + 1e-12 * np.trace(psd[e]) / mn * np.eye(mn))
        y = np.linalg.solve(L, g_mid[e])
        eta[e] = 0.5 * float(y @ y)
    return eta


def bisected(mesh: HermiteMesh) -> HermiteMesh:
    """The mesh with every element cut in two (2N elements; uniform when ``mesh`` is)."""
    return HermiteMesh(mesh.order, mesh.T, 2 * mesh.N) if mesh.uniform else mesh.split(np.arange(mesh.N))


def _refine(system: System, result: PlanResult, N: int | HermiteMesh, *, cost: str, method: str, tol: float,
            max_iter: int, limits: JointLimits | None) -> PlanResult:
    """The problem on N uniform elements (or on a given mesh) solved from ``result``'s trajectory at its
    nodes (exact when the new mesh holds the old one's nodes).
    """
    mesh = N if isinstance(N, HermiteMesh) else HermiteMesh(result.mesh.order, result.mesh.T, N)
    working = result.limits.working if result.limits is not None else None
    return plan(system, mesh, *result.problem.boundary, cost=cost, method=method, tol=tol, max_iter=max_iter,
                C_init=resample(result.mesh, result.coeffs, mesh), G=result.G, limits=limits, working=working)


def estimate(system: System, result: PlanResult, *, cost: str, method: str = "pr-cg", tol: float = 1e-10,
             max_iter: int = 5000, limits: JointLimits | None = None, order_hint: float | None = None) -> ErrorEstimate:
    """The error estimate of a converged plan (see the module docstring): one warm-started solve on
    2N elements, and one on N/2 unless the plan already holds it. Same cost, tol and limits as the plan.

    On a non-uniform mesh the 2N elements are its elements bisected and there is no N/2 solve: the
    order is ``order_hint`` (measured on an earlier mesh), else the factor 2.
    """
    start = time.perf_counter()
    N = result.mesh.N
    if not result.converged:
        return ErrorEstimate(None, {"method": "none", "note": "the plan did not converge"})
    kw = dict(cost=cost, method=method, tol=tol, max_iter=max_iter, limits=limits)
    fine = _refine(system, result, bisected(result.mesh), **kw)
    iterations = fine.optimizer.iterations
    if not fine.converged:
        return ErrorEstimate(None, {"method": "none", "note": f"the solve on {2 * N} elements did not converge"},
                             wall_time_s=time.perf_counter() - start, iterations=iterations)
    coarse = None
    if result.mesh.uniform and result.coarser is not None and result.coarser.mesh.uniform \
            and result.coarser.mesh.N * 2 == N:
        coarse = result.coarser
    coarse_source = "the plan's own continuation level"
    if coarse is None and N % 2 == 0 and result.mesh.uniform:
        coarse = _refine(system, result, N // 2, **kw)
        iterations += coarse.optimizer.iterations
        coarse_source = "solved from the plan's values at its nodes"
    J_coarse = coarse.J if coarse is not None and coarse.converged else None
    relative, info = richardson(J_coarse, result.J, fine.J, order=result.mesh.order, tol=tol,
                                order_hint=None if result.mesh.uniform else order_hint)
    eta = element_indicators(system, result, cost) / max(abs(result.J), 1e-300)
    basis = {"method": "richardson", "description": "J on N/2 (when available), N and 2N elements, the others solved "
             "from this plan; |J(N) - J*| ~ factor * (J(N) - J(2N)), factor = 2^p / (2^p - 1)", "N": [N // 2, N, 2 * N] if J_coarse is not None else [N, 2 * N],
             "J": [J_coarse, result.J, fine.J] if J_coarse is not None else [result.J, fine.J], **info}
    if J_coarse is not None:
        basis["coarse"] = coarse_source
    fine = replace(fine, levels=result.levels + fine.levels, coarser=result)
    return ErrorEstimate(relative, basis, eta, fine, time.perf_counter() - start, iterations)


def correction_indicators(system: System, result: PlanResult, refined: PlanResult, cost: str) -> np.ndarray:
    """ζ_e (N,): the energy of the correction that refining brings, element by element (absolute, as J).

    δ = C(2N) − C(N) on the bisected mesh (the plan prolonged exactly); ζ_e = ½ Σ δ_fᵀ H_f δ_f over the
    two halves f of element e, with H_f the Gauss-Newton blocks of the cost at the refined plan, so that
    Σ ζ_e = ½ δᵀ H δ ≈ J(N) − J(2N). Unlike η_e it sees limits: where a limit holds the plan on both
    meshes alike, δ and ζ_e vanish. ``N: auto`` splits the elements with the largest ζ_e.
    """
    fine = refined.mesh
    problem = ControlProblem(system, fine, *result.problem.boundary, cost=cost, G=refined.G)
    delta = refined.coeffs - resample(result.mesh, result.coeffs, fine)
    ev = problem.evaluate(problem.layout.pack(refined.coeffs))
    _, GNs = problem.hessian_samples(ev)
    B = element_blocks(problem.op_h, GNs)  # (2N, 2mn, 2mn), local order a·n + j
    loc = fine.local_coefficients(delta).reshape(fine.N, -1)
    zeta = 0.5 * np.einsum("ei,eij,ej->e", loc, B, loc)
    return zeta[0::2] + zeta[1::2]


def marked(indicators: np.ndarray, share: float) -> np.ndarray:
    """The fewest elements (indices, sorted) whose indicators hold ``share`` of their sum (Dörfler marking)."""
    order = np.argsort(indicators)[::-1]
    total = float(np.sum(indicators))
    if not total > 0:
        return np.arange(indicators.size)
    k = int(np.searchsorted(np.cumsum(indicators[order]), share * total)) + 1
    return np.sort(order[: min(k, indicators.size)])


@dataclass(frozen=True, eq=False)
class AutoResult:
    """``N: auto``: the first plan of the refinement whose estimate is below accuracy / ``AUTO_SAFETY``.

    plan, error : that plan and its estimate; steps : per mesh tried, {N, J, J_error_estimate, mesh,
    split} (and converged: False for a mesh whose solve failed: the refinement then stops and keeps
    the previous plan); reached : whether the estimate met the accuracy (else the finest converged
    plan tried, at most ``AUTO_MAX_ELEMENTS`` elements).
    """

    plan: PlanResult
    error: ErrorEstimate
    steps: tuple[dict, ...]
    reached: bool


def plan_auto(system: System, order: str, T: float, q0, dq0, q1, dq1, *, accuracy: float = DEFAULT_ACCURACY,
              cost: str = "covariant", method: str = "pr-cg", tol: float = 1e-10, max_iter: int = 5000,
              limits: JointLimits | None = None, start: int = AUTO_START, max_elements: int = AUTO_MAX_ELEMENTS,
              refine: str = "h", callback=None) -> AutoResult:
    """Plan on ``start`` equal elements, then refine (each mesh warm-started from the last) until the
    estimate <= accuracy / ``AUTO_SAFETY``.

    ``refine="h"``: split the fewest elements whose correction indicators (``correction_indicators``)
    hold ``AUTO_SPLIT_SHARE`` of their sum; the new mesh's plan starts from the last plan prolonged
    exactly (the same function), so J does not rise. When that is ``AUTO_SPLIT_ALL`` of the elements
    or more, every element is split, and the estimate's own solve on the bisected mesh is the next plan.
    ``refine="uniform"``: always that (N doubles; the meshes stay uniform). The solver tolerance is
    min(tol, accuracy/100).
    """
    if refine not in ("h", "uniform"):
        raise ValueError(f"refine must be 'h' or 'uniform', got {refine!r}")
    tol = min(tol, accuracy / 100)
    kw = dict(cost=cost, method=method, tol=tol, max_iter=max_iter, limits=limits)
    result = plan(system, HermiteMesh(order, T, start), q0, dq0, q1, dq1, callback=callback, **kw)
    steps: list[dict] = []
    hint = None  # the order measured on the last uniform mesh, for the estimates on non-uniform ones
    split = None  # how many elements were split to reach the mesh
    previous = None  # the last converged plan and its estimate
    while True:
        if previous is not None and not result.converged:
            # a finer mesh whose solve failed (not converged, infeasible at rounding level): keep the last
            # converged plan, which is the better answer, and say that the accuracy was not reached
            steps.append({"N": result.mesh.N, "J": result.J, "J_error_estimate": None,
                          "mesh": "uniform" if result.mesh.uniform else "nonuniform", "split": split, "converged": False})
            return AutoResult(previous[0], previous[1], tuple(steps), False)
        err = estimate(system, result, order_hint=hint, **kw)
        if err.relative is None and previous is not None and result.converged and previous[1].relative is not None:
            # the estimate's own solve (on the bisected mesh) failed; the plan refines the previous one
            # (its space holds the previous plan, J did not rise), so the previous estimate bounds its error
            J_prev = previous[0].J
            bound = (abs(J_prev - result.J) + previous[1].relative * abs(J_prev)) / max(abs(result.J), 1e-300)
            err = replace(err, relative=bound, basis={
                "method": "bound from the coarser mesh (the estimate's solve on the bisected mesh did not converge)",
                "N_coarser": previous[0].mesh.N, "J_coarser": J_prev, "estimate_coarser": previous[1].relative,
                "failed": err.basis})
        if err.basis.get("order_measured") is not None:
            hint = err.basis["order_used"]
        steps.append({"N": result.mesh.N, "J": result.J, "J_error_estimate": err.relative,
                      "mesh": "uniform" if result.mesh.uniform else "nonuniform", "split": split})
        reached = err.relative is not None and err.relative <= accuracy / AUTO_SAFETY
        if reached or err.refined is None:
            return AutoResult(result, err, tuple(steps), reached)
        previous = (result, err)
        cut = np.arange(result.mesh.N)
        if refine == "h":
            cut = marked(correction_indicators(system, result, err.refined, cost), AUTO_SPLIT_SHARE)
        if result.mesh.N + cut.size > max_elements:
            return AutoResult(result, err, tuple(steps), reached)
        split = int(cut.size)
        if cut.size >= AUTO_SPLIT_ALL * result.mesh.N:
            result = err.refined
            continue
        mesh = result.mesh.split(cut)
        working = result.limits.working if result.limits is not None else None
        result = plan(system, mesh, q0, dq0, q1, dq1, C_init=resample(result.mesh, result.coeffs, mesh),
                      G=result.G, working=working, callback=callback, **kw)
