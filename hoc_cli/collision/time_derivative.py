"""The collision rows' part of dJ*/dT, for a free final time planned with the collision constraint enforced.

A free T is found by the search over fixed-T plans (``hoc_cli.free_time.minimize_time``), which needs
dJ*/dT at each. By the envelope theorem it is the T derivative of the Lagrangian L = J + Σ λ_r c_r at the plan,
along the family of coefficients that ``hoc_cli.free_time.plan_time_derivative`` follows: the same s-domain
trajectory (``rescale``) except the fixed coefficients (x0's velocity, a joint goal's x1), which keep their
t-domain values. The collision rows c_r = bound − d_r(q(t_r)) sit at fixed s (the points of
``hoc_cli.collision.enforce``, placed per element), and d depends on q alone, which the rescaled free
coefficients keep: only the fixed coefficients of derivative order ≥ 1 move the rows, so the part is 0 for a
start and a joint goal at rest. It is taken here by a central difference of Σ λ_r d_r along that family (the
distances are smooth where λ_r > 0: a row held at its bound). Pure maths: no I/O.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from hoc_cli.collision.constraint import point_configurations
from hoc_cli.collision.evaluate import distances
from hoc_cli.constraints.points import PointSet
from hoc_cli.free_time import rescale
from hoc_cli.goals.mesh import mesh_fractions, scaled_mesh

STEP = 1e-6  # the central difference's step, relative to T


def collision_time_derivative(constraint, result) -> float:
    """∂(Σ λ_r c_r)/∂T [cost units per s] at the plan ``result`` (a ``PlanResult`` or ``GoalResult`` planned with
    ``constraint``, a ``hoc_cli.collision.enforce.CollisionConstraint``; its outcome's multipliers λ (P, Q) at the
    point times t (P,)). 0 when no row holds a multiplier or no fixed coefficient of order ≥ 1 is non-zero.
    """
    outcome = getattr(result, "constraint", None)
    warm = None if outcome is None else outcome.warm
    if warm is None:
        return 0.0
    live = np.any(warm.lam > 0.0, axis=1)
    mesh, C = result.mesh, np.asarray(result.coeffs, float)
    free = result.problem.layout.free.reshape(C.shape)
    moving = ~free[:, 1:] & (C[:, 1:] != 0.0)
    if not live.any() or not moving.any():
        return 0.0
    e, s = mesh.element_of(warm.t[live])
    lam = warm.lam[live]
    scene = constraint.rows_scene()
    fractions = mesh_fractions(mesh)

    def weighted(T: float) -> float:  # Σ λ_r d_r on the family at T
        C_T = np.where(free, rescale(C, mesh.T, T), C)
        points = PointSet.build(scaled_mesh(mesh.order, T, mesh.N, fractions), e, s, np.ones(e.size))
        return float(np.sum(lam * distances(constraint.model, scene, point_configurations(points, C_T))))

    h = STEP * mesh.T
    return -(weighted(mesh.T + h) - weighted(mesh.T - h)) / (2.0 * h)


def with_collision_slope(solve, constraint):
    """``solve(T, nearest) -> TimePoint`` (``minimize_time``'s fixed-T solve, planning with ``constraint``) with the
    collision rows' part added to its dJ/dT.
    """
    def solve_with(T: float, nearest):
        p = solve(T, nearest)
        return dataclasses.replace(p, dJ_dT=p.dJ_dT + collision_time_derivative(constraint, p.result))

    return solve_with
