"""``ActiveRows``: the rows of boolean masks in their order, and their Jacobian against the limit rows' own values."""
from __future__ import annotations

import numpy as np

from hoc_cli.constraints.bounds import KINEMATIC, JointLimits
from hoc_cli.constraints.penalty import LimitRows
from hoc_cli.elements import HermiteMesh
from hoc_cli.goals.active_limits import ActiveRows
from hoc_cli.goals.replan_point import row_values


def _reference(lo, hi) -> np.ndarray:
    """(kind, element, row, joint, side) (5, a) of the True entries, kind by kind, lower then upper, np.nonzero's order."""
    out = []
    for k in range(KINEMATIC):
        for side, mask in ((-1, lo[k]), (1, hi[k])):
            for e, r, j in zip(*np.nonzero(mask)):
                out.append((k, e, r, j, side))
    return np.array(out, int).reshape(-1, 5).T


def test_the_rows_of_masks_are_their_true_entries_kind_by_kind_lower_first():
    rng = np.random.default_rng(3)
    for trial in range(30):
        N, n = int(rng.integers(1, 6)), int(rng.integers(1, 5))
        p = (0.0, 0.05, 0.5, 1.0)[trial % 4]
        lo = tuple(rng.random((N, R, n)) < p for R in (12, 10, 8, 6))
        hi = tuple(rng.random((N, R, n)) < p for R in (12, 10, 8, 6))
        rows = ActiveRows.where(lo, hi)
        ref = _reference(lo, hi)
        got = np.array([rows.kind, rows.elem, rows.row, rows.joint, rows.side])
        assert got.shape == ref.shape and np.array_equal(got, ref)
        assert rows.kind.dtype == np.int_


def test_the_jacobian_of_rows_gives_their_values_on_uniform_and_non_uniform_meshes():
    rng = np.random.default_rng(4)
    n = 3
    limits = JointLimits.from_arrays([f"j{i}" for i in range(n)], lower=-np.ones(n), upper=np.ones(n),
                                     velocity=2.0 * np.ones(n), acceleration=5.0 * np.ones(n))
    for mesh in (HermiteMesh("quintic", 0.8, 4), HermiteMesh.from_nodes("quintic", np.array([0.0, 0.1, 0.35, 0.4, 0.9])),
                 HermiteMesh("cubic", 0.5, 3)):
        free = np.ones((mesh.N + 1) * mesh.m * n, bool)
        free[: mesh.m * n] = False  # the start node fixed
        rows = LimitRows.build(mesh, free, n)
        C = rng.normal(size=(mesh.N + 1, mesh.m, n))
        kr = row_values(limits, rows, C)
        lo = tuple(np.isfinite(g) & (rng.random(g.shape) < 0.4) for g in kr.g_lo)
        hi = tuple(np.isfinite(g) & (rng.random(g.shape) < 0.4) for g in kr.g_hi)
        active = ActiveRows.where(lo, hi)
        A, A_full = active.jacobian(rows, limits, free)
        g = A_full @ C.ravel() + active.offsets(limits)
        ref = np.array([(kr.g_lo if s < 0 else kr.g_hi)[k][e, r, j]
                        for k, e, r, j, s in zip(active.kind, active.elem, active.row, active.joint, active.side)])
        assert active.size > 10
        np.testing.assert_allclose(g, ref, rtol=1e-12, atol=1e-12)
        assert np.array_equal(A, A_full[:, free])
    empty = ActiveRows.empty().jacobian(rows, limits, free)
    assert empty[0].shape == (0, int(free.sum())) and empty[1].shape == (0, free.size)
