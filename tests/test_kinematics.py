"""Batched link kinematics (poses, frame Jacobians, link velocities and their derivatives) against
Pinocchio and central differences."""
from __future__ import annotations

import warnings

import numpy as np
import pytest
from _robots import ERD, ROBOTS, SHIPPED, THIRD_PARTY, PinocchioOracle, random_tree_urdf

from hoc_cli import dynamics as D
from hoc_cli.errors import HocWarning
from hoc_cli.model import load_robot

pytest.importorskip("pinocchio")

CASES = {name: (ROBOTS / name, {}) for name in SHIPPED}
CASES.update({name: (ERD / path, kw) for name, (path, kw) in THIRD_PARTY.items()})
#: shipped robots, UR5, both Panda reductions (one with a prismatic finger), continuous joints,
#: and a branching tree
KIN_CASES = SHIPPED + [
    "ur5 (6-DOF arm)",
    "panda arm, mimic fingers locked (7-DOF)",
    "panda with a prismatic finger, reordered",
    "kinova (continuous joints)",
    "baxter (branching, mimic grippers locked)",
]
_MODELS: dict = {}
# Cases whose task joints move the master of a mimic joint: hoc must say that it holds the mimic fixed.
WARNS_MIMIC = {"panda with a prismatic finger, reordered": 1, "baxter (branching, mimic grippers locked)": 2}


def model_of(case: str):
    if case not in _MODELS:
        path, kw = CASES[case]
        assert path.is_file(), f"{path} missing: the test extra installs example-robot-data"
        if case in WARNS_MIMIC:
            with pytest.warns(HocWarning, match="mimic coupling is not modelled") as record:
                _MODELS[case] = load_robot(path, **kw)
            assert len(record) == WARNS_MIMIC[case]
        else:
            with warnings.catch_warnings():
                warnings.simplefilter("error", HocWarning)
                _MODELS[case] = load_robot(path, **kw)
    return _MODELS[case]


def moving_links(model) -> list[str]:
    """Every link carried by a movable body (the ones with a nonzero Jacobian)."""
    return [name for name, b in zip(model.link_names, model.link_body) if b >= 0]


def pin_frame_jacobian(oracle: PinocchioOracle, q, link: str) -> np.ndarray:
    """(6, n) LOCAL_WORLD_ALIGNED Jacobian of a link's BODY frame, columns in model order."""
    pin = oracle.pin
    fid = oracle.pm.getFrameId(link, pin.BODY)
    J = pin.computeFrameJacobian(oracle.pm, oracle.pd, oracle.config(q), fid, pin.LOCAL_WORLD_ALIGNED)
    return np.reshape(J, (6, -1))[:, oracle.idx_v]  # a 6 × 1 Jacobian comes back as (6,)


def pin_velocity_derivatives(oracle: PinocchioOracle, q, dq, link: str):
    """(V (6,), ∂V/∂q (6, n), ∂V/∂q̇ (6, n)) of a link's BODY frame, LOCAL_WORLD_ALIGNED.

    Built from Pinocchio's LOCAL derivatives: V = diag(R, R) V_L, so with ∂R/∂q_j = [ω_j]× R
    (ω_j = J[3:6, j]) ∂V/∂q_j = diag(R, R) ∂V_L/∂q_j + (ω_j × V[0:3], ω_j × V[3:6]). (Pinocchio
    4.1's own LOCAL_WORLD_ALIGNED ∂V/∂q is not the partial derivative of its LOCAL_WORLD_ALIGNED
    getFrameVelocity: it differs from central differences of it by O(1) on lbr7.)
    """
    pin = oracle.pin
    v = oracle.velocity(dq)
    pin.computeForwardKinematicsDerivatives(oracle.pm, oracle.pd, oracle.config(q), v, 0 * v)
    fid = oracle.pm.getFrameId(link, pin.BODY)
    dvl_dq, dvl_dv = (np.reshape(x, (6, -1)) for x in
                      pin.getFrameVelocityDerivatives(oracle.pm, oracle.pd, fid, pin.LOCAL))
    pin.updateFramePlacements(oracle.pm, oracle.pd)
    R = oracle.pd.oMf[fid].rotation
    V = pin.getFrameVelocity(oracle.pm, oracle.pd, fid, pin.LOCAL_WORLD_ALIGNED).vector
    J = np.reshape(pin.getFrameJacobian(oracle.pm, oracle.pd, fid, pin.LOCAL_WORLD_ALIGNED), (6, -1))
    dv_dq = np.vstack([R @ dvl_dq[:3], R @ dvl_dq[3:]])
    dv_dq[:3] += np.cross(J[3:].T, V[:3]).T
    dv_dq[3:] += np.cross(J[3:].T, V[3:]).T
    dv_dv = np.vstack([R @ dvl_dv[:3], R @ dvl_dv[3:]])
    return V, dv_dq[:, oracle.idx_v], dv_dv[:, oracle.idx_v]


def links_to_check(model) -> list[str]:
    links = moving_links(model)
    return links if len(links) <= 12 else links[:: len(links) // 12 + 1] + links[-1:]


@pytest.mark.parametrize("case", KIN_CASES)
def test_frame_jacobian_agrees_with_pinocchio_local_world_aligned(case):
    model = model_of(case)
    oracle = PinocchioOracle(model)
    q = np.random.default_rng(21).uniform(-np.pi, np.pi, (3, model.n))
    for link in links_to_check(model):
        J = D.frame_jacobian(model, q, link)
        assert J.shape == (3, 6, model.n)
        for k in range(len(q)):
            np.testing.assert_allclose(J[k], pin_frame_jacobian(oracle, q[k], link), rtol=0, atol=1e-12)


@pytest.mark.parametrize("case", KIN_CASES)
def test_link_velocity_and_its_derivatives_agree_with_pinocchio(case):
    model = model_of(case)
    oracle = PinocchioOracle(model)
    rng = np.random.default_rng(22)
    q = rng.uniform(-np.pi, np.pi, (3, model.n))
    dq = rng.standard_normal((3, model.n))
    for link in links_to_check(model):
        V, dV_dq, dV_ddq = D.link_velocity_derivatives(model, q, dq, link)
        np.testing.assert_array_equal(D.link_velocity(model, q, dq, link), V)
        pose, *rest = D.link_motion(model, q, dq, link)  # the same pass, with the link's pose (one chain only)
        np.testing.assert_allclose(pose, D.link_poses(model, q)[link], rtol=0, atol=1e-14)
        for a, b in zip(rest, (V, dV_dq, dV_ddq)):
            np.testing.assert_array_equal(a, b)
        for k in range(len(q)):
            ref_V, ref_dq, ref_dv = pin_velocity_derivatives(oracle, q[k], dq[k], link)
            np.testing.assert_allclose(V[k], ref_V, rtol=0, atol=1e-12)
            np.testing.assert_allclose(dV_dq[k], ref_dq, rtol=0, atol=1e-11)
            np.testing.assert_allclose(dV_ddq[k], ref_dv, rtol=0, atol=1e-12)


def _vee(S: np.ndarray) -> np.ndarray:
    """(.., 3) axial vector of the skew-symmetric part of S (.., 3, 3)."""
    A = 0.5 * (S - np.swapaxes(S, -1, -2))
    return np.stack([A[..., 2, 1], A[..., 0, 2], A[..., 1, 0]], axis=-1)


@pytest.mark.parametrize("case", SHIPPED + ["ur5 (6-DOF arm)", "panda with a prismatic finger, reordered"])
def test_frame_jacobian_is_the_derivative_of_link_poses(case):
    # column j: the origin's velocity dp/dq_j and ω with dR/dq_j = [ω]× R, by central differences
    model = model_of(case)
    q = np.random.default_rng(23).uniform(-np.pi, np.pi, (4, model.n))
    eps = 1e-6
    links = links_to_check(model)
    J = {link: D.frame_jacobian(model, q, link) for link in links}
    for j in range(model.n):
        e = np.zeros(model.n)
        e[j] = eps
        plus, minus = D.link_poses(model, q + e), D.link_poses(model, q - e)
        for link in links:
            Tp, Tm, T = plus[link], minus[link], D.link_poses(model, q)[link]
            dp = (Tp[:, :3, 3] - Tm[:, :3, 3]) / (2 * eps)
            dR = (Tp[:, :3, :3] - Tm[:, :3, :3]) / (2 * eps)
            w = _vee(dR @ np.swapaxes(T[:, :3, :3], 1, 2))
            np.testing.assert_allclose(J[link][:, 0:3, j], dp, rtol=0, atol=1e-8)
            np.testing.assert_allclose(J[link][:, 3:6, j], w, rtol=0, atol=1e-8)


@pytest.mark.parametrize("case", SHIPPED + ["panda with a prismatic finger, reordered",
                                            "baxter (branching, mimic grippers locked)"])
def test_velocity_derivatives_match_central_differences(case):
    model = model_of(case)
    rng = np.random.default_rng(24)
    q = rng.uniform(-np.pi, np.pi, (3, model.n))
    dq = rng.standard_normal((3, model.n))
    link = moving_links(model)[-1]
    V, dV_dq, dV_ddq = D.link_velocity_derivatives(model, q, dq, link)
    np.testing.assert_allclose(V, np.einsum("krj,kj->kr", D.frame_jacobian(model, q, link), dq), atol=1e-13)
    eps = 1e-6
    for j in range(model.n):
        e = np.zeros(model.n)
        e[j] = eps
        fd_q = (D.link_velocity(model, q + e, dq, link) - D.link_velocity(model, q - e, dq, link)) / (2 * eps)
        fd_v = (D.link_velocity(model, q, dq + e, link) - D.link_velocity(model, q, dq - e, link)) / (2 * eps)
        np.testing.assert_allclose(dV_dq[:, :, j], fd_q, rtol=0, atol=1e-8)
        np.testing.assert_allclose(dV_ddq[:, :, j], fd_v, rtol=0, atol=1e-8)


@pytest.mark.parametrize("seed", range(4))
def test_random_trees_with_every_joint_type_agree_with_pinocchio(tmp_path, seed):
    rng = np.random.default_rng(200 + seed)
    path = tmp_path / f"random{seed}.urdf"
    path.write_text(random_tree_urdf(rng, 8))
    model = load_robot(path)
    oracle = PinocchioOracle(model)
    q = rng.uniform(-np.pi, np.pi, (2, model.n))
    dq = rng.standard_normal((2, model.n))
    for link in moving_links(model):
        J = D.frame_jacobian(model, q, link)
        V, dV_dq, _ = D.link_velocity_derivatives(model, q, dq, link)
        for k in range(len(q)):
            np.testing.assert_allclose(J[k], pin_frame_jacobian(oracle, q[k], link), rtol=0, atol=1e-12)
            ref_V, ref_dq, _ = pin_velocity_derivatives(oracle, q[k], dq[k], link)
            np.testing.assert_allclose(V[k], ref_V, rtol=0, atol=1e-12)
            np.testing.assert_allclose(dV_dq[k], ref_dq, rtol=0, atol=1e-11)


def test_jacobian_columns_vanish_for_joints_that_do_not_move_the_link():
    # dual_arm: the two arms are separate branches; a fixed-base link never moves
    model = model_of("dual_arm.urdf")
    q = np.random.default_rng(25).uniform(-np.pi, np.pi, (2, model.n))
    for link, b in zip(model.link_names, model.link_body):
        J = D.frame_jacobian(model, q, link)
        if b < 0:
            assert not J.any()
            continue
        moving = np.zeros(model.n, dtype=bool)
        while b >= 0:
            moving[b] = True
            b = model.parent[b]
        assert not J[:, :, ~moving].any()
        assert np.abs(J[:, :, moving]).sum(axis=1).min() > 0.0


def test_single_samples_unknown_links_and_wrong_shapes():
    model = model_of("lbr7.urdf")
    rng = np.random.default_rng(26)
    q, dq = rng.standard_normal((2, 5, model.n))
    link = model.link_names[-1]
    J = D.frame_jacobian(model, q, link)
    batched = D.link_velocity_derivatives(model, q, dq, link)
    for k in range(len(q)):
        np.testing.assert_array_equal(D.frame_jacobian(model, q[k], link), J[k])
        for b, s in zip(batched, D.link_velocity_derivatives(model, q[k], dq[k], link)):
            assert s.shape == b.shape[1:]
            np.testing.assert_allclose(s, b[k], rtol=1e-15, atol=1e-15)
    with pytest.raises(KeyError, match="no link 'gripper'; links are"):
        D.frame_jacobian(model, q, "gripper")
    with pytest.raises(ValueError, match="dq: expected shape"):
        D.link_velocity(model, q, dq[:, :3], link)
    assert D.frame_jacobian(model, np.zeros((0, model.n)), link).shape == (0, 6, model.n)
