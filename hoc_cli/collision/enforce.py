"""Collision avoidance enforced: the augmented-Lagrangian outer loop, with the certificate as its stopping test.

Imposed: d ≥ bound at ``POINTS_PER_ELEMENT`` points of every element (t = 0 and T excluded: x0 and
x1 are data, checked before the solve), for every pair that comes closer than bound + ``INFLUENCE``
at some point or has a positive multiplier, at every point where it is closer than bound +
``ROW_REACH`` or has a multiplier, re-selected each outer iteration (a pair is imposed well beyond
its contact: an inner solve may move the contact in time). bound = margin + inflation, the
inflation ``INFLATION`` (lowered for a pair whose x0 or x1 distance leaves less room). The terms
are ``constraint.CollisionTerms`` (PHR), added to the control problem through its ``terms`` hook.

The loop (one level of the planner's continuation):

1. Select the rows; solve min I + Φ from the current x (``minimize``: the plain solve; with joint
   limits, ``limit_rounds.LimitState.rounds``: their PHR terms join Φ, their multipliers, ρ and
   working set go on from the previous outer iteration, and the rounds stop once the plan is
   settled within its limits, or meets them exactly once the clearance is certified at ``tol``).
   The rows start from the distances at x (``constraint.RowStart``: rows that cannot reach their
   bound are not evaluated).
2. λ ← μ on the rows. The worst violation at the points, max(0, bound − d), decides ρ: × 10 when it
   did not fall to a quarter of the previous one and is still above the inflation (closer to the
   obstacle than the margin itself); within the inflation the multiplier updates finish the job.
3. When it is below ``VIOLATION_TOL`` the continuous trajectory is certified (``certify``, at the
   margin itself). Certified, the inner solve converged and the joint limits met: done (limits not
   met yet: the loop goes on). Not certified (the clearance
   dips between points): ``REFINE_POINTS`` points are added inside each interval the certificate
   could not prove, and the loop goes on; at most ``MAX_REFINEMENTS`` times.
4. Infeasible when ρ has grown ``RHO_RANGE``-fold and the violation, still above the inflation
   (the distance below the margin itself), no longer falls by a tenth; else the loop goes on (ρ at
   most ``RHO_MAX``·ρ0) until ``MAX_OUTER`` outer iterations, and the certificate decides: a plan
   that comes closer than the margin is infeasible, one that does not but is not proven clear is
   not converged.

Coarse levels (``full`` False) stop at step 3 without the certificate: they only start the next level.
Every start's loop and the starts together stop once their inner solves have spent ``MAX_ITERATIONS``
iterations: not converged, the message naming the budget and the closest pair.

A start in collision (``solve``): when the loop from the level's start ends infeasible, it runs
again from the minimum-jerk guess (when the start was a coarser level's plan) and from ``via_guess``
through each of the ``VIA_TRIES`` vias of ``guess.via_candidates`` whose straight path
q0 → q_v → q1 is clear at its samples, and keeps the lowest-cost converged plan; infeasible if none
converges. Each level starts at its own ρ0, with the coarser level's multipliers.
"""
from __future__ import annotations

import dataclasses
import functools
import logging
import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from hoc_cli.collision.certify import Certificate, certify
from hoc_cli.collision.constraint import CollisionTerms, RowStart, point_configurations, row_reach, sphere_rows_scene
from hoc_cli.collision.evaluate import distances
from hoc_cli.collision.guess import via_candidates, via_guess
from hoc_cli.collision.limit_rounds import LimitState, LimitWarm
from hoc_cli.collision.scene import CollisionScene
from hoc_cli.constraints.bounds import JointLimits
from hoc_cli.constraints.points import PointSet
from hoc_cli.constraints.prolong import Duals
from hoc_cli.elements import HermiteMesh
from hoc_cli.model.tree import RobotModel

_log = logging.getLogger(__name__)  # the outer iterations at DEBUG level
POINTS_PER_ELEMENT = 8
MIN_POINTS = 64       # points per level at least (a coarse level's path must not slip between its points)
INFLUENCE = 0.05      # m beyond the bound: pairs nearer than this at some point are imposed ...
ROW_REACH = 0.25      # m beyond the bound: ... at every point where they are nearer than this (or hold a multiplier)
INFLATION = 1e-3      # m imposed above the margin at the points
VIOLATION_TOL = 5e-4  # m: the points' worst violation at which the certificate is asked (half the inflation:
                      # the points are then 0.5 mm clear of the margin; the certificate decides)
RHO_START = 1.0       # ρ0 = RHO_START·max(|J|, 1e-6)/(T·c0²): the start's worst violation c0 (at least
MIN_VIOLATION = 0.01  # MIN_VIOLATION m) costs about J; cost units per m² per s
RHO_GROWTH = 10.0
RHO_RANGE = 1e4       # infeasible once ρ has grown this much and the violation no longer falls
RHO_RANGE_STEPS = round(math.log(RHO_RANGE) / math.log(RHO_GROWTH))  # ... that is, after this many growths by RHO_GROWTH
STALL_RATIO = 0.9
RHO_MAX = 1e7         # ρ stays below RHO_MAX·ρ0 (the inner problems' conditioning)
MAX_OUTER = 30
COARSE_MAX_OUTER = 8
REFINE_POINTS = 4
MAX_REFINEMENTS = 6
VIA_TRIES = 3
MAX_ITERATIONS = 5_000   # inner iterations in all, over one solve's outer iterations and starts: then it ends
VIA_MAX_OUTER = 10
SPHERE_ROWS = True    # obstacles are imposed against spheres along the capsules (constraint.sphere_rows_scene)
LOOSE_TOL = 1e-5      # the inner solves' relative tolerance until the points are clear and the clearance certified
COARSE_EXCESS = 2e-3  # m: a coarse level stops once its points are this close to the bound (it only starts the next)


@dataclass(frozen=True, eq=False)
class CollisionWarm:
    """A level's multipliers for the next: point times t (P,) s, weights w (P,) s, λ (P, Q), ρ (each level starts at
    its own ρ0; a re-solve on the same mesh N and points at this ρ, if larger); the joint limits' state
    (``limit_rounds.LimitWarm``), if any.
    """

    t: np.ndarray
    w: np.ndarray
    lam: np.ndarray
    rho: float
    limits: LimitWarm | None = None
    N: int = 0

    def stretched(self, factor: float) -> "CollisionWarm":
        """The state for the same task in ``factor`` times the duration (a free T's next fixed-T plan, warm-started
        from the nearest one's coefficients rescaled in time): the point times and weights scaled, each row's
        multiplier kept; the joint limits' multipliers on their rows of the stretched mesh, ρ restarting from its ρ0
        (as the goal rows' does, ``hoc_cli.goals.time_solver``).
        """
        limits = self.limits
        if limits is not None:
            rows = limits.duals.rows
            mesh = rows.mesh
            longer = (HermiteMesh(mesh.order, mesh.T * factor, mesh.N) if mesh.uniform
                      else HermiteMesh.from_nodes(mesh.order, mesh.nodes * factor))
            duals = Duals(dataclasses.replace(rows, mesh=longer), limits.duals.mu_lo, limits.duals.mu_hi)
            limits = LimitWarm(duals, None, None)
        return dataclasses.replace(self, t=self.t * factor, w=self.w * factor, limits=limits)


@dataclass(frozen=True, eq=False)
class CollisionOutcome:
    """The outer loop's result on one level.

    status : "converged" | "infeasible" | "not_converged"; message; certificate : the plan's (None on
    coarse levels); outer_iterations; rho; rows : rows imposed last; points : points used;
    start : "start" (the level's start: the guess or the coarser level's plan), "guess" (the minimum-jerk
    guess, after the coarser plan failed) or "via" (a via guess); warm : multipliers for the next level;
    proved : what ``certificate`` is the certificate of: (model, scene, mesh, coefficients (N+1, m, n)), or None.
    """

    status: str
    message: str
    certificate: Certificate | None
    outer_iterations: int
    rho: float
    rows: int
    points: int
    start: str
    warm: CollisionWarm | None
    proved: tuple | None = None

    def certificate_of(self, model: RobotModel, scene: CollisionScene, mesh, C: np.ndarray) -> Certificate | None:
        """``certificate`` when it is ``certify(model, scene, mesh, C)``'s (the same model and scene, the same mesh and
        coefficients: the report of the plan the loop certified takes it instead of certifying it again), else None.
        """
        if self.certificate is None or self.proved is None:
            return None
        m, sc, me, coeffs = self.proved
        same_mesh = me is mesh or (me.order == mesh.order and np.array_equal(me.nodes, mesh.nodes))
        if m is model and sc is scene and same_mesh and np.array_equal(coeffs, C):
            return self.certificate
        return None

    def summary(self) -> dict:
        """``collision_enforce`` for the JSON summary."""
        return {"status": self.status, "outer_iterations": self.outer_iterations, "points": self.points,
                "rows": self.rows, "start": self.start}


def _per_element(mesh) -> int:
    """Points per element: ``POINTS_PER_ELEMENT``, more on coarse meshes (``MIN_POINTS`` in all)."""
    return max(POINTS_PER_ELEMENT, -(-MIN_POINTS // mesh.N))


def base_points(mesh, end: bool = False) -> PointSet:
    """``_per_element`` points per element at s = (j + ½)/S (not t = 0), and t = T when ``end`` (a free final q)."""
    S = _per_element(mesh)
    e = np.repeat(np.arange(mesh.N), S)
    s = np.tile((np.arange(S) + 0.5) / S, mesh.N)
    if end:
        e, s = np.append(e, mesh.N - 1), np.append(s, 1.0)
    return PointSet.build(mesh, e, s, mesh.hs[e] / S)


def _free_q1(problem) -> bool:
    """Whether the problem's final q is free (a link goal): its layout frees the last node's q."""
    n = problem.layout.n
    return bool(problem.layout.free.reshape(problem.mesh.N + 1, -1, n)[-1, 0].any())


def _add_points(points: PointSet, intervals) -> PointSet:
    """``points`` plus ``REFINE_POINTS`` points inside each interval [t0, t1] (weights h_e/S)."""
    mesh = points.mesh
    if not intervals:
        return points
    frac = (np.arange(REFINE_POINTS) + 1) / (REFINE_POINTS + 1)
    t = np.concatenate([t0 + frac * (t1 - t0) for t0, t1 in intervals])
    e, s = mesh.element_of(t)
    e = np.concatenate([points.e, e])
    s = np.concatenate([points.s, s])
    return PointSet.build(mesh, e, s, mesh.hs[e] / _per_element(mesh))


def _transfer(warm: CollisionWarm, points: PointSet) -> np.ndarray:
    """λ (P, Q) on ``points`` from a warm start: the nearest old point's multiplier per unit time × the new weight."""
    order = np.argsort(warm.t)
    t_old = warm.t[order]
    t = points.t
    i = np.clip(np.searchsorted(t_old, t), 1, t_old.size - 1) if t_old.size > 1 else np.zeros(t.size, int)
    if t_old.size > 1:
        i = np.where(np.abs(t_old[i - 1] - t) <= np.abs(t_old[i] - t), i - 1, i)
    k = order[i]
    return warm.lam[k] / warm.w[k, None] * points.weight[:, None]


@dataclass(frozen=True, eq=False)
class CollisionConstraint:
    """d ≥ margin on the whole trajectory for every pair of ``scene`` (module docstring): what
    ``OptimalControlProblem.constraint`` holds and ``planner.plan`` calls level by level.
    """

    model: RobotModel
    scene: CollisionScene
    _rows: list = field(default_factory=list, repr=False)  # the rows' scene, built on first use

    def solve(self, problem, x0: np.ndarray, tol: float, minimize: Callable, *, warm: CollisionWarm | None = None,
              full: bool = True, system=None, limits: JointLimits | None = None, working: np.ndarray | None = None):
        """(inner result with the plan's x, J without Φ, the limits' ``EnforceResult`` or None, ``CollisionOutcome``).

        ``minimize(problem, x, tol) -> OptimizeResult`` is the unconstrained minimiser of ``problem`` (with its
        ``terms``). With ``limits`` (and ``system``, the dynamics) the joint limits are terms of the same loop
        (``limit_rounds``), their working set starting from ``working`` (K, n) when given.
        Without ``warm`` (the plan's first level) a start the loop cannot free tries via guesses.
        """
        spent = [0]  # the inner iterations of every start: at most MAX_ITERATIONS (plus the solve that crossed it)

        def counted(p, x: np.ndarray, tol_inner: float):
            res = minimize(p, x, tol_inner)
            spent[0] += res.iterations
            return res

        inner = functools.partial(self._loop, problem, tol=tol, minimize=counted, full=full,
                                  limits=None if limits is None or not limits.any else (system, limits, working),
                                  spent=lambda: spent[0] >= MAX_ITERATIONS)
        got = inner(x0, warm=warm, max_outer=MAX_OUTER if full else COARSE_MAX_OUTER, start="start")
        if got[3].status != "infeasible":
            return got
        mesh = problem.mesh
        q0, dq0, q1, dq1 = problem.boundary
        starts = [] if warm is None else [("guess", problem.initial_guess())]  # a coarser level's plan failed here
        for qv, clearance in via_candidates(self.model, self.scene, q0, q1, count=VIA_TRIES):
            if clearance >= 0:  # a via whose straight path collides too is no way round
                starts.append(("via", problem.layout.pack(via_guess(mesh, q0, dq0, qv, q1, dq1))))
        best = None
        for label, x in starts:
            if spent[0] >= MAX_ITERATIONS:
                break
            tried = inner(x, warm=None, max_outer=VIA_MAX_OUTER, start=label)
            if tried[3].status == "converged" and (best is None or tried[1] < best[1]):
                best = tried
        if best is None:
            o = got[3]
            vias = sum(label == "via" for label, _ in starts)
            message = f"{o.message} (from the start and {vias} via guesses)"
            return got[:3] + (dataclasses.replace(o, message=message),)
        return best

    def rows_scene(self) -> CollisionScene:
        """The pairs imposed (``constraint.sphere_rows_scene``: obstacles against spheres along the capsules)."""
        got = self._rows
        if not got:
            scene = sphere_rows_scene(self.scene) if SPHERE_ROWS else self.scene
            got.extend([scene, row_reach(self.model, scene, np.arange(scene.size))])
        return got[0]

    def _pair_reach(self) -> np.ndarray:
        """(Q', n) ``constraint.row_reach`` of every pair of ``rows_scene``."""
        self.rows_scene()
        return self._rows[1]

    def _bounds(self, problem, scene: CollisionScene) -> np.ndarray:
        """The bound (Q,) m per pair of ``scene``: margin + INFLATION, or less where x0 or x1 is nearer (half its
        room; below the margin for a sphere pair whose padding takes the room).
        """
        q0, _, q1, _ = problem.boundary
        margin = self.scene.margin
        ends = distances(self.model, scene, np.stack([q0] if _free_q1(problem) else [q0, q1])).min(axis=0)
        return margin + np.minimum(0.5 * (ends - margin), INFLATION)

    def _loop(self, problem, x: np.ndarray, *, tol: float, minimize: Callable, full: bool, limits,
              warm: CollisionWarm | None, max_outer: int, start: str, spent: Callable[[], bool]):
        model, mesh, exact = self.model, problem.mesh, self.scene
        lim = None if limits is None else LimitState(*limits, problem, None if warm is None else warm.limits)
        scene = self.rows_scene()  # the rows; the certificate takes the exact pairs
        bound = self._bounds(problem, scene)                            # (Q,)
        points = base_points(mesh, end=_free_q1(problem))
        J0 = problem.bare_cost(x)
        D = distances(model, scene, point_configurations(points, problem.coefficients(x)))
        known = (x, points)  # D is at this plan and these points
        c0 = max(float(np.max(bound - D, initial=0.0)), MIN_VIOLATION)
        rho0 = RHO_START * max(abs(J0), 1e-6) / (mesh.T * c0 ** 2)
        lam, rho = np.zeros((points.size, scene.size)) if warm is None else _transfer(warm, points), rho0
        if warm is not None and warm.N == mesh.N and np.array_equal(warm.t, points.t):  # a re-solve on the same mesh
            rho = max(rho0, warm.rho)                                                   # and points: ρ goes on with λ
        prev = math.inf
        grown = 0  # how many times ρ has grown (counted: ρ0·10⁴ computed by products is not ρ0·1e4 exactly)
        refinements = 0
        tight = float(np.max(bound - D, initial=0.0)) <= VIOLATION_TOL  # the start is clear at the points already
        status, message, cert, res, rows = "not_converged", "", None, None, 0
        own = problem.terms  # the problem's own terms (a goal's rows) stay; Φ joins them
        limits_met = True
        outer = 0
        spent_out = False  # the loop ended on the iteration budget (not converged, whatever the clearance)
        try:
            for outer in range(1, max_outer + 1):
                if outer > 1 and spent():
                    outer -= 1
                    message = f"stopped when its inner solves had spent {MAX_ITERATIONS} iterations (outer iterations: {outer})"
                    spent_out = True
                    break
                if known[0] is not x or known[1] is not points:
                    D = distances(model, scene, point_configurations(points, problem.coefficients(x)))   # (P, Q)
                near = ((D < bound + INFLUENCE) | (lam > 0)).any(axis=0)   # (Q,): imposed ...
                p, k = np.nonzero(near & ((D < bound + ROW_REACH) | (lam > 0)))  # ... where within ROW_REACH
                rows = p.size
                start_rows = RowStart(point_configurations(points, problem.coefficients(x)), D[p, k],
                                      self._pair_reach()[k])  # rows that cannot reach their bound are skipped
                terms = CollisionTerms(model, scene, points, p, k, lam[p, k], rho, bound[k], start_rows, curvature=full)
                problem.terms = own + (terms,)
                inner_tol = tol if tight and full else max(tol, LOOSE_TOL)
                if lim is None:
                    res = minimize(problem, x, inner_tol)
                    x = res.x
                else:  # the joint limits' rounds, from their multipliers of the previous outer iteration
                    res, x, limits_met = lim.rounds(problem, x, inner_tol, minimize, exact=tight and full, polish=not full,
                                                      spent=spent)
                D = distances(model, scene, point_configurations(points, problem.coefficients(x)))
                known = (x, points)
                lam = np.zeros_like(D)
                lam[p, k] = terms.multipliers(D[p, k])
                excess = float(np.max(bound - D, initial=0.0))
                if _log.isEnabledFor(logging.DEBUG):
                    _log.debug(f"collision outer {outer} N {mesh.N} start {start} it {res.iterations} "
                               f"J {problem.bare_cost(x):.10g} rows {rows} excess {excess:.3e} rho {rho:.3e} "
                               f"min d {float(D.min()):.4f}"
                               + ("" if lim is None else f" limits met {limits_met} rho {lim.rho or 0:.3e} "
                                  f"working {int(lim.working.sum())}"))
                if not full and excess <= COARSE_EXCESS:
                    status, message = "converged", f"near the bound at the points (outer iterations: {outer})"
                    break
                if excess <= VIOLATION_TOL:
                    if not full:
                        status, message = "converged", f"clear at the points (outer iterations: {outer})"
                        break
                    proved = problem.coefficients(x)
                    cert = certify(model, exact, mesh, proved)
                    if cert.certified and not tight:  # once more with the plan's tolerance, λ updated
                        tight = True
                        continue
                    if cert.certified and not limits_met and outer < max_outer:
                        continue  # the joint limits' multipliers still move
                    if cert.certified:
                        if res.converged and limits_met:
                            status = "converged"
                            message = (f"clearance certified >= {scene.margin:g} m on the whole trajectory "
                                       f"(outer iterations: {outer})")
                        elif not limits_met:
                            message = "clearance certified, but the joint limits were not met"
                        else:
                            message = f"clearance certified, but the inner solve stopped: {res.message}"
                        break
                    if refinements < MAX_REFINEMENTS:
                        refinements += 1
                        old = points.size
                        points = _add_points(points, [c["interval"] for c in cert.collisions])
                        lam = np.concatenate([lam, np.zeros((points.size - old, scene.size))])
                        continue
                    message = "clear at the points, but the clearance between them could not be certified"
                    break
                cert = None
                if excess > 0.25 * prev and excess > INFLATION:  # within the inflation the multipliers finish
                    if grown >= RHO_RANGE_STEPS and excess > STALL_RATIO * prev and excess > INFLATION:
                        status = "infeasible"  # still in collision (beyond the margin) and no longer improving
                        break
                    rho = min(rho * RHO_GROWTH, rho0 * RHO_MAX)
                    grown += 1
                prev = min(prev, excess) if math.isfinite(prev) else excess
            else:
                message = f"not clear after {max_outer} outer iterations"
        finally:
            problem.terms = own
        C = problem.coefficients(x)
        if cert is None and full:
            proved = C
            cert = certify(model, exact, mesh, C)
        if status != "converged":
            if cert is not None:
                closest, pair, t = cert.distance, cert.pair, cert.t
            else:
                D = distances(model, scene, point_configurations(points, C))
                i, j = np.unravel_index(int(np.argmin(D)), D.shape)
                closest, pair, t = float(D[i, j]), scene.names[j], float(points.t[i])
            a, b = pair
            how = f"overlap by {-closest:.4g} m" if closest < 0 else f"come within {closest:.4g} m"
            if spent_out:
                message = f"{message}: {a} and {b} {how} at t = {t:.4g} s (margin {scene.margin:g} m)"
            elif status == "infeasible" or closest < scene.margin:
                status = "infeasible"
                message = (f"no collision-free trajectory was found: {a} and {b} {how} at t = {t:.4g} s "
                           f"(margin {scene.margin:g} m)")
        J = problem.bare_cost(x)
        er = None if lim is None else lim.result(res, x, J, outer)
        warm_next = CollisionWarm(points.t, points.weight, lam, rho, None if lim is None else lim.warm(), mesh.N)
        outcome = CollisionOutcome(status=status, message=message, certificate=cert if full else None,
                                   outer_iterations=outer, rho=rho, rows=rows, points=points.size, start=start,
                                   warm=warm_next, proved=(model, exact, mesh, np.array(proved)) if full and cert is not None else None)
        return dataclasses.replace(res, x=x), J, er, outcome
