"""The dense SQP's programme at its own optimum, with linearly dependent active rows, takes the zero step.

A limit held along a whole element makes its Bernstein rows linearly dependent, and at a converged plan they are
all active up to rounding. The programme ``qp_step.solve_qp`` then has d = 0 as its minimiser (the gradient is a
combination of the rows' and the goal rows' normals, with μ ≥ 0). Its least-distance form is solved by
Lawson-Hanson NNLS; SciPy's ``optimize.nnls`` (1.15 on) can end such a problem at a point that is not its
minimiser (scipy/scipy#25389: on these programmes, steps of |d| ~ 100 that break the rows): its answer is checked
against the KKT conditions and hoc's own NNLS (``hoc_cli.optimize.nnls``) solves those it gets wrong. The reference is the KKT point built into each programme.
"""
from __future__ import annotations

import numpy as np

from hoc_cli.goals.qp_step import solve_qp


def _at_its_optimum(seed: int, P: int = 60, r: int = 3, groups: int = 12, copies: int = 4):
    """(U, g, E, e, A, b): H = UᵀU positive definite, ``groups`` row directions each repeated ``copies`` times with
    positive factors (dependent rows), b at rounding level, and g = −(Aᵀμ + Eᵀν) for some μ ≥ 0: d = 0 is the KKT point.
    """
    rng = np.random.default_rng(seed)
    R = np.triu(rng.standard_normal((P, P)))
    U = R + np.diag(np.abs(np.diag(R)) + P ** 0.5)
    E = rng.standard_normal((r, P))
    base = rng.standard_normal((groups, P))
    A = np.repeat(base, copies, axis=0) * rng.uniform(0.5, 2.0, (groups * copies, 1))
    b = 1e-15 * rng.standard_normal(A.shape[0])
    mu = np.where(rng.random(A.shape[0]) < 0.5, rng.uniform(0.0, 10.0, A.shape[0]), 0.0)
    g = -(A.T @ mu + E.T @ rng.standard_normal(r))
    return U, g, E, np.zeros(r), A, b


def test_the_programme_at_its_optimum_with_dependent_active_rows_takes_no_step():
    """200 programmes (0.7 s; SciPy 1.17.1's NNLS gets 2 of them wrong: seeds 86 and 101, steps of |d| ≈ 110)."""
    for seed in range(200):
        U, g, E, e, A, b = _at_its_optimum(seed)
        step = solve_qp(U, g, E, e, A, b)
        assert np.linalg.norm(step.d) <= 1e-9, seed
        assert abs(step.decrease) <= 1e-12 * max(np.abs(g).max(), 1.0), seed
        assert np.all(step.mu >= 0.0), seed
        assert np.allclose(g + A.T @ step.mu + E.T @ step.nu, 0.0, atol=1e-9 * np.abs(g).max()), seed  # KKT
