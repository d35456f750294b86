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
