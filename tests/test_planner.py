"""The planner: exact gradients, the banded Newton matrix, the paper's validation problem, URDF robots."""
import zlib
from pathlib import Path

import numpy as np
import pytest

from hoc_cli.banded import element_blocks, element_blocks_kron
from hoc_cli.elements import HermiteMesh, error_norm
from hoc_cli.model import load_robot
from hoc_cli.planner import plan
from hoc_cli.problem import ControlProblem
from hoc_cli.system import LinearOscillator, RobotSystem
from hoc_cli.verification import convergence_order

ROBOTS = Path(__file__).resolve().parent.parent / "robots"
SHIPPED = sorted(p.name for p in ROBOTS.glob("*.urdf"))


def _random_boundary(model, rng):
    lo = np.where(np.isfinite(model.lower), model.lower, -2.0)
    hi = np.where(np.isfinite(model.upper), model.upper, 2.0)
    q0, q1 = (lo + (hi - lo) * rng.uniform(0.3, 0.7, model.n) for _ in range(2))
    return q0, rng.normal(0, 0.3, model.n), q1, rng.normal(0, 0.3, model.n)


@pytest.mark.parametrize("urdf", SHIPPED)
@pytest.mark.parametrize("order", ["cubic", "quintic"])
@pytest.mark.parametrize("cost", ["covariant", "torque"])
def test_analytic_gradient_matches_central_differences_on_every_shipped_robot(urdf, order, cost):
    rng = np.random.default_rng(zlib.crc32(f"{urdf} {order} {cost}".encode()))
    model = load_robot(ROBOTS / urdf)
    P = ControlProblem(RobotSystem(model), HermiteMesh(order, 1.2, 3), *_random_boundary(model, rng), cost=cost, G=5)
    x = P.initial_guess() + 0.05 * rng.normal(size=P.layout.size)
    g = P.evaluate(x).grad
    for _ in range(3):
        d = rng.normal(size=x.size)
        eps = 1e-6
        fd = (P.value(x + eps * d) - P.value(x - eps * d)) / (2 * eps)
        assert g @ d == pytest.approx(fd, rel=2e-7, abs=1e-7 * np.abs(g).sum())


@pytest.mark.parametrize("cost", ["covariant", "torque"])
def test_banded_newton_matrix_equals_the_finite_difference_hessian(cost):
    rng = np.random.default_rng(5)
    model = load_robot(ROBOTS / "two_link.urdf")
    mesh = HermiteMesh("quintic", 1.0, 3)
    P = ControlProblem(RobotSystem(model), mesh, *_random_boundary(model, rng), cost=cost, G=5)
    x = P.initial_guess() + 0.05 * rng.normal(size=P.layout.size)
    n = x.size
    H = np.empty((n, n))
    for i in range(n):
        e = np.zeros(n)
        e[i] = 1e-5
        H[:, i] = (P.evaluate(x + e).grad - P.evaluate(x - e).grad) / 2e-5
    assert P.op_h.G == P.G  # with G = 5 the preconditioner quadrature is the cost's own
    blocks = element_blocks(P.op_h, P.sample_hessians(*P.op_h.apply(P.coefficients(x))))
    mn = mesh.m * model.n
    D = np.zeros(((mesh.N + 1) * mn,) * 2)
    for e in range(mesh.N):
        D[e * mn:(e + 2) * mn, e * mn:(e + 2) * mn] += blocks[e]
    D = D[np.ix_(P.layout.free, P.layout.free)]
    np.testing.assert_allclose(D, 0.5 * (H + H.T), atol=1e-6 * np.abs(H).max())


@pytest.mark.parametrize("order", ["cubic", "quintic"])
@pytest.mark.parametrize("nodes", [None, [0.0, 0.05, 0.13, 0.2, 0.34, 0.41]])
def test_element_blocks_by_their_kronecker_structure_equal_the_quadrature_of_the_sample_hessians(order, nodes):
    """``element_blocks`` and ``element_blocks_kron`` assembled against Σ_k w_k J_kᵀ H_k J_k, with J_k the Jacobian of
    the samples (q, q̇, q̈) at sample k in the coefficients, taken column by column from ``op.apply`` of unit
    coefficients (a uniform and a non-uniform mesh)."""
    rng = np.random.default_rng(7)
    n = 3
    mesh = HermiteMesh(order, 0.41, 5) if nodes is None else HermiteMesh.from_nodes(order, np.array(nodes))
    op = mesh.quadrature(mesh.m + 3)
    H = rng.normal(size=(op.K, 3 * n, 3 * n))
    H = H + np.swapaxes(H, 1, 2)
    size = (mesh.N + 1) * mesh.m * n
    J = np.zeros((op.K, 3 * n, size))
    for c in range(size):
        unit = np.zeros(size)
        unit[c] = 1.0
        J[:, :, c] = np.concatenate(op.apply(unit.reshape(mesh.N + 1, mesh.m, n)), axis=1)
    reference = np.einsum("k,kia,kij,kjb->ab", op.w, J, H, J)
    mn = mesh.m * n
    for blocks in (element_blocks(op, H), element_blocks_kron(op, H)):
        D = np.zeros((size, size))
        for e in range(mesh.N):
            D[e * mn:(e + 2) * mn, e * mn:(e + 2) * mn] += blocks[e]
        np.testing.assert_allclose(D, reference, rtol=0, atol=1e-12 * np.abs(reference).max())


@pytest.mark.parametrize("urdf", SHIPPED)
@pytest.mark.parametrize("cost", ["covariant", "torque"])
def test_per_sample_hessian_matches_central_differences_of_the_gradient(urdf, cost):
    """The per-sample Hessian (one batched reverse sweep over forward-perturbed copies, the q̈ block
    and D from its outputs) against central differences of the exact per-sample gradient
    (∂L/∂q, ∂L/∂q̇, ∂L/∂q̈), on every shipped robot at random states, for both costs."""
    rng = np.random.default_rng(zlib.crc32(f"{urdf} {cost}".encode()))
    model = load_robot(ROBOTS / urdf)
    n = model.n
    P = ControlProblem(RobotSystem(model), HermiteMesh("quintic", 1.0, 1), *_random_boundary(model, rng), cost=cost)
    lo = np.where(np.isfinite(model.lower), model.lower, -2.0)
    hi = np.where(np.isfinite(model.upper), model.upper, 2.0)
    K = 4
    q = lo + (hi - lo) * rng.uniform(0.2, 0.8, (K, n))
    dq, ddq = rng.normal(0, 1.0, (2, K, n))
    H = P.sample_hessians(q, dq, ddq)

    def grad(x):
        s = P.sample_gradients(x[:, :n], x[:, n:2 * n], x[:, 2 * n:], jacobians=False)
        return np.concatenate([s.gq, s.gdq, s.gddq], axis=1)

    x = np.concatenate([q, dq, ddq], axis=1)
    eps = 1e-6
    ref = np.empty((K, 3 * n, 3 * n))
    for j in range(3 * n):
        e = np.zeros(3 * n)
        e[j] = eps
        ref[:, :, j] = (grad(x + e) - grad(x - e)) / (2 * eps)
    ref = 0.5 * (ref + np.swapaxes(ref, 1, 2))
    scale = np.abs(ref).max(axis=(1, 2), keepdims=True)
    assert np.all(np.abs(H - ref) <= 5e-6 * scale)  # forward differences: up to ~2e-6 measured


@pytest.mark.parametrize("cost", ["covariant", "torque"])
def test_sample_gradients_from_full_jacobians_equal_the_reverse_sweep(cost):
    """The two routes to ∂L/∂(q, q̇, q̈): full ∂u/∂q, ∂u/∂q̇ (id_derivatives) and the RNEA reverse sweep."""
    rng = np.random.default_rng(11)
    model = load_robot(ROBOTS / "lbr7.urdf")
    P = ControlProblem(RobotSystem(model), HermiteMesh("quintic", 1.0, 1), *_random_boundary(model, rng), cost=cost)
    q = _random_boundary(model, rng)[0] + 0.1 * rng.normal(size=(6, model.n))
    dq, ddq = rng.normal(0, 1.0, (2, 6, model.n))
    a = P.sample_gradients(q, dq, ddq, jacobians=True)
    b = P.sample_gradients(q, dq, ddq, jacobians=False)
    assert a.Jq.shape == (6, model.n, model.n) and b.Jq is None
    for name in ("L", "gq", "gdq", "gddq", "u", "w"):
        ref = getattr(a, name)
        np.testing.assert_allclose(getattr(b, name), ref, rtol=0, atol=1e-10 * np.abs(ref).max())


def test_evaluation_samples_and_the_gradient_hook_serve_a_penalty_on_the_samples():
    """A term Σ_k φ(q_k, q̇_k, q̈_k) built from ``Evaluation``'s samples, differentiated through
    ``gradient_from_samples``, against central differences of the same term."""
    rng = np.random.default_rng(3)
    model = load_robot(ROBOTS / "two_link.urdf")
    P = ControlProblem(RobotSystem(model), HermiteMesh("quintic", 1.0, 3), *_random_boundary(model, rng), G=5)
    x = P.initial_guess() + 0.05 * rng.normal(size=P.layout.size)

    def penalty(ev):  # φ = Σ q³/3 + q̇²/2 + U q̈ with U a fixed random (K, n) array
        return float(np.sum(ev.q ** 3 / 3 + ev.dq ** 2 / 2 + ev.ddq * U))

    ev = P.evaluate(x)
    U = rng.normal(size=ev.u.shape)
    assert ev.q.shape == ev.u.shape == (P.op.K, model.n)
    np.testing.assert_array_equal(np.stack([ev.q, ev.dq, ev.ddq]), np.stack(P.op.apply(P.coefficients(x))))
    g = P.gradient_from_samples(ev.q ** 2, ev.dq, U)
    eps = 1e-6
    for _ in range(3):
        d = rng.normal(size=x.size)
        fd = (penalty(P.evaluate(x + eps * d, grad=False)) - penalty(P.evaluate(x - eps * d, grad=False))) / (2 * eps)
        assert g @ d == pytest.approx(fd, rel=1e-7)


def _validation(order, Ns=(2, 4, 8, 16, 32)):
    """The paper's validation problem: q̈ + q = u, T = π, x0 = (0, 1), x1 = (0, −1); exact q = sin t."""
    hs, Is, es = [], [], []
    for N in Ns:
        mesh = HermiteMesh(order, np.pi, N)
        r = plan(LinearOscillator(), mesh, [0.0], [1.0], [0.0], [-1.0], cost="torque")
        assert r.converged
        hs.append(mesh.h)
        Is.append(r.J)
        es.append(error_norm(mesh, r.coeffs, (np.sin, np.cos, lambda t: -np.sin(t))))
    return np.array(hs), np.array(Is), np.array(es)


@pytest.mark.parametrize("order,order_I,order_e", [("cubic", 4.0, 4.0), ("quintic", 8.0, 6.0)])
def test_validation_problem_converges_at_the_measured_orders(order, order_I, order_e):
    h, I, e = _validation(order)
    assert np.all(np.diff(I) < 0) and np.all(np.diff(e) < 0)
    assert convergence_order(h[1:], I[1:]) == pytest.approx(order_I, abs=0.15)
    assert convergence_order(h[1:], e[1:]) == pytest.approx(order_e, abs=0.15)


@pytest.mark.parametrize("order,N", [("cubic", 32), ("quintic", 16)])
def test_planner_finds_the_exact_optimum_of_the_oscillator_from_rest_to_one(order, N):
    """q̈ + q = u, x0 = (0, 0), x1 = (1, 0), T = π. The control equation ü + u = 0 and the four
    boundary conditions give u* = (2/π) sin t, q* = (sin t − t cos t)/π and J* = 1/π."""
    mesh = HermiteMesh(order, np.pi, N)
    r = plan(LinearOscillator(), mesh, [0.0], [0.0], [1.0], [0.0], cost="torque")
    assert r.converged
    t = np.linspace(0, np.pi, 301)
    q, dq, ddq = mesh.evaluate_all(r.coeffs, t)
    u = ddq + q
    assert r.J == pytest.approx(1 / np.pi, rel=1e-6)
    np.testing.assert_allclose(u[:, 0], 2 / np.pi * np.sin(t), atol=2e-3 if order == "cubic" else 3e-6)
    np.testing.assert_allclose(q[:, 0], (np.sin(t) - t * np.cos(t)) / np.pi, atol=1e-6)
    # and the discrete J is above the continuous optimum, converging to it
    assert r.J >= 1 / np.pi - 1e-15


@pytest.mark.parametrize("order,expected", [("cubic", 4.0), ("quintic", 8.0)])
def test_cost_on_a_urdf_robot_decreases_towards_a_limit_as_N_doubles_at_the_measured_order(order, expected):
    """2-link arm: J(N) − J(2N) measured to shrink like h⁴ (cubic) and h⁸ (quintic, asymptotically:
    4.6, 6.5, 8.1 over N = 4…32), the orders of the validation problem's I(q_h)."""
    model = load_robot(ROBOTS / "two_link.urdf")
    S = RobotSystem(model)
    Js, hs = [], []
    for N in (4, 8, 16, 32):
        mesh = HermiteMesh(order, 1.5, N)
        r = plan(S, mesh, [0, 0], [0, 0], [1.2, -0.6], [0, 0])
        assert r.converged
        Js.append(r.J)
        hs.append(mesh.h)
    d = -np.diff(Js)
    assert np.all(d > 0)  # monotone decrease: the spaces are nested (N doubles)
    last_order = np.log(d[-2] / d[-1]) / np.log(2.0)
    assert last_order == pytest.approx(expected, abs=0.4)


def test_each_optimum_beats_the_other_on_its_own_cost():
    model = load_robot(ROBOTS / "two_link.urdf")
    S = RobotSystem(model)
    mesh = HermiteMesh("quintic", 1.5, 8)
    b = ([0, 0], [0, 0], [1.2, -0.6], [0, 0])
    cov = plan(S, mesh, *b, cost="covariant")
    tor = plan(S, mesh, *b, cost="torque")
    Pc = ControlProblem(S, mesh, *b, cost="covariant", G=cov.G)
    Pt = ControlProblem(S, mesh, *b, cost="torque", G=tor.G)
    assert Pc.value(Pc.layout.pack(cov.coeffs)) < Pc.value(Pc.layout.pack(tor.coeffs))
    assert Pt.value(Pt.layout.pack(tor.coeffs)) < Pt.value(Pt.layout.pack(cov.coeffs))


def test_plain_polak_ribiere_without_preconditioner_reaches_the_same_optimum_on_a_small_problem():
    mesh = HermiteMesh("cubic", np.pi, 4)
    pre = plan(LinearOscillator(), mesh, [0.0], [1.0], [0.0], [-1.0], cost="torque")
    plain = plan(LinearOscillator(), mesh, [0.0], [1.0], [0.0], [-1.0], cost="torque", precondition=False)
    assert plain.J == pytest.approx(pre.J, rel=1e-8)
    assert plain.optimizer.iterations > pre.optimizer.iterations  # the h⁻⁴ conditioning, measured in docs/benchmarks.md


def test_work_counts_on_the_two_link_arm_do_not_grow():
    """Pinned work counts (measured 5 iterations, 8 evaluations): a slower algorithm fails here."""
    model = load_robot(ROBOTS / "two_link.urdf")
    r = plan(RobotSystem(model), HermiteMesh("quintic", 1.5, 16), [0, 0], [0, 0], [1.2, -0.6], [0, 0])
    assert r.converged
    assert r.optimizer.iterations <= 7 and r.optimizer.n_evals <= 12


def test_continuation_levels_nest_and_end_at_the_requested_mesh():
    from hoc_cli.planner import continuation_levels

    assert continuation_levels(36) == [3, 9, 18, 36]
    assert continuation_levels(16) == [4, 16]
    assert continuation_levels(8) == [2, 8]
    assert continuation_levels(3) == [3]
    assert continuation_levels(64) == [4, 16, 32, 64]  # above 16: the plan at N/2, refined
    assert continuation_levels(17) == [2, 5, 17]  # a prime has no divisor: not nested (interpolated)
    for N in range(4, 300):
        levels = continuation_levels(N)
        assert levels[-1] == N and levels == sorted(set(levels))
        if any(N % d == 0 for d in range(2, N)) and len(levels) > 1:  # composite: the level below N divides it
            assert N % levels[-2] == 0
        if N > 16 and N % 2 == 0:
            assert levels[:-1] == continuation_levels(N // 2)  # the path of N passes through the plan at N/2


def test_coarse_to_fine_and_single_mesh_solves_reach_the_same_optimum():
    model = load_robot(ROBOTS / "two_link.urdf")
    S = RobotSystem(model)
    mesh = HermiteMesh("quintic", 1.5, 16)
    a = plan(S, mesh, [0, 0], [0, 0], [1.2, -0.6], [0, 0], continuation=True)
    b = plan(S, mesh, [0, 0], [0, 0], [1.2, -0.6], [0, 0], continuation=False)
    assert a.converged and b.converged
    assert a.J == pytest.approx(b.J, rel=1e-10)
    # J to 1e-10 leaves the coefficients accurate to about its square root in the softest directions
    np.testing.assert_allclose(a.coeffs[:, 0], b.coeffs[:, 0], atol=1e-5)
    np.testing.assert_allclose(a.coeffs, b.coeffs, rtol=1e-3, atol=1e-3)


@pytest.mark.parametrize("config", ["two_link.yaml", "dual_arm.yaml", "lbr7_swing.yaml"])
def test_the_default_tolerance_gives_J_within_1e_10_of_a_much_tighter_solve(config):
    from hoc_cli.io.task import load_task, resolve

    task = load_task(ROBOTS.parent / "configs" / config)
    model = load_robot(task.robot)
    s = resolve(task, model.joint_names)
    S = RobotSystem(model)
    mesh = HermiteMesh(task.order, task.T, min(task.N, 8))
    default = plan(S, mesh, s.q0, s.dq0, s.q1, s.dq1)
    tight = plan(S, mesh, s.q0, s.dq0, s.q1, s.dq1, tol=1e-15, G=default.G)
    assert default.converged and tight.converged
    assert abs(default.J - tight.J) <= 1e-10 * tight.J


class _Offset:
    """A stand-in objective term: a constant added to J (gradient and Newton blocks zero)."""

    def evaluate(self, C, grad=True):
        return 7.0, np.zeros_like(C)


@pytest.mark.parametrize("cost", ["covariant", "torque"])
def test_bare_cost_after_an_evaluation_without_gradient_reuses_its_value(cost):
    """The limits' measure after a polish prices the point the polish has just evaluated: ``bare_cost`` takes I(q_h)
    from that evaluation (no second dynamics pass), the same number as a fresh problem's; at another x, or on a
    copy with another quadrature at the same x, it is computed afresh."""
    import copy

    rng = np.random.default_rng(4)
    model = load_robot(ROBOTS / "lbr7.urdf")
    P = ControlProblem(RobotSystem(model), HermiteMesh("quintic", 1.0, 3), *_random_boundary(model, rng), cost=cost)
    x = P.initial_guess() + 0.05 * rng.normal(size=P.layout.size)
    fresh = ControlProblem(RobotSystem(model), P.mesh, *P.boundary, cost=cost).bare_cost(x)
    P.terms = (_Offset(),)
    assert P.evaluate(x, grad=False).J == fresh + 7.0
    evals = P.n_evals
    assert P.bare_cost(x.copy()) == fresh and P.n_evals == evals  # reused
    y = x + 1e-3
    assert P.bare_cost(y) == ControlProblem(RobotSystem(model), P.mesh, *P.boundary, cost=cost).bare_cost(y)
    assert P.n_evals == evals + 1
    P.evaluate(x, grad=False)
    other = copy.copy(P)
    other.op = other.mesh.quadrature(6)  # another quadrature (as a real-time copy on a rescaled mesh has)
    assert other.bare_cost(x) != fresh and other.n_evals == evals + 3


@pytest.mark.parametrize("cost", ["covariant", "torque"])
def test_an_evaluation_with_gradient_at_its_last_x_reuses_the_cost_part(cost):
    """An evaluation with gradient at the x of the last one (the next inner solve starting at the polished point)
    takes I(q_h), its gradient and noise from it without a dynamics pass, the terms evaluated afresh: the same numbers
    as a fresh problem's; ``bare_cost`` there is the evaluation without gradient's number; another x or a copy with
    another quadrature computes afresh."""
    import copy

    rng = np.random.default_rng(5)
    model = load_robot(ROBOTS / "lbr7.urdf")
    P = ControlProblem(RobotSystem(model), HermiteMesh("quintic", 1.0, 3), *_random_boundary(model, rng), cost=cost)
    x = P.initial_guess() + 0.05 * rng.normal(size=P.layout.size)
    ref = ControlProblem(RobotSystem(model), P.mesh, *P.boundary, cost=cost)
    fresh, bare = ref.evaluate(x), ref.bare_cost(x)
    assert ref.evaluate(x, grad=False).J == bare
    calls = []
    sample = P.sample_gradients
    P.sample_gradients = lambda *a, **k: calls.append(1) or sample(*a, **k)
    first = P.evaluate(x)
    assert P.bare_cost(x.copy()) == bare and len(calls) == 1
    first.grad[:] = 0.0  # a caller's change to its gradient does not reach the kept one
    P.terms = (_Offset(),)
    again = P.evaluate(x.copy())
    assert len(calls) == 1 and again.J == fresh.J + 7.0 and np.array_equal(again.grad, fresh.grad)
    assert again.noise == fresh.noise and np.array_equal(again.u, fresh.u)
    P.evaluate(x + 1e-3)
    assert len(calls) == 2
    P.evaluate(x)
    other = copy.copy(P)
    other.op = other.mesh.quadrature(6)
    other.evaluate(x)
    assert len(calls) == 4
    # a polish's trial point: the evaluation without gradient, I(q_h)'s gradient kept for the next inner solve
    y = x + 2e-3
    plain = ControlProblem(RobotSystem(model), P.mesh, *P.boundary, cost=cost)
    trial = P.evaluate(y, grad=False, keep_gradient=True)
    assert trial.grad is None and trial.J == plain.evaluate(y, grad=False).J + 7.0 and len(calls) == 5
    assert P.evaluate(y).J == plain.evaluate(y).J + 7.0 and len(calls) == 5
