"""The restoration's rows (``hoc_cli.goals.restoration``) on the UR5 fast catch's initial trajectory (tests/_ur5_catch.py).

- ``active_limits.kinematic_rows``: every kinematic Bernstein row's g, the same numbers as the augmented Lagrangian's
  (``all_rows``, ``LimitTerms``), −inf where a row is data or a bound infinite;
- ``restoration._time_column``: the T column of the goal rows and of the limit rows along the rescaled family, exact,
  against central differences of the rows at coefficients rescaled to T ± δ.
"""
from __future__ import annotations

import numpy as np
import pytest
from _ur5_catch import URDF, ur5_catch

pytestmark = pytest.mark.skipif(not URDF.is_file(), reason="example-robot-data is not installed")


def _start(T: float = 0.5):
    from hoc_cli.goals.time_solver import goal_solver

    model, arm, limits, problem = ur5_catch()
    goals = problem.goals()
    start = goal_solver(arm, "quintic", 8, problem.q0, problem.dq0, goals, limits=limits).initial(T)
    return arm, limits, goals, start


def test_kinematic_rows_are_the_augmented_lagrangians_rows():
    from hoc_cli.constraints.bounds import KINEMATIC
    from hoc_cli.constraints.penalty import LimitRows
    from hoc_cli.goals.active_limits import all_rows, kinematic_rows

    arm, limits, goals, start = _start()
    rows = LimitRows.build(start.mesh, start.problem.layout.free, limits.n)
    C = start.coeffs + 0.3 * np.random.default_rng(1).standard_normal(start.coeffs.shape)
    ref = all_rows(arm, limits, rows, C)
    g_lo, g_hi = kinematic_rows(limits, rows, C)
    assert len(g_lo) == len(g_hi) == KINEMATIC
    for k in range(KINEMATIC):
        assert np.array_equal(g_lo[k], ref.g_lo[k]) and np.array_equal(g_hi[k], ref.g_hi[k])
    assert np.isneginf(g_lo[0]).any() and np.isfinite(g_hi[1]).any()  # rows set by x0 are data; the UR5 has no q̈ limit
    assert max(float(np.max(g)) for g in g_hi) > 0.0


def test_the_restorations_T_column_against_central_differences():
    from hoc_cli.constraints.penalty import LimitRows
    from hoc_cli.free_time import rescale
    from hoc_cli.goals.active_limits import ActiveRows, kinematic_rows
    from hoc_cli.goals.replan_point import point_problem
    from hoc_cli.goals.restoration import _goal_rows, _time_column

    arm, limits, goals, start = _start()
    mesh, problem = start.mesh, start.problem
    q0, dq0 = problem.boundary[:2]
    T = mesh.T
    C = start.coeffs.copy()
    C[1:, 1:] += 0.2 * np.random.default_rng(2).standard_normal(C[1:, 1:].shape)  # not the family's own start
    lam = [np.zeros(p.residual.size) for p in problem.points]
    cache: dict = {}

    def rows_at(T_: float, C_: np.ndarray):
        prob, _, where = point_problem(arm, "quintic", 8, T_, q0, dq0, goals, problem.cost, start.G, None, cache)
        pt = _goal_rows(prob, where, C_, lam)
        rows = LimitRows.build(prob.mesh, prob.layout.free, limits.n)
        g_lo, g_hi = kinematic_rows(limits, rows, pt.C)
        return pt, rows, g_lo, g_hi

    pt, rows, g_lo, g_hi = rows_at(T, C)
    select = ActiveRows.where(tuple(np.isfinite(g) for g in g_lo), tuple(np.isfinite(g) for g in g_hi))
    _, A_full = select.jacobian(rows, limits, problem.layout.free)
    c_T, g_T = _time_column(pt, A_full, select.kind, T)
    delta = 1e-5 * T
    plus, minus = (rows_at(T + s * delta, rescale(pt.C, T, T + s * delta)) for s in (1.0, -1.0))
    fd_c = (plus[0].c - minus[0].c) / (2 * delta)
    fd_g = (select.gather(plus[2], plus[3]) - select.gather(minus[2], minus[3])) / (2 * delta)
    assert np.abs(c_T - fd_c).max() <= 1e-6 * np.abs(fd_c).max()
    assert np.abs(g_T - fd_g).max() <= 1e-6 * np.abs(fd_g).max()
    assert np.abs(fd_g).max() > 1.0 and np.abs(fd_c).max() > 1.0


def test_active_rows_where_lists_the_masked_rows_kind_by_kind_lower_then_upper():
    """``ActiveRows.where``: every True entry of the masks once, as (kind, element, row, joint, side), per kind the lower
    rows then the upper ones, each in C order (the order the rows' programmes and multipliers follow), against a loop
    over every entry; ``gather`` reads them back."""
    from hoc_cli.constraints.bounds import KINEMATIC
    from hoc_cli.goals.active_limits import ActiveRows

    rng = np.random.default_rng(4)
    for _ in range(20):
        N, n = int(rng.integers(1, 6)), int(rng.integers(1, 7))
        shapes = [(N, R, n) for R in (6, 6, 4, 2)[:KINEMATIC]]
        lo = tuple(rng.random(s) < 0.3 for s in shapes)
        hi = tuple(rng.random(s) < 0.3 for s in shapes)
        ref = [(k, e, r, j, side) for k in range(KINEMATIC) for side, mask in ((-1, lo[k]), (1, hi[k]))
               for e in range(N) for r in range(shapes[k][1]) for j in range(n) if mask[e, r, j]]
        got = ActiveRows.where(lo, hi)
        assert list(zip(*(a.tolist() for a in got._fields()))) == ref
        values_lo = tuple(rng.standard_normal(s) for s in shapes)
        values_hi = tuple(rng.standard_normal(s) for s in shapes)
        assert got.gather(values_lo, values_hi).tolist() == [(values_lo if s < 0 else values_hi)[k][e, r, j]
                                                              for k, e, r, j, s in ref]


@pytest.mark.parametrize("N", [8, 16])
def test_a_rejected_trial_is_solved_again_with_the_rows_it_broke(N):
    """The restoration on the catch's own mesh (the path of vias, non-uniform meshes and N < 8) from the guess 0.5 s: a full
    step of the goal rows breaks limit rows that were 5 % inside their bound and so not in its programme; re-solving the
    rejected trial with them (``restoration.WIDEN``) reaches a T where the catch meets its goal and the tightened limits
    in at most 20 steps (measured 15 on 8 elements, 18 on 16), where steps that do not see those rows took 44 and 97."""
    from hoc_cli.goals.replan import TimeRange
    from hoc_cli.goals.restoration import restore
    from hoc_cli.goals.time_solver import goal_solver

    model, arm, limits, problem = ur5_catch(N)
    goals = problem.goals()
    start = goal_solver(arm, "quintic", N, problem.q0, problem.dq0, goals, limits=limits).initial(0.5)
    found = restore(arm, start, goals, limits, span=TimeRange(0.3, 0.8))
    assert found.feasible and found.violation <= 1e-9 and found.row_violation <= 1e-9
    assert 0.5 < found.T < 0.6 and found.steps <= 20


def _count_calls(monkeypatch, calls: dict, key: str, owner, name: str) -> None:
    """Wrap ``owner.name`` so that each call adds 1 to ``calls[key]`` and then runs the original."""
    original = getattr(owner, name)

    def spy(*args, **kwargs):
        calls[key] += 1
        return original(*args, **kwargs)

    monkeypatch.setattr(owner, name, spy)


def test_a_trial_its_limit_rows_alone_reject_evaluates_no_goal_rows(monkeypatch):
    """A trial whose limit rows alone leave the ratio of actual to predicted decrease below ¼ (m ≥ ½Σmax(0, g + κ)²) is
    rejected, and re-solved with the rows it broke, without the goal rows' forward kinematics there: on the catch's 8
    elements from 0.5 s, 15 steps with 22 goal-row evaluations for 38 programmes (39 when every trial evaluates them:
    one per programme and one at the start), to the same feasible T as
    ``test_a_rejected_trial_is_solved_again_with_the_rows_it_broke``."""
    import hoc_cli.goals.restoration as restoration
    from hoc_cli.goals.replan import TimeRange

    arm, limits, goals, start = _start()
    calls = {"rows": 0, "programmes": 0}
    _count_calls(monkeypatch, calls, "rows", restoration, "_goal_rows")
    _count_calls(monkeypatch, calls, "programmes", restoration, "solve_qp")
    found = restoration.restore(arm, start, goals, limits, span=TimeRange(0.3, 0.8))
    assert found.feasible and found.violation <= 1e-9 and found.row_violation <= 1e-9 and 0.5 < found.T < 0.6
    assert calls["rows"] <= calls["programmes"] - 10


def test_the_restoration_builds_one_problem_and_rescales_only_its_mesh_rows_and_points(monkeypatch):
    """Each trial T of the restoration needs the mesh there, its limit rows and its goal points only: the problem
    (``point_problem``: a ``GoalProblem`` and its quadrature) is built once, at the first T, and its layout and fixed
    coefficients serve every other T; the restoration from 0.5 s on the catch's 8 elements visits ~30 Ts and ends where
    ``test_a_rejected_trial_is_solved_again_with_the_rows_it_broke`` does, its C at each T as a fresh problem's there."""
    import hoc_cli.goals.replan_point as replan_point
    import hoc_cli.goals.restoration as restoration
    from hoc_cli.goals.replan import TimeRange

    arm, limits, goals, start = _start()
    calls = {"problems": 0, "rescaled": 0}
    _count_calls(monkeypatch, calls, "problems", restoration, "point_problem")
    _count_calls(monkeypatch, calls, "rescaled", replan_point, "problem_on")
    found = restoration.restore(arm, start, goals, limits, span=TimeRange(0.3, 0.8))
    assert found.feasible and 0.5 < found.T < 0.6 and found.steps >= 10
    assert calls == {"problems": 1, "rescaled": 0}
    # the coefficients at the T found, as a problem built there gives them
    model, arm2, limits2, problem = ur5_catch()
    fresh = replan_point.point_problem(arm, "quintic", 8, found.T, problem.q0, problem.dq0, goals, start.problem.cost,
                                       start.G, limits, {})[0]
    assert np.array_equal(fresh.coefficients(fresh.layout.pack(found.coeffs)), found.coeffs)
