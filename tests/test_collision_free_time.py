"""A free final time with the collision constraint enforced (``strategy._solve_free_time``): the free-T optimum when
it keeps the margin, else the search over fixed-T plans with the constraint, whose dJ*/dT takes the collision rows'
part (``hoc_cli.collision.time_derivative``).

References: coal and Pinocchio at 1 kHz for the clearance; fixed-T plans at T* ± h for the optimality of T
(F = J + weight·T no lower there); the rows' exact gradients (``pair_gradient``) and the shape functions' scaling
for the collision part of dJ/dT, which the module takes by a central difference.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from _collision_tasks import coal_two_link, plan, task_folder

import hoc_cli
from hoc_cli.collision.evaluate import pair_gradient
from hoc_cli.collision.time_derivative import collision_time_derivative
from hoc_cli.ocp.problem import Fixed

BALL = {"name": "ball", "sphere": {"radius": 0.1}, "position": [1.75, 0, 0.55]}  # on the free plan's path
ARM = {"upper_arm": [{"capsule": {"a": [0, 0, 0], "b": [1, 0, 0], "radius": 0.05}}],
       "forearm": [{"capsule": {"a": [0, 0, 0], "b": [1, 0, 0], "radius": 0.05}}]}
FREE = {"free": True, "min": 1.0, "max": 2.5, "guess": 1.5, "weight": 1.0}


def _doc(dq0=(0.0, 0.0)) -> dict:
    return {"robot": "../robots/two_link.urdf", "x0": {"q": [0.0, 0.0], "dq": list(dq0)}, "x1": {"q": [1.2, -0.6]},
            "T": FREE, "N": 8, "output": {"rate": 1000.0}, "collision": {"robot": ARM, "obstacles": [BALL]}}


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    return task_folder(tmp_path, monkeypatch, ("two_link.urdf",))


def _problem(d, doc):
    """The ``OptimalControlProblem`` of ``doc`` with the constraint, as ``hoc plan`` builds it."""
    import yaml

    from hoc_cli.io.robot import load_model
    from hoc_cli.io.task import load_task, resolve
    from hoc_cli.io.task.problem import problem_from_task, task_limits
    from hoc_cli.report.collision import enforced_problem, task_collision

    (d / "p.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    task = load_task(d / "p.yaml")
    model = load_model(task)
    states = resolve(task, model.joint_names)
    problem = problem_from_task(task, model, states, task_limits(model, states.limits))
    return enforced_problem(task, model, task_collision(task, model), problem)[0]


@pytest.mark.parametrize("dq0", [(0.0, 0.0), (0.6, -0.4)])
def test_a_free_T_round_a_ball_is_certified_coal_agrees_and_no_fixed_T_nearby_does_better(workdir, dq0):
    doc = _doc(dq0)
    r, free = plan(workdir, doc, "--collision", "check")
    assert r.exit_code == 0 and free["min_clearance"]["distance"] < -0.1  # the free optimum goes through the ball
    r, s = plan(workdir, doc)
    assert r.exit_code == 0 and "warning" not in r.stderr, r.stderr
    assert s["status"] == "converged" and s["collision_mode"] == "enforce" and s["collision_active"] is True
    assert s["min_clearance"]["certified"] and s["collisions"] == [] and s["T_bound"] is None
    assert coal_two_link(workdir / "out.csv", BALL) >= 0.01 - 1e-9
    assert s["cost"] > free["cost"]
    problem = _problem(workdir, doc)
    F = s["cost"] + FREE["weight"] * s["T"]
    for h in (-0.02, -0.01, 0.01, 0.02):  # the objective of fixed-T plans with the constraint around T*
        near = hoc_cli.solve(dataclasses.replace(problem, time=Fixed(s["T"] + h)))
        assert near.converged and near.J + FREE["weight"] * near.T >= F - 1e-6 * F


def test_the_collision_rows_part_of_dJ_dT_is_their_gradient_along_the_moved_fixed_coefficients(workdir):
    """At a start moving at q̇0 ≠ 0 the fixed velocity coefficients keep their t-domain values while T changes,
    which moves the configurations at the rows' points: dq_r/dT = Σ_d (d/T) q_r^(d) (q_r^(d): the part of q at
    the point from the fixed coefficients of order d). The module's central difference of Σ λ d agrees with
    −Σ λ_r ∇d_r·dq_r/dT from the rows' exact gradients; at rest it is 0. (On two elements, so that the contact lies
    in the element beside t = 0, the only one those coefficients' shape functions reach.)
    """
    from hoc_cli.collision.constraint import point_configurations
    from hoc_cli.constraints.points import PointSet

    for dq0, expect_zero in (((0.6, -0.4), False), ((0.0, 0.0), True)):
        problem = _problem(workdir, {**_doc(dq0), "T": 1.1, "N": 2})  # the contact in an element beside t = 0
        result = hoc_cli.solve(problem).result
        got = collision_time_derivative(problem.constraint, result)
        if expect_zero:
            assert got == 0.0
            continue
        warm = result.constraint.warm
        live = np.any(warm.lam > 0, axis=1)
        assert live.sum() >= 2
        mesh, C = result.mesh, result.coeffs
        free = result.problem.layout.free.reshape(C.shape)
        e, s_ = mesh.element_of(warm.t[live])
        points = PointSet.build(mesh, e, s_, np.ones(e.size))
        dq_dT = np.zeros((e.size, C.shape[2]))
        for d in range(1, C.shape[1]):
            only = np.zeros_like(C)
            only[:, d] = np.where(~free[:, d], C[:, d], 0.0)
            dq_dT += d / mesh.T * point_configurations(points, only)
        scene = problem.constraint.rows_scene()
        q = point_configurations(points, C)
        rows, pairs = np.nonzero(warm.lam[live] > 0)
        _, grad = pair_gradient(problem.constraint.model, scene, q, rows, pairs)
        want = -float(np.sum(warm.lam[live][rows, pairs] * np.einsum("mn,mn->m", grad, dq_dT[rows])))
        assert abs(want) > 1e-3 and abs(got - want) <= 1e-6 * abs(want)


def test_init_with_a_free_T_and_collision_enforcement_says_in_one_line_that_it_is_not_used(workdir):
    r, first = plan(workdir, _doc(), "-o", "first.mcap")
    assert r.exit_code == 0
    r, again = plan(workdir, _doc(), "--init", "first.mcap")
    assert r.exit_code == 0 and r.stderr.count("hoc: warning:") == 1
    assert "--init is not used for a free T with collision enforcement" in r.stderr
    assert again["collision_active"] is True and abs(again["T"] - first["T"]) <= 1e-9 * first["T"]
