"""Hermite elements: nodal basis (errata-corrected), polynomial reproduction, continuity, adjoint, orders."""
import numpy as np
import pytest

from hoc_cli.elements import POLY_DEGREE, HermiteMesh, error_norm, reference_basis
from hoc_cli.verification import convergence_order, interpolation_errors

# Expected nodal values: [function k][derivative r] at t = -1, 0, +1.
# Cubic: phi, psi;  quintic: phi, psi, theta.  Cubic second derivatives are not nodal (C1 only).
NODAL = {
    "cubic": {0: [(0, 1, 0), (0, 0, 0)], 1: [(0, 0, 0), (0, 1, 0)]},
    "quintic": {
        0: [(0, 1, 0), (0, 0, 0), (0, 0, 0)],
        1: [(0, 0, 0), (0, 1, 0), (0, 0, 0)],
        2: [(0, 0, 0), (0, 0, 0), (0, 1, 0)],
    },
}


@pytest.mark.parametrize("order", ["cubic", "quintic"])
def test_reference_functions_are_a_nodal_basis_at_minus_one_zero_and_one(order):
    t = np.array([-1.0, 0.0, 1.0])
    for r, per_function in NODAL[order].items():
        values = reference_basis(order, t, r)  # (3, m)
        for k, expected in enumerate(per_function):
            np.testing.assert_allclose(values[:, k], expected, atol=1e-14, err_msg=f"{order} f{k} d{r}")


def test_printed_cubic_phi_of_the_paper_is_not_nodal_but_the_corrected_one_is():
    printed = lambda t: (1 - abs(t) ** 2) * (1 + 2 * abs(t))  # the paper's formula (ERRATA.md)
    assert printed(0.5) == pytest.approx(1.5)
    assert reference_basis("cubic", [0.5])[0, 0] == pytest.approx(0.5)


def test_reference_functions_vanish_outside_minus_one_one():
    for order in ("cubic", "quintic"):
        assert np.all(reference_basis(order, [-1.5, 1.0001, 3.0]) == 0)


def _random_polynomial(rng, degree):
    c = rng.normal(size=degree + 1)
    p = np.polynomial.Polynomial(c)
    return p, p.deriv(1), p.deriv(2)


@pytest.mark.parametrize("order", ["cubic", "quintic"])
@pytest.mark.parametrize("N", [1, 3, 7])
def test_elements_reproduce_polynomials_of_their_degree_exactly_with_derivatives(order, N):
    rng = np.random.default_rng(N)
    mesh = HermiteMesh(order, 1.7, N)
    p, dp, ddp = _random_polynomial(rng, POLY_DEGREE[order])
    C = mesh.interpolate(p, dp, ddp)
    t = np.concatenate([rng.uniform(0, 1.7, 50), mesh.nodes])
    for r, f in enumerate((p, dp, ddp)):
        np.testing.assert_allclose(mesh.evaluate(C, t, r)[:, 0], f(t), rtol=1e-11, atol=1e-11)


@pytest.mark.parametrize("order", ["cubic", "quintic"])
def test_elements_do_not_reproduce_one_degree_more(order):
    mesh = HermiteMesh(order, 1.0, 2)
    p = np.polynomial.Polynomial([0] * (POLY_DEGREE[order] + 1) + [1.0])
    C = mesh.interpolate(p, p.deriv(), p.deriv(2))
    assert abs(mesh.evaluate(C, [0.25])[0, 0] - p(0.25)) > 1e-6


@pytest.mark.parametrize("order,smooth", [("cubic", 2), ("quintic", 3)])
def test_trajectory_is_continuous_across_nodes_up_to_its_smoothness(order, smooth):
    rng = np.random.default_rng(7)
    mesh = HermiteMesh(order, 2.0, 5)
    C = rng.normal(size=(6, mesh.m, 3))
    loc = mesh.local_coefficients(C)
    for r in range(smooth):
        left_end = np.einsum("j,ejn->en", mesh.shape_values(np.array([1.0]), r)[0], loc[:-1])
        right_start = np.einsum("j,ejn->en", mesh.shape_values(np.array([0.0]), r)[0], loc[1:])
        np.testing.assert_allclose(left_end, right_start, atol=1e-12)
        np.testing.assert_allclose(left_end, C[1:-1, r], atol=1e-12)  # and equals the nodal coefficient


def test_cubic_second_derivative_jumps_at_nodes():
    rng = np.random.default_rng(1)
    mesh = HermiteMesh("cubic", 2.0, 4)
    C = rng.normal(size=(5, 2, 1))
    loc = mesh.local_coefficients(C)
    a = np.einsum("j,ejn->en", mesh.shape_values(np.array([1.0]), 2)[0], loc[:-1])
    b = np.einsum("j,ejn->en", mesh.shape_values(np.array([0.0]), 2)[0], loc[1:])
    assert np.max(np.abs(a - b)) > 1e-3


@pytest.mark.parametrize("order", ["cubic", "quintic"])
def test_quadrature_operator_transpose_passes_the_dot_product_test(order):
    rng = np.random.default_rng(3)
    mesh = HermiteMesh(order, 1.3, 6)
    op = mesh.quadrature(5)
    C = rng.normal(size=(7, mesh.m, 4))
    g = [rng.normal(size=(op.K, 4)) for _ in range(3)]
    lhs = sum(np.sum(gi * ai) for gi, ai in zip(g, op.apply(C)))
    rhs = np.sum(op.transpose(*g) * C)
    assert lhs == pytest.approx(rhs, rel=1e-13)


def test_quadrature_operator_matches_pointwise_evaluation_and_integrates_exactly():
    mesh = HermiteMesh("quintic", 2.0, 4)
    op = mesh.quadrature(4)
    C = np.random.default_rng(0).normal(size=(5, 3, 2))
    for r, vals in enumerate(op.apply(C)):
        np.testing.assert_allclose(vals, mesh.evaluate(C, op.t, r), atol=1e-12)
    assert op.integrate(op.t**7) == pytest.approx(2.0**8 / 8, rel=1e-13)  # degree 7 = 2G-1


@pytest.mark.parametrize("order,expected", [("cubic", 4.0), ("quintic", 6.0)])
def test_interpolation_error_of_sin_converges_at_the_papers_order(order, expected):
    h, err = interpolation_errors(order)
    assert np.all(np.diff(err) < 0)
    assert convergence_order(h, err) == pytest.approx(expected, abs=0.2)


def test_error_norm_is_zero_for_an_exact_interpolant():
    mesh = HermiteMesh("quintic", 1.0, 3)
    p = np.polynomial.Polynomial([1, 2, 3, 4, 5, 6])
    C = mesh.interpolate(p, p.deriv(), p.deriv(2))
    assert error_norm(mesh, C, (p, p.deriv(), p.deriv(2))) < 1e-12


@pytest.mark.parametrize("bad", [dict(T=0.0), dict(T=-1.0), dict(T=float("nan")), dict(N=0), dict(order="linear")])
def test_mesh_rejects_invalid_parameters(bad):
    kw = dict(order="cubic", T=1.0, N=2) | bad
    with pytest.raises(ValueError):
        HermiteMesh(**kw)


def test_mesh_takes_numpy_scalars_and_shares_one_read_only_operator_per_mesh_and_G():
    a = HermiteMesh("quintic", np.array(1.5), np.int64(4))  # a 0-d array T, a numpy N
    b = HermiteMesh("quintic", 1.5, 4)
    assert type(a.T) is float and type(a.N) is int and a == b
    op = a.quadrature(6)
    assert b.quadrature(6) is op and b.quadrature(7) is not op
    with pytest.raises(ValueError):
        op.w[0] = 0.0  # cached arrays are read-only: no caller can corrupt another's operator
