"""A free final time by Newton (SQP) steps in (x, T) together; and the same steps at a fixed T (``plan_fixed_time``).

``hoc_cli.free_time.minimize_time`` finds the optimal T by a one-dimensional search over fixed-T solves
(each a full solve with its goal and limit loops: 7 solves and ~50 s for the lbr7 catch). Here the warm
replan's SQP steps (``hoc_cli.goals.replan``: x, T and the multipliers together, the limits as inequality
rows of each step's QP) move x and T to where F'(T) = dJ*/dT + weight vanishes or a bound holds it: the
same first-order conditions as the search's end.

1. The plan at the guess T: with limits enforced, the same Newton steps at fixed T from the initial
   trajectory with zero multipliers and an empty working set (``GoalSolver.initial``; the limits are the
   steps' inequality rows), a step halved while it does not decrease the ℓ1 merit function
   (``replan_qp.MeritTest``; a Levenberg-Marquardt shift of the Newton matrix grows while steps are cut)
   or raises the goal rows' violation above ``COLD_FLOOR``; then, as
   ``plan_goals`` does, while J with G + 4 Gauss points per element differs from J by more than 1e-12
   relative, G grows by 4 and the steps go on from the plan (its multipliers by least squares,
   ``hoc_cli.goals.warm.previous_plan``). When those steps do not converge within
   ``COLD_STEPS``, and without limits, one fixed-T solve (``plan_goals``: continuation, the goal rows' and
   the limits' augmented-Lagrangian loops). The lbr7 catch: 25 steps; a two-link link goal: 4.
   When the initial trajectory at the guess breaks a kinematic limit, a restoration first minimises the
   violation of the goal rows and the (tightened) limit rows over x and T (``hoc_cli.goals.restoration``): at a
   guess T with no plan within the limits (the UR5's fast catch) T moves to where there is one, and the plan
   at the guess is made there, from the restored trajectory. Where the coarse stage below applies, the restoration
   runs on its elements (``_restored``: the UR5's fast catch 11 restoration steps there against 13 on its 8
   elements, then 10 steps in x and T on 4 elements and 3 on the mesh, where the steps on the mesh took 29 + 30). The
   restoration ends at ``RESTORE_TOL``, and the coarse steps in x and T from it take ``RESTORED_FLOOR``.
   The coarse stage starts its steps in x and T from the restored trajectory at once, without steps at the restored
   T (T has left the guess already; on the UR5's fast catch those took 11 steps, then 10 in x and T).
   When the restoration stalls (a local minimum of the violation), it restarts from the initial trajectory at the middle
   and the ends of T's range (``_restore_either_end``). When every one stalls, one with T at a bound of its range (no
   T there where the goal meets the limits), and the steps at the guess do not converge, the plan ends there, not
   converged (``_unfinished``), without the search.
2. The steps in x and T from that plan (the same quadrature test at their end).
3. When those do not converge, the search runs, seeded with the plan at the guess.

On a uniform mesh of 2·``COARSE_N`` elements or more without vias, when the start of 1. on
``COARSE_N`` elements (resampled, or restored there) keeps the limits, 1. and 2. run first on those elements (steps of a programme a fraction
of the size), and the coarse optimum, resampled to the mesh at its T with least-squares multipliers, starts the
steps in x and T there (``_coarse_first``). The lbr7 catch at N = 8, 16, 32: 6 to 7 + 7 steps on 4 elements and
4 to 6 on the mesh (each programme there of up to ~700 unknowns at N = 32). Under the torque cost: 85 + 10 steps on
4 elements and 6 + 1 on the mesh; when the coarse optimum is farther from the mesh's, the steps in x and T from it stop after
``FINE_STEPS`` and steps at the coarse T (merit test) and in x and T follow. The optimum reached is the one the steps on the mesh
reach: J to 1e-14 relative, T within the steps' own stopping test (|F| ≤ 1e-7·|J|/T leaves T uncertain by
1e-10 to 5e-9 relative on the catch, measured). Its limit multipliers are then re-estimated by least squares
(``_canonical_multipliers``: those of a limit held along whole elements are not unique, and the programme's pick
depends on the path). When a coarse stage does not converge, 1. and 2. run on the mesh.

The coarse stage stops at a relative accuracy of ``COARSE_ACCURACY`` (the model decrease, the goal rows and ∂ℒ/∂T;
the limit rows and the exact check as on the mesh), as ``plan_goals``' coarse levels: its optimum differs from the
mesh's by the discretisation anyway. With a free T its steps in x and T stop at ``COARSE_FREE_ACCURACY``, about that
difference (the lbr7 catch: J 5e-4, T 2e-4 relative), and its steps at the guess sooner, at ``COARSE_START_ACCURACY``:
they only start the steps in x and T, which move T away from the guess by 20 %; not at their start, whose first
programme can predict a small decrease far from the optimum (the torque catch's). Its cost, gradient and exact Hessian
take ``COARSE_G`` Gauss points per element (the mesh's G when that is fewer): the quadrature's change of the coarse
optimum is far below the discretisation's.

``plan_fixed_time`` is 1. alone at a fixed T (no restoration: T cannot move), coarse first where that applies, with
the quadrature test and ``_canonical_multipliers``: ``hoc_cli.solve``'s fixed-T goal plan within enforced limits
(``replan_fixed_time`` from an earlier plan, ``--init``). The steps follow the optimum nearest the initial
trajectory, as IPOPT's do, where ``plan_goals``' first augmented-Lagrangian subproblem may leave it for any other
(docs/goals.md, "Goal rows").

Moving T only once the plan at the guess has converged keeps the search's local optimum: steps in x
and T from the initial trajectory reached the catch's optimum in fewer steps, but on a two-link link
goal they ran to T's upper bound, a local optimum of J + weight·T 40 % dearer than the interior one.

Pure maths: no I/O.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np

from hoc_cli.elements import HermiteMesh
from hoc_cli.free_time import FreeTimeResult, TimePoint, minimize_time, plan_time_derivative
from hoc_cli.goals.active_limits import kinematic_rows
from hoc_cli.goals.mesh import mesh_fractions, scaled_mesh
from hoc_cli.goals.replan import TimeRange, replan
from hoc_cli.goals.restoration import restore
from hoc_cli.optimize import Status
from hoc_cli.optimize.blas import one_thread
from hoc_cli.planner import QUADRATURE_RTOL, resample

MAX_STEPS = 120  # Newton steps in x and T from the plan at the guess before the search takes over (the lbr7 catch
# under the torque cost takes 37; the search after them costs minutes there)
COLD_STEPS = 200  # Newton steps at the guess T from the initial trajectory before ``plan_goals`` takes over (the lbr7
# catch under the torque cost takes 86, where ``plan_goals`` takes 50 s)
COARSE_N = 4  # elements of the mesh on which a cold free-T plan of 2·COARSE_N elements or more first finds its T
RESTORE_TOL = 1e-4  # the restoration ends feasible with the goal rows met to this (m, rad, m/s) and the tightened
# rows to this of their size (inside the limits by ``restoration.MARGIN``): the SQP steps meet the rows from there, where
# its Gauss-Newton steps to 1e-9 cost the UR5's fast catch from 0.5 s 2 restoration steps and 3 coarse steps more
RESTART_GAP = 0.05  # a restoration restarts (``_restore_either_end``) only at a T this far (relative) from the start's
FINE_STEPS = 20  # steps in x and T from the resampled coarse optimum (the lbr7 catch: 5-7) before steps at the coarse T
RESTORED_FLOOR = 5e-2  # the same of the coarse steps in x and T from a restored trajectory: it meets the goal rows, but
# its J is far above the optimum's (the UR5's fast catch: 619 against 99), and the first long steps curve off the rows
# (the catch from 0.5 s: 10 steps there where 2 cm takes 13; from 0.6 s: 8, then 3 on the mesh, where with 2 cm the
# coarse steps ran to their limit of 120 and the mesh's took 7 at the restored T and 5 in x and T)
COLD_FLOOR = 1e-2  # m, rad, m/s: the goal rows' violation a step from scratch may reach undamped
FREE_COLD_FLOOR = 2e-2  # the same on the coarse stage of a free T, whose steps in x and T move the target (the lbr7
# catch: 1 cm halved a corrected step at 1.2e-2 thrice, twice); the fixed-T goal plans keep COLD_FLOOR (the Panda reach:
# 46 steps with 2 cm, 41 with 1 cm)
COARSE_ACCURACY = 1e-6  # the coarse stage's stopping test (decrement and ∂ℒ/∂T relative, goal rows in m, rad, m/s), as
# ``plan_goals``' coarse levels: its optimum differs from the mesh's by the discretisation (5e-4 of J on the lbr7 catch)
COARSE_FREE_ACCURACY = 1e-4  # the same test of the coarse steps in x and T: about the coarse optimum's distance to the
# mesh's (the lbr7 catch: J 5e-4, T 2e-4 relative), which the steps on the mesh cover anyway (7 steps there instead of
# 8 to COARSE_ACCURACY, then 4 on the mesh either way)
COARSE_G = 5  # Gauss points per element of the coarse stage (the cost, its gradient and its exact Hessian; the mesh's: 8 for
# quintic elements): the coarse optimum then moves by 3e-7 of J on the UR5's fast catch (6e-8 with 6 points), far less than
# the 2.5e-5 between it and the mesh's optimum; the same steps on both UR5 tasks with 5/8 of the samples' dynamics. The
# steps on the mesh from the coarse optimum vary with its last digits: on the lbr7 catch at N = 32, 4 from 5, 7 or 8
# points, 6 from 6 (catch_ball.yaml -N 32)
COARSE_START_ACCURACY = 1e-3  # the same test of the coarse steps at the guess T before those in x and T (a free T): they
# only start the steps in x and T, which move T by 20 % on the lbr7 catch (7 steps there instead of 9, then 7 either way);
# not at the start itself (the lbr7 catch under the torque cost: its first programme predicts 0.24 of J = 614, where
# the optimum at the guess is 458; from there the steps in x and T took 110-120 where they take 23 from that optimum)


@one_thread()  # one BLAS thread while solving (hoc_cli/optimize/blas.py)
def minimize_time_sqp(solve: Callable[[float, TimePoint | None], TimePoint], system, goals, T_min: float,
                      T_max: float, *, guess: float | None = None, weight: float = 0.0, limits=None,
                      max_steps: int = MAX_STEPS, cold_steps: int = COLD_STEPS, coarse: int = COARSE_N) -> FreeTimeResult:
    """The free-T optimum (module docstring); ``solve`` as ``minimize_time``'s (a ``GoalSolver``, whose results
    are ``GoalResult``; without an ``initial`` method the steps from scratch are skipped); ``goals``: the
    ``Goals``; ``limits``: the enforced ``JointLimits`` or None; ``cold_steps`` = 0 skips the steps from scratch.
    """
    guess = math.sqrt(T_min * T_max) if guess is None else min(max(guess, T_min), T_max)
    span = TimeRange(T_min, T_max, weight)
    initial = getattr(solve, "initial", None)
    first = None
    if initial is not None and cold_steps > 0 and limits is not None and limits.any:
        start = initial(guess)
        level, stalled = None, False  # the start on ``coarse`` elements, when the restoration made it there
        restored = None  # restored on ``coarse`` elements: makes the start on the mesh, when the coarse stage fails
        if _breaks_limits(system, start, limits):  # perhaps no plan at the guess: T moves to where there is one
            restored, level, stalled, guess = _restored(system, start, goals, limits, span, coarse, initial)
            if level is None:
                start, restored = restored(), None
        # (with ``level`` the coarse stage reads only the mesh's order, N and kind, x0, the cost and G of ``start``)
        coarsened = (_coarse_first(system, start, goals, limits, span, cold_steps, max_steps, coarse, level=level)
                     if coarse else None)
        if coarsened is not None:
            return coarsened
        start = restored() if restored is not None else start
        r = replan(system, start, goals, limits=limits, fallback=False, max_steps=cold_steps,
                   violation_floor=COLD_FLOOR, merit=True)
        if not r.converged and stalled:  # the violation's minimum at T's bound: no T in range meets the limits
            return _unfinished(r, span)
        r = _with_quadrature(r, system, goals, None, limits, max_steps) if r.converged else None
        if r is not None:
            plan = r.plan
            d = plan_time_derivative(plan, system, limits, goals=plan.terms if plan.problem.points else None)
            first = TimePoint(T=guess, J=plan.J, dJ_dT=d, result=plan)
    if first is None:
        first = solve(guess, None)
    if getattr(first.result, "converged", False):
        r = replan(system, first.result, goals, free=span, limits=limits, fallback=False, max_steps=max_steps)
        r = _with_quadrature(r, system, goals, span, limits, max_steps) if r.converged else None
        if r is not None:
            point = _point(r)
            return _result(point, [first, point], T_min, T_max, weight)

    def seeded(T: float, nearest: TimePoint | None) -> TimePoint:
        return first if T == first.T else solve(T, nearest)

    return minimize_time(seeded, T_min, T_max, guess=guess, weight=weight)


def _restored(system, start, goals, limits, span: TimeRange, coarse: int, initial: Callable | None = None):
    """(a function making the start of the steps on the mesh of ``start``, the start on ``coarse`` elements or None,
    whether the restoration on the mesh stalled at a bound of T, the start's T) after the restoration (``hoc_cli.goals.restoration.restore``) of
    ``start``, the initial trajectory at the guess that breaks a kinematic limit: both at the restored T with zero
    multipliers, or ``start`` itself and None when no T was found. Stalled at a bound: the violation's minimum over x
    and T sits at the end of T's range, where it still decreases beyond it (the UR5's fast catch with T ≤ 0.5 s); a stall
    inside the range is no such evidence (the lbr7 catch with a via: stalled at 0.35 s, where the search over T then
    finds the optimum at 0.466 s).

    Where ``_coarse_first`` applies (``_coarsens``), the restoration runs on the ``coarse`` elements it starts from (each
    step's programme a fraction of the size; the initial trajectory, one quintic, is the same there): the UR5's fast
    catch restores in 11 steps there against 13 on its 8 elements, and the coarse optimum is then 3 steps from the mesh's.
    Its trajectory resampled to the mesh of ``start`` (exact when the coarse nodes are nodes of the mesh) starts the
    steps on the mesh when the coarse stage does not converge; when the coarse restoration finds no T, the restoration
    runs on the mesh of ``start`` (as where the coarse stage does not apply).
    """
    from hoc_cli.goals.warm import previous_plan

    mesh = start.mesh
    q0, dq0 = start.problem.boundary[:2]
    cost, G = start.problem.cost, start.G

    def plan_on(level: HermiteMesh, C: np.ndarray, G: int = G):
        return previous_plan(system, level, C, q0, dq0, goals, cost=cost, G=G, multipliers="zeros")

    if coarse and _coarsens(mesh, goals, coarse):
        def coarse_start(plan):
            level = HermiteMesh(mesh.order, plan.mesh.T, coarse)
            return plan_on(level, resample(plan.mesh, plan.coeffs, level), _coarse_gauss(G))

        found, _ = _restore_either_end(system, start, goals, limits, span, coarse_start, initial)
        if found.feasible:
            level = HermiteMesh(mesh.order, found.T, coarse)
            fine = HermiteMesh(mesh.order, found.T, mesh.N)
            return (lambda: plan_on(fine, resample(level, found.coeffs, fine)), plan_on(level, found.coeffs, _coarse_gauss(G)),
                    False, found.T)
    found, at_bound = _restore_either_end(system, start, goals, limits, span, lambda plan: plan, initial)
    if not found.feasible:
        return lambda: start, None, at_bound, mesh.T
    restored = plan_on(scaled_mesh(mesh.order, found.T, mesh.N, mesh_fractions(mesh)), found.coeffs)
    return lambda: restored, None, False, found.T


def _restore_either_end(system, start, goals, limits, span: TimeRange, on: Callable, initial: Callable | None):
    """(the ``Restoration`` from ``on(start)``, whether a restoration stalled at a bound of T). When it stalls (a local
    minimum of the violation, not feasible) and ``initial`` (T ↦ the initial trajectory at T) is given, the restoration
    runs again from ``on(initial(T₁))`` for T₁ the geometric middle of T's range, then its upper and its lower end
    (those more than ``RESTART_GAP`` from the start's T), and the first feasible one is returned: the violation over x and
    T has local minima away from the T where the goal meets the limits (the UR5's fast catch: from the guess 0.4 s it
    stalls at 0.31 s with the goal rows 7 cm off, from 0.8 s at 0.47 s and 53 cm, where the search over T then ran for
    minutes; from the middle 0.49 s it restores in 18 and 12 steps).
    """
    found = restore(system, on(start), goals, limits, span=span, tol=RESTORE_TOL)
    at_bound = found.stalled and found.T in (span.min, span.max)
    if found.feasible or not found.stalled or initial is None:
        return found, at_bound
    T0 = start.mesh.T
    for T1 in (math.sqrt(span.min * span.max), span.max, span.min):
        if abs(T1 - T0) <= RESTART_GAP * T0:
            continue
        again = restore(system, on(initial(T1)), goals, limits, span=span, tol=RESTORE_TOL)
        if again.feasible:
            return again, False
        at_bound = at_bound or (again.stalled and again.T in (span.min, span.max))
    return found, at_bound


def _coarsens(mesh, goals, coarse: int) -> bool:
    """Whether ``_coarse_first`` applies on ``mesh``: uniform, at least 2·``coarse`` elements, no vias."""
    return mesh.uniform and mesh.N >= 2 * coarse and not goals.vias


def _coarse_gauss(G: int) -> int:
    """The Gauss points per element of the coarse stage: ``COARSE_G``, or G when that is fewer."""
    return min(G, COARSE_G)


def _coarse_first(system, start, goals, limits, span: TimeRange, cold_steps: int, max_steps: int,
                  coarse: int, level=None) -> FreeTimeResult | None:
    """``_coarse_replan`` as the free-T optimum (a ``FreeTimeResult``), or None."""
    record: list = []  # every replan's outcome: the plan reports their steps and evaluations together
    r = _coarse_replan(system, start, goals, limits, span, cold_steps, max_steps, coarse, level=level, record=record)
    if r is None:
        return None
    point = TimePoint(T=r.T, J=r.plan.J, dJ_dT=r.dJ_dT, result=_with_work(r.plan, record))
    return _result(point, [point], span.min, span.max, span.weight)


def _coarse_replan(system, start, goals, limits, span: TimeRange | None, cold_steps: int, max_steps: int,
                   coarse: int, level=None, record: list | None = None):
    """The free-T optimum on the mesh of ``start`` (the initial trajectory at the guess, or the restored one) by way of
    ``coarse`` elements: ``start`` resampled to them (zero multipliers), the steps from scratch at its T and the steps in x and T there (each step a small
    programme; the goal rows' violation floor ``FREE_COLD_FLOOR``, ``COLD_FLOOR`` at a fixed T, as far from the optimum), then the coarse optimum
    resampled to the mesh at its T (multipliers and working set by least squares, ``hoc_cli.goals.warm.previous_plan``)
    and the steps in x and T from it (at most ``FINE_STEPS``; when they do not converge, steps at the coarse T from
    it with the merit test, as from scratch, and then those in x and T), the quadrature test at their end. None when the mesh is not uniform, has fewer
    than 2·``coarse`` elements, the goals have vias, the resampled start breaks a limit (the UR5's fast catch after its
    restoration on the mesh), or a stage does not converge (the steps on the mesh itself then run). ``level``: the start on
    the ``coarse`` elements when it is given there (``_restored``: then with a free T the steps in x and T start from it,
    without the steps at its T), else ``start`` resampled. ``span`` None: T fixed
    (no steps in T). Returns the converged ``ReplanResult`` on the mesh, or None.
    """
    from hoc_cli.goals.warm import previous_plan

    mesh = start.mesh
    if not _coarsens(mesh, goals, coarse):
        return None
    q0, dq0 = start.problem.boundary[:2]
    cost, G = start.problem.cost, start.G
    plan = restored = level
    if plan is None:
        level = HermiteMesh(mesh.order, mesh.T, coarse)
        plan = previous_plan(system, level, resample(mesh, start.coeffs, level), q0, dq0, goals, cost=cost,
                             G=_coarse_gauss(G), multipliers="zeros")
    if _breaks_limits(system, plan, limits):
        return None
    start_accuracy = COARSE_ACCURACY if span is None else COARSE_START_ACCURACY  # T fixed: this is the coarse optimum
    floor = COLD_FLOOR if span is None else FREE_COLD_FLOOR
    r = None
    # the points' problems of the coarse runs, then of the mesh's: each run starts where the last one ended (its first
    # point's dynamics, goal rows and Hessian samples are the last one's)
    coarse_cache: dict = {}
    fine_cache: dict = {}
    if restored is None or span is None:
        r = _run(record, system, plan, goals, limits=limits, fallback=False, max_steps=cold_steps, violation_floor=floor,
                 merit=True, accuracy=start_accuracy, cache=coarse_cache)
        if r.steps == 0 and start_accuracy != COARSE_ACCURACY:  # the start itself passed: its model says little there
            r = _run(record, system, plan, goals, limits=limits, fallback=False, max_steps=cold_steps,
                     violation_floor=floor, merit=True, accuracy=COARSE_ACCURACY, cache=coarse_cache)
    if span is not None and (r is None or _met(r)):  # restored: T already left the guess, the steps in x and T at once
        r = _run(record, system, plan if r is None else r.plan, goals, free=span, limits=limits, fallback=False,
                 max_steps=max_steps, violation_floor=floor if restored is None else RESTORED_FLOOR,
                 accuracy=COARSE_FREE_ACCURACY, cache=coarse_cache)
    if not _met(r):
        return None
    fine = HermiteMesh(mesh.order, r.T, mesh.N)
    plan = previous_plan(system, fine, resample(r.plan.mesh, r.plan.coeffs, fine), q0, dq0, goals, cost=cost, G=G,
                         limits=limits)
    r = _run(record, system, plan, goals, free=span, limits=limits, fallback=False, max_steps=min(max_steps, FINE_STEPS),
             cache=fine_cache)
    if not r.converged:  # far from the mesh's optimum (the torque cost): steps at the coarse T first, as from scratch
        r = _run(record, system, plan, goals, limits=limits, fallback=False, max_steps=cold_steps,
                   violation_floor=COLD_FLOOR, merit=True, cache=fine_cache)
        if r.converged and span is not None:
            r = _run(record, system, r.plan, goals, free=span, limits=limits, fallback=False, max_steps=max_steps,
                     cache=fine_cache)
    r = _with_quadrature(r, system, goals, span, limits, max_steps, record) if r.converged else None
    if r is None:
        return None
    return _canonical_multipliers(system, r, goals, limits, span, record)


@one_thread()  # one BLAS thread while solving (hoc_cli/optimize/blas.py)
def plan_fixed_time(system, start, goals, limits, *, cold_steps: int = COLD_STEPS, max_steps: int = MAX_STEPS,
                    coarse: int = COARSE_N):
    """A goal plan in a fixed T within kinematic ``limits`` by the SQP steps from the initial trajectory ``start`` (a
    ``GoalResult`` with zero multipliers, ``GoalSolver.initial``): step 1. of the module docstring at T, first on
    ``coarse`` elements where ``_coarse_replan`` applies (then steps on the mesh from the coarse optimum), the quadrature
    test at the end and the limit multipliers re-estimated by least squares (``_canonical_multipliers``). The
    ``GoalResult`` (its ``quadrature_change`` J's relative change with G + 4 Gauss points), or None when the steps do not
    converge (an effort limit broken, no plan within the limits found): the caller then solves by ``plan_goals``.

    Steps of a local model, as IPOPT's, follow the nearest optimum from the initial trajectory, where a first
    augmented-Lagrangian subproblem minimised to convergence may leave it for any other: docs/goals.md.
    """
    record: list = []  # every replan's outcome: the plan reports their steps and evaluations together
    r = _coarse_replan(system, start, goals, limits, None, cold_steps, max_steps, coarse, record=record) if coarse else None
    if r is None:
        r = _run(record, system, start, goals, limits=limits, fallback=False, max_steps=cold_steps,
                 violation_floor=COLD_FLOOR, merit=True)
        r = _with_quadrature(r, system, goals, None, limits, max_steps, record) if r.converged else None
        if r is None:
            return None
        r = _canonical_multipliers(system, r, goals, limits, None, record)
    return _fixed_plan(r, record, "SQP steps from the initial trajectory: converged")


@one_thread()  # one BLAS thread while solving (hoc_cli/optimize/blas.py)
def replan_fixed_time(system, previous, goals, limits, *, max_steps: int = MAX_STEPS):
    """A goal plan in a fixed T within kinematic ``limits`` by SQP steps from an earlier plan on the same mesh
    (``previous``: a ``GoalResult`` with least-squares multipliers and working set, ``hoc_cli.goals.warm.previous_plan``;
    ``hoc plan --init``), as ``plan_fixed_time`` ends; None when they do not converge.
    """
    record: list = []
    r = _run(record, system, previous, goals, limits=limits, fallback=False, max_steps=max_steps)
    r = _with_quadrature(r, system, goals, None, limits, max_steps, record) if r.converged else None
    if r is None:
        return None
    r = _canonical_multipliers(system, r, goals, limits, None, record)
    return _fixed_plan(r, record, "SQP steps from the initial plan: converged")


def _with_work(plan, record: list):
    """``plan`` (a ``GoalResult``) with its optimizer's iterations, evaluations and Newton matrices the totals of every
    replan in ``record`` (the summary's ``iterations``, ``evaluations``, ``hessians``: all the steps that made it).
    """
    work = [x.plan.optimizer for x in record]
    optimizer = dataclasses.replace(plan.optimizer, iterations=sum(o.iterations for o in work),
                                    n_evals=sum(o.n_evals for o in work), n_precond=sum(o.n_precond for o in work))
    return dataclasses.replace(plan, optimizer=optimizer)


def _fixed_plan(r, record: list, message: str):
    """The ``GoalResult`` of the converged fixed-T replan ``r``: ``message``, the steps and evaluations of every replan in
    ``record``, and J's relative change with G + 4 Gauss points as its ``quadrature_change``.
    """
    plan = _with_work(r.plan, record)
    problem = plan.problem
    J4 = problem.with_quadrature(problem.G + 4).value(problem.layout.pack(plan.coeffs))
    optimizer = dataclasses.replace(plan.optimizer, message=message)
    changes = {"quadrature_change": abs(J4 - plan.J) / max(abs(J4), 1e-300), "optimizer": optimizer}
    if plan.limits is not None:
        changes["limits"] = dataclasses.replace(plan.limits, message=message)
    return dataclasses.replace(plan, **changes)


def _canonical_multipliers(system, r, goals, limits, span: TimeRange | None, record: list | None = None):
    """The converged replan ``r`` with its limit multipliers re-estimated at its optimum by least squares
    (``hoc_cli.goals.warm.previous_plan``, μ ≥ 0 over the rows within 1e-3 of their bound) and confirmed by steps in
    x and T from there that take none; ``r`` itself when they take a step or do not converge.

    Where a limit holds along whole elements its Bernstein rows are linearly dependent and the programme's multipliers
    among them are not unique: each step's programme picks some, depending on the working set it started from. The
    least-squares estimate does not depend on the path: warm replans from it (``hoc_cli.realtime``) take the steps
    they take from the plan of the steps on the mesh alone (the lbr7 catch: 2-4 steps after a step cut by its budget,
    where the multipliers of the coarse path's last programme took up to 12). The confirming steps evaluate on a problem
    of their own at T (not the one ``r``'s steps rescaled there): a plan read back from its file and replanned
    (``hoc plan --init``) has its J to the last bit. Their Newton matrix is made of the sample Hessians of the one
    that confirmed ``r`` (its last point's, or of the point a tiny step before: ``replan_qp.keeps_factor``), with the
    new multipliers' rows: no Hessian sweep.
    """
    from hoc_cli.goals.warm import previous_plan

    plan = r.plan
    q0, dq0 = plan.problem.boundary[:2]
    again = previous_plan(system, plan.mesh, plan.coeffs, q0, dq0, goals, cost=plan.problem.cost, G=plan.G,
                          limits=limits)
    # the Newton matrix of the stopping test of r's steps (r's last point or the one a tiny step before): its samples
    confirmed = _run(record, system, again, goals, free=span, limits=limits, fallback=False, max_steps=0,
                     hessians=plan.newton_hessians)
    return confirmed if confirmed.converged and confirmed.steps == 0 else r


def _met(r) -> bool:
    """Whether the steps of ``r`` met their stopping test (``COARSE_ACCURACY``'s on a coarse stage, where the plan is not
    ``converged``: its goal rows are met to that accuracy, not to ``EQ_ACCEPT``).
    """
    return r.plan.optimizer.status is Status.CONVERGED


def _run(record: list | None, *args, **options):
    """``replan(*args, **options)``, its outcome appended to ``record`` (when given)."""
    r = replan(*args, **options)
    if record is not None:
        record.append(r)
    return r


def _breaks_limits(system, plan, limits) -> bool:
    """Whether the plan's coefficients break a kinematic limit row (g > 0) or its goal rows (> ``COLD_FLOOR``)."""
    from hoc_cli.constraints.penalty import LimitRows

    rows = LimitRows.build(plan.mesh, plan.problem.layout.free, limits.n)
    g_lo, g_hi = kinematic_rows(limits, rows, plan.coeffs)
    worst = max(float(np.max(g, initial=-np.inf)) for g in g_lo + g_hi)
    return worst > 0.0 or plan.violation > COLD_FLOOR


def _unfinished(r, span: TimeRange) -> FreeTimeResult:
    """The end of a free T whose restoration stalled at a bound of T (the violation over x and T least at the end of
    ``span``: no T in it found where the goal rows meet the kinematic limits) and whose steps at the guess T from the initial trajectory
    did not converge (``r``, their replan): its last
    plan, not converged (its status kept: ``max_iter``, or ``not_finite`` when a programme left the floating-point
    range), and no search over T, whose fixed-T solves at T without a plan ran for minutes (the UR5's fast catch).
    """
    plan = r.plan
    message = (f"free final time: no T in [{span.min:g}, {span.max:g}] s found where the goal is met within the "
               f"limits, nor a plan at T = {r.T:g} s ({r.steps} steps)")
    changes = {"optimizer": dataclasses.replace(plan.optimizer, message=message)}
    if plan.limits is not None:
        changes["limits"] = dataclasses.replace(plan.limits, status="not_converged", message=message)
    point = TimePoint(T=r.T, J=plan.J, dJ_dT=r.dJ_dT, result=dataclasses.replace(plan, **changes))
    return FreeTimeResult(T=r.T, J=plan.J, dJ_dT=r.dJ_dT, objective=plan.J + span.weight * r.T, weight=span.weight,
                          bound=None, point=point, history=[point], converged=False)


def _point(r) -> TimePoint:
    return TimePoint(T=r.T, J=r.plan.J, dJ_dT=r.dJ_dT, result=r.plan)


def _result(point: TimePoint, history: list, T_min: float, T_max: float, weight: float) -> FreeTimeResult:
    T, slope = point.T, point.dJ_dT + weight
    bound = "min" if T <= T_min and slope > 0 else "max" if T >= T_max and slope < 0 else None
    return FreeTimeResult(T=T, J=point.J, dJ_dT=point.dJ_dT, objective=point.J + weight * T, weight=weight,
                          bound=bound, point=point, history=history, converged=True)


def _with_quadrature(r, system, goals, span: TimeRange | None, limits, max_steps: int, record: list | None = None):
    """The converged replan ``r`` with G raised by 4 (and the steps resumed) until its quadrature converges
    (``_quadrature_converged``; G ≤ 32 as ``plan_goals``), or None when resumed steps do not converge; ``span``:
    the free T's range, or None for a fixed T.
    """
    from hoc_cli.goals.warm import previous_plan

    while not _quadrature_converged(r.plan) and r.plan.G < 32:
        plan = r.plan
        q0, dq0 = plan.problem.boundary[:2]
        start = previous_plan(system, plan.mesh, plan.coeffs, q0, dq0, goals, cost=plan.problem.cost, G=plan.G + 4,
                              limits=limits)
        r = _run(record, system, start, goals, free=span, limits=limits, fallback=False, max_steps=max_steps)
        if not r.converged:
            return None
    return r


def _quadrature_converged(plan) -> bool:
    """J of the plan with G + 4 Gauss points per element equal to its J to ``QUADRATURE_RTOL`` (or within four
    times the cost's rounding noise), as ``plan_goals`` accepts a quadrature. The plan's J (a replan's: its problem's
    cost at its coefficients, the same number) decides alone when it is within the first; else its problem's evaluation
    gives the noise.
    """
    problem = plan.problem
    x = problem.layout.pack(plan.coeffs)
    J4 = problem.with_quadrature(problem.G + 4).value(x)
    if not problem.terms and abs(J4 - plan.J) <= QUADRATURE_RTOL * abs(J4):  # the plan's J is the problem's at x
        return True
    ev = problem.evaluate(x)  # and the noise
    return abs(J4 - ev.J) <= max(QUADRATURE_RTOL * abs(J4), 4 * ev.noise)
