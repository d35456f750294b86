"""Batched dynamics against Pinocchio, finite differences and physics identities."""
from __future__ import annotations

import warnings

import numpy as np
import pytest
from _robots import (
    ERD,
    ROBOTS,
    SHIPPED,
    THIRD_PARTY,
    PinocchioOracle,
    random_state,
    random_tree_urdf,
)

from hoc_cli import dynamics as D
from hoc_cli.errors import HocWarning
from hoc_cli.model import load_robot

pytest.importorskip("pinocchio")

CASES = {name: (ROBOTS / name, {}) for name in SHIPPED}
CASES.update({name: (ERD / path, kw) for name, (path, kw) in THIRD_PARTY.items()})
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


def rel_err(a, b) -> float:
    return float(np.abs(a - b).max() / max(1.0, np.abs(b).max()))


@pytest.mark.parametrize("case", list(CASES))
def test_inverse_dynamics_mass_matrix_and_derivatives_agree_with_pinocchio(case):
    model = model_of(case)
    oracle = PinocchioOracle(model)
    q, dq, ddq = random_state(np.random.default_rng(3), 4, model.n)
    u = D.inverse_dynamics(model, q, dq, ddq)
    M = D.mass_matrix(model, q)
    u2, du_dq, du_ddq, M2 = D.id_derivatives(model, q, dq, ddq)
    for k in range(len(q)):
        ref_dq, ref_dv, ref_da = oracle.rnea_derivatives(q[k], dq[k], ddq[k])
        assert rel_err(u[k], oracle.rnea(q[k], dq[k], ddq[k])) < 1e-10
        assert rel_err(M[k], oracle.crba(q[k])) < 1e-10
        assert rel_err(u2[k], u[k]) < 1e-12
        assert rel_err(du_dq[k], ref_dq) < 1e-10
        assert rel_err(du_ddq[k], ref_dv) < 1e-10
        assert rel_err(M2[k], ref_da) < 1e-10


@pytest.mark.parametrize("case", ["lbr7.urdf", "dual_arm.urdf", "kinova (continuous joints)"])
def test_link_poses_agree_with_pinocchio_for_every_link(case):
    model = model_of(case)
    oracle = PinocchioOracle(model)
    q = np.random.default_rng(4).uniform(-np.pi, np.pi, (2, model.n))
    poses = D.link_poses(model, q)
    assert set(poses) == set(model.link_names)
    for k in range(2):
        for link in model.link_names:
            np.testing.assert_allclose(poses[link][k], oracle.link_pose(q[k], link), atol=1e-12)


@pytest.mark.parametrize("case", SHIPPED + ["panda with a prismatic finger, reordered"])
def test_derivatives_match_central_differences(case):
    model = model_of(case)
    rng = np.random.default_rng(5)
    q, dq, ddq = random_state(rng, 3, model.n)
    _, du_dq, du_ddq, M = D.id_derivatives(model, q, dq, ddq)
    eps = 1e-6
    for j in range(model.n):
        e = np.zeros(model.n)
        e[j] = eps
        fd_q = (D.inverse_dynamics(model, q + e, dq, ddq) - D.inverse_dynamics(model, q - e, dq, ddq)) / (2 * eps)
        fd_v = (D.inverse_dynamics(model, q, dq + e, ddq) - D.inverse_dynamics(model, q, dq - e, ddq)) / (2 * eps)
        fd_a = (D.inverse_dynamics(model, q, dq, ddq + e) - D.inverse_dynamics(model, q, dq, ddq - e)) / (2 * eps)
        scale = 1.0 + np.abs(du_dq).max()
        assert np.abs(fd_q - du_dq[:, :, j]).max() < 1e-6 * scale
        assert np.abs(fd_v - du_ddq[:, :, j]).max() < 1e-6 * scale
        assert np.abs(fd_a - M[:, :, j]).max() < 1e-6 * scale


@pytest.mark.parametrize("case", SHIPPED + ["alex upper body (19 joints, branching)"])
def test_mass_matrix_is_symmetric_positive_definite(case):
    model = model_of(case)
    q = np.random.default_rng(6).uniform(-np.pi, np.pi, (20, model.n))
    M = D.mass_matrix(model, q)
    np.testing.assert_allclose(M, np.swapaxes(M, 1, 2), rtol=0, atol=1e-13 * np.abs(M).max())
    assert np.linalg.eigvalsh(M).min() > 0.0


def test_mass_cholesky_factors_spd_matrices_and_rejects_singular_ones():
    rng = np.random.default_rng(3)
    A = rng.standard_normal((4, 5, 5))
    M = A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(5)
    L = D.mass_cholesky(M)
    np.testing.assert_allclose(L @ np.swapaxes(L, 1, 2), M, rtol=1e-13, atol=1e-13)
    np.testing.assert_array_equal(L, np.linalg.cholesky(M))
    # rank-deficient by construction: the last row/column is the sum of the first two
    S = M.copy()
    S[2, :, 4] = S[2, :, 0] + S[2, :, 1]
    S[2, 4, :] = S[2, 0, :] + S[2, 1, :]
    S[2, 4, 4] = S[2, 0, 0] + 2 * S[2, 0, 1] + S[2, 1, 1]
    S[2] = 0.5 * (S[2] + S[2].T)
    with pytest.raises(np.linalg.LinAlgError):
        D.mass_cholesky(S)


@pytest.mark.parametrize("case", ["lbr7.urdf", "dual_arm.urdf", "panda with a prismatic finger, reordered"])
def test_batched_results_equal_a_loop_over_single_samples(case):
    model = model_of(case)
    rng = np.random.default_rng(7)
    q, dq, ddq = random_state(rng, 6, model.n)
    lam = rng.standard_normal(q.shape)
    batched = (
        D.inverse_dynamics(model, q, dq, ddq),
        D.mass_matrix(model, q),
        D.bias_forces(model, q, dq),
        D.forward_dynamics(model, q, dq, ddq),
        *D.id_derivatives(model, q, dq, ddq),
        *D.id_vjp(model, q, dq, ddq, lam),
        D.mass_quadratic_grad(model, q, dq),
    )
    for k in range(len(q)):
        single = (
            D.inverse_dynamics(model, q[k], dq[k], ddq[k]),
            D.mass_matrix(model, q[k]),
            D.bias_forces(model, q[k], dq[k]),
            D.forward_dynamics(model, q[k], dq[k], ddq[k]),
            *D.id_derivatives(model, q[k], dq[k], ddq[k]),
            *D.id_vjp(model, q[k], dq[k], ddq[k], lam[k]),
            D.mass_quadratic_grad(model, q[k], dq[k]),
        )
        for b, s in zip(batched, single):
            assert s.shape == b.shape[1:]
            np.testing.assert_allclose(b[k], s, rtol=1e-13, atol=1e-12)


@pytest.mark.parametrize("case", SHIPPED + ["baxter (branching, mimic grippers locked)"])
def test_forward_dynamics_inverts_inverse_dynamics(case):
    model = model_of(case)
    q, dq, ddq = random_state(np.random.default_rng(8), 10, model.n)
    u = D.inverse_dynamics(model, q, dq, ddq)
    np.testing.assert_allclose(D.forward_dynamics(model, q, dq, u), ddq, rtol=0, atol=1e-9)
    np.testing.assert_allclose(
        u, np.einsum("kij,kj->ki", D.mass_matrix(model, q), ddq) + D.bias_forces(model, q, dq), atol=1e-10)


def test_inverse_dynamics_without_gravity_drops_exactly_the_gravity_torques():
    model = model_of("lbr7.urdf")
    q, dq, ddq = random_state(np.random.default_rng(9), 5, model.n)
    g = D.inverse_dynamics(model, q, 0 * dq, 0 * ddq)
    np.testing.assert_allclose(D.inverse_dynamics(model, q, dq, ddq, gravity=False) + g,
                               D.inverse_dynamics(model, q, dq, ddq), atol=1e-12)
    np.testing.assert_allclose(D.gravity_forces(model, q), g, atol=1e-12)


@pytest.mark.parametrize("case", ["lbr7.urdf", "dual_arm.urdf", "kinova (continuous joints)",
                                  "panda with a prismatic finger, reordered"])
@pytest.mark.parametrize("gravity", [True, False])
def test_vector_jacobian_products_contract_the_derivative_matrices(case, gravity):
    model = model_of(case)
    rng = np.random.default_rng(10)
    q, dq, ddq = random_state(rng, 5, model.n)
    lam = rng.standard_normal(q.shape)
    u, du_dq, du_ddq, _ = D.id_derivatives(model, q, dq, ddq, gravity=gravity)
    u2, gq, gdq, gddq = D.id_vjp(model, q, dq, ddq, lam, gravity=gravity)
    np.testing.assert_allclose(u2, u, atol=1e-12)
    np.testing.assert_allclose(gddq, np.einsum("kij,kj->ki", D.mass_matrix(model, q), lam), atol=1e-10)
    np.testing.assert_allclose(gq, np.einsum("ki,kij->kj", lam, du_dq), atol=1e-10)
    np.testing.assert_allclose(gdq, np.einsum("ki,kij->kj", lam, du_ddq), atol=1e-10)


@pytest.mark.parametrize("case", ["two_link.urdf", "lbr7.urdf", "panda with a prismatic finger, reordered"])
def test_mass_quadratic_gradient_matches_central_differences(case):
    model = model_of(case)
    rng = np.random.default_rng(11)
    q = rng.uniform(-np.pi, np.pi, (4, model.n))
    v = rng.standard_normal((4, model.n))
    grad = D.mass_quadratic_grad(model, q, v)

    def quad(qq):
        return np.einsum("ki,kij,kj->k", v, D.mass_matrix(model, qq), v)

    eps = 1e-6
    for j in range(model.n):
        e = np.zeros(model.n)
        e[j] = eps
        fd = (quad(q + e) - quad(q - e)) / (2 * eps)
        np.testing.assert_allclose(grad[:, j], fd, rtol=1e-6, atol=1e-7)


def test_pendulum_linearisation_gives_the_papers_natural_frequency():
    # ω² = (∂g/∂q) / M at the bottom: g/l with l = 1.0195 m, ω = 3.102 s⁻¹ (paper)
    model = model_of("pendulum.urdf")
    zero = np.zeros((1, 1))
    _, du_dq, _, M = D.id_derivatives(model, zero, zero, zero)
    assert np.sqrt(du_dq[0, 0, 0] / M[0, 0, 0]) == pytest.approx(3.102, abs=5e-4)


def test_wrong_shapes_raise_value_errors_naming_the_argument():
    model = model_of("two_link.urdf")
    with pytest.raises(ValueError, match="dq: expected shape"):
        D.inverse_dynamics(model, np.zeros((3, 2)), np.zeros((3, 3)), np.zeros((3, 2)))
    with pytest.raises(ValueError, match="ddq: has 4 samples but q has 3"):
        D.inverse_dynamics(model, np.zeros((3, 2)), np.zeros((3, 2)), np.zeros((4, 2)))
    with pytest.raises(ValueError, match="q: expected shape"):
        D.mass_matrix(model, np.zeros((2, 2, 2)))


def test_an_empty_batch_returns_empty_arrays():
    model = model_of("two_link.urdf")
    empty = np.zeros((0, 2))
    assert D.inverse_dynamics(model, empty, empty, empty).shape == (0, 2)
    assert D.mass_matrix(model, empty).shape == (0, 2, 2)


@pytest.mark.parametrize("seed", range(6))
def test_random_trees_with_every_joint_type_and_arbitrary_axes_agree_with_pinocchio(tmp_path, seed):
    rng = np.random.default_rng(100 + seed)
    path = tmp_path / f"random{seed}.urdf"
    path.write_text(random_tree_urdf(rng, 8))
    model = load_robot(path)  # a tree whose joints all came out fixed would be a ModelError
    oracle = PinocchioOracle(model)
    q, dq, ddq = random_state(rng, 3, model.n)
    u, du_dq, du_ddq, M = D.id_derivatives(model, q, dq, ddq)
    lam = rng.standard_normal(q.shape)
    _, gq, gdq, gddq = D.id_vjp(model, q, dq, ddq, lam)
    poses = D.link_poses(model, q)
    for k in range(len(q)):
        ref_dq, ref_dv, ref_da = oracle.rnea_derivatives(q[k], dq[k], ddq[k])
        assert rel_err(u[k], oracle.rnea(q[k], dq[k], ddq[k])) < 1e-10
        assert rel_err(D.mass_matrix(model, q[k]), oracle.crba(q[k])) < 1e-10
        assert rel_err(du_dq[k], ref_dq) < 1e-10
        assert rel_err(du_ddq[k], ref_dv) < 1e-10
        assert rel_err(M[k], ref_da) < 1e-10
        assert rel_err(gq[k], lam[k] @ ref_dq) < 1e-10
        assert rel_err(gdq[k], lam[k] @ ref_dv) < 1e-10
        assert rel_err(gddq[k], oracle.crba(q[k]) @ lam[k]) < 1e-10
        for link in model.link_names:
            np.testing.assert_allclose(poses[link][k], oracle.link_pose(q[k], link), atol=1e-12)


@pytest.mark.parametrize("case", ["two_link.urdf", "lbr7.urdf", "dual_arm.urdf", "panda with a prismatic finger, reordered",
                                  "alex upper body (19 joints, branching)"])
def test_id_and_mass_gives_the_same_numbers_as_inverse_dynamics_and_mass_matrix(case):
    """One pass for u and M (the unit-acceleration columns riding along) is bit for bit the two separate passes on a
    batch (more samples than a chunk too); for one sample to rounding (BLAS may sum a 1-column product otherwise)."""
    model = model_of(case)
    q, dq, ddq = random_state(np.random.default_rng(5), 700, model.n)
    u, M = D.id_and_mass(model, q, dq, ddq)
    assert np.array_equal(u, D.inverse_dynamics(model, q, dq, ddq))
    assert np.array_equal(M, D.mass_matrix(model, q))
    u1, M1 = D.id_and_mass(model, q[3], dq[3], ddq[3])
    assert u1.shape == (model.n,) and M1.shape == (model.n, model.n)
    np.testing.assert_allclose(u1, D.inverse_dynamics(model, q[3], dq[3], ddq[3]), rtol=0, atol=1e-13 * np.abs(u1).max())
    np.testing.assert_allclose(M1, D.mass_matrix(model, q[3]), rtol=0, atol=1e-13 * np.abs(M1).max())


@pytest.mark.parametrize("case", ["two_link.urdf", "lbr7.urdf", "panda with a prismatic finger, reordered",
                                  "alex upper body (19 joints, branching)"])
@pytest.mark.parametrize("K", [1, 65, 700])
def test_a_kept_inverse_dynamics_pass_gives_id_vjp_s_numbers_without_a_second_pass(case, K, monkeypatch):
    """``inverse_dynamics_kept`` and ``id_vjp_kept`` are ``inverse_dynamics`` and ``id_vjp`` bit for bit (one sample,
    one chunk, and more samples than a chunk, where the VJP makes its own pass), and within a chunk the VJP runs no
    second Newton-Euler pass."""
    from hoc_cli.dynamics import _passes

    model = model_of(case)
    rng = np.random.default_rng(11)
    q, dq, ddq = random_state(rng, K, model.n)
    lam = rng.standard_normal((K, model.n))
    ref_u = D.inverse_dynamics(model, q, dq, ddq)
    ref = D.id_vjp(model, q, dq, ddq, lam)
    passes = []
    forward = _passes._forward
    monkeypatch.setattr(_passes, "_forward", lambda *a, **k: passes.append(1) or forward(*a, **k))
    u, kept = D.inverse_dynamics_kept(model, q, dq, ddq)
    got = D.id_vjp_kept(model, kept, lam)
    assert np.array_equal(u, ref_u) and u.flags.c_contiguous
    for x, y in zip(got, ref):
        assert np.array_equal(x, y) and x.flags.c_contiguous
    assert len(passes) == (1 if K <= 512 else 3)  # 700 samples: two chunks for the torques, the VJP its own pass


@pytest.mark.parametrize("case", ["lbr7.urdf", "panda with a prismatic finger, reordered"])
def test_the_velocity_product_rows_taken_by_index_are_the_products_with_their_0_1_rows(case):
    """A v and g = Sᵀ f̄ pick rows of v and f̄ (one 1 per row of A9 and Sᵀ): indexing gives the numbers of the products
    with those rows bit for bit, and the remaining product rows are those of the whole product, at any sample count."""
    from hoc_cli.dynamics._layout import _consts

    model = model_of(case)
    C = _consts(model)
    ABq = np.stack([C.ABq18[i] for i in range(model.n)])
    rng = np.random.default_rng(2)
    for K in (1, 3, 16, 180, 720):
        v = rng.standard_normal((model.n, 6, K))
        whole = np.matmul(C.ABq, v)
        assert np.array_equal(whole[:, 18:], v[:, C.a_sel]) and np.array_equal(whole[:, :18], np.matmul(ABq, v))
        Y = np.matmul(C.ISb, v)
        assert np.array_equal(Y[:, 6:], v[:, C.s_sel]) and np.array_equal(Y[:, :6], np.matmul(C.I, v))
