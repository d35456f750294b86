"""``goals.terms.point_set`` on a uniform mesh keeps the h = 1 shape values of its points per order and local coordinates
(they do not depend on T) and scales them by the mesh's h: the numbers of ``PointSet.build`` (``HermiteMesh.shape_values``)
bit for bit, at any T, N and order, for points inside elements, on nodes and at the ends.
"""
from __future__ import annotations

import numpy as np
import pytest

from hoc_cli.constraints.points import PointSet
from hoc_cli.elements import HermiteMesh
from hoc_cli.goals.terms import GoalPoint, point_set


@pytest.mark.parametrize("order", ["cubic", "quintic"])
def test_point_set_is_point_set_build_bit_for_bit(order):
    fractions = [1.0, 0.5, 0.3, 0.0, 0.7371]
    for N in (1, 4, 8, 16):
        for T in (0.3, 0.589371357, 1.5, 2.7, 0.3):  # 0.3 twice: the kept values reused
            mesh = HermiteMesh(order, T, N)
            got = point_set(mesh, [GoalPoint(s, None) for s in fractions])
            x = np.array(fractions) * N
            e = np.clip(np.floor(x).astype(int), 0, N - 1)
            ref = PointSet.build(mesh, e, x - e, np.ones(len(fractions)))
            assert got.mesh is mesh
            for a, b in ((got.B, ref.B), (got.e, ref.e), (got.s, ref.s), (got.weight, ref.weight)):
                assert a.shape == b.shape and np.array_equal(a, b)


def test_goal_row_jacobian_is_the_point_sets_adjoint_bit_for_bit():
    """``GoalTerms.jacobian`` builds each row's gradient from its point's shape functions directly: the numbers of
    ``PointSet.transpose`` applied to the row's (∂c/∂q, ∂c/∂q̇) at its point (zero elsewhere), bit for bit, for a link
    goal with a velocity row at T and a second point inside an element (the lbr7 catch, N = 4 and 8)."""
    from _robots import lbr7_catch_problem

    from hoc_cli.goals.terms import GoalTerms
    from hoc_cli.goals.time_solver import goal_solver

    problem = lbr7_catch_problem(8)
    goals = problem.goals()
    rng = np.random.default_rng(3)
    for N in (4, 8):
        start = goal_solver(problem.system, "quintic", N, problem.q0, problem.dq0, goals).initial(0.4)
        final = start.problem.points[0]
        points = [final, GoalPoint(0.37, final.residual, "via")]
        for _ in range(5):
            C = start.coeffs + 0.3 * rng.standard_normal(start.coeffs.shape)
            terms = GoalTerms(start.mesh, points, [np.zeros(p.residual.size) for p in points], 0.0)
            res = terms.residuals(C)
            c, D = terms.jacobian(C, res)
            where = point_set(start.mesh, points)
            k = 0
            for i, r in enumerate(res):
                for j in range(r[0].size):
                    S = np.zeros((3, len(points), C.shape[-1]))
                    S[0, i], S[1, i] = r[1][j], r[2][j]
                    assert np.array_equal(D[k], where.transpose(S)) and c[k] == r[0][j]
                    k += 1
            assert k == D.shape[0] == 12  # position and velocity rows at both points


def test_the_time_columns_two_residuals_by_one_batch_are_two_calls_bit_for_bit():
    """``GoalTerms.time_column`` evaluates a frame residual at (q, q̇, T) ± ε·(dz, 1) by one batch of its forward kinematics
    with each sample's own T (``terms._plus_minus``): the numbers of two calls of the residual, bit for bit,
    for a moving target with ``match_velocity`` and a pose goal with an orientation."""
    from _robots import lbr7_catch_problem

    from hoc_cli.goals.residuals import FrameResidual
    from hoc_cli.goals.terms import _plus_minus

    catch = lbr7_catch_problem(8)
    moving = catch.goals().final
    pose = FrameResidual(moving.model, "lbr_flange", np.array([0.5, 0.1, 0.6]), orientation=np.eye(3))
    rng = np.random.default_rng(5)
    for residual in (moving, pose):
        for _ in range(10):
            q, dq, z0, z1 = rng.standard_normal((4, 7))
            eps, T = 1e-5 * 0.4, 0.4
            plus, minus = _plus_minus(residual, q, dq, (z0, z1), eps, T)
            ref_plus = residual(q + eps * z0, dq + eps * z1, T + eps)
            ref_minus = residual(q - eps * z0, dq - eps * z1, T - eps)
            for i in (1, 2, 3):
                assert np.array_equal(plus[i], ref_plus[i]) and np.array_equal(minus[i], ref_minus[i])
            assert np.array_equal(plus[0], ref_plus[0])
