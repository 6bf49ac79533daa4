"""Sparse block-banded Levenberg–Marquardt (rsrd_jax.plan) against dense references."""

import jax
import jax.numpy as jnp
import jaxlie
import jaxtyping
import numpy as np
import pytest

from rsrd_jax.plan import (
    BandedProblem,
    Cost,
    LMResult,
    SolverConfig,
    TerminationConfig,
    TrustRegionConfig,
    banded_cholesky,
    banded_cholesky_solve,
    banded_matvec,
    banded_solve,
    banded_to_dense,
    solve_lm,
)
from rsrd_jax.plan._lm import _linearise


def _random_spd_bands(rng, T, B, D):
    """Lower bands of A = L L^T for a random well-conditioned block-banded lower L."""
    L = rng.normal(size=(T, B + 1, D, D)) * 0.5
    for t in range(T):
        L[t, 0] = np.tril(L[t, 0]) + 2.0 * np.eye(D)
        L[t, t + 1 :] = 0.0
    Ld = np.zeros((T * D, T * D))
    for t in range(T):
        for k in range(min(B, t) + 1):
            Ld[t * D : (t + 1) * D, (t - k) * D : (t - k + 1) * D] = L[t, k]
    A = Ld @ Ld.T
    bands = np.zeros((T, B + 1, D, D))
    for t in range(T):
        for k in range(min(B, t) + 1):
            bands[t, k] = A[t * D : (t + 1) * D, (t - k) * D : (t - k + 1) * D]
    return A, jnp.asarray(bands, jnp.float32)


@pytest.mark.parametrize("B", [0, 1, 2, 3])
def test_banded_solve_equals_dense(B):
    rng = np.random.default_rng(B)
    T, D = 9, 4
    A, bands = _random_spd_bands(rng, T, B, D)
    rhs = rng.normal(size=(T, D))
    x_dense = np.linalg.solve(A, rhs.reshape(-1)).reshape(T, D)
    rhs32 = jnp.asarray(rhs, jnp.float32)

    @jax.jit
    def run(bands, rhs):
        L = banded_cholesky(bands)
        x = banded_solve(bands, rhs)
        return banded_to_dense(bands), x, banded_to_dense(L), banded_cholesky_solve(L, rhs), banded_matvec(bands, x)

    dense, x, L, x2, Ax = run(bands, rhs32)
    np.testing.assert_allclose(dense, A, atol=1e-5)
    np.testing.assert_allclose(x, x_dense, atol=2e-5, rtol=1e-4)
    np.testing.assert_allclose(np.tril(L), np.linalg.cholesky(A), atol=2e-5)
    np.testing.assert_allclose(x2, x_dense, atol=2e-5, rtol=1e-4)
    np.testing.assert_allclose(Ax, rhs, atol=2e-5)


def test_banded_solve_vmap():
    rng = np.random.default_rng(7)
    mats = [_random_spd_bands(rng, 6, 2, 3) for _ in range(5)]
    bands = jnp.stack([b for _, b in mats])
    rhs = rng.normal(size=(5, 6, 3))
    xs = jax.jit(jax.vmap(banded_solve))(bands, jnp.asarray(rhs, jnp.float32))
    for (A, _), r, x in zip(mats, rhs, xs):
        np.testing.assert_allclose(x, np.linalg.solve(A, r.reshape(-1)).reshape(6, 3), atol=2e-5, rtol=1e-4)


# ---------------------------------------------------------------------------------------------
# Toy chain: planar N-link arm tracking end-effector targets with velocity/acceleration smoothness
# ---------------------------------------------------------------------------------------------

N_LINKS, T_KEYS = 5, 8


def _fk(q):
    a = jnp.cumsum(q)
    return jnp.stack([jnp.sum(jnp.cos(a)), jnp.sum(jnp.sin(a)), a[-1]]) / jnp.array([N_LINKS, N_LINKS, 1.0])


def _unary(q, target, p):
    return jnp.concatenate([p["w_pose"] * (_fk(q) - target), p["w_rest"] * q])


def _vel(qw, _, p):
    return p["w_vel"] * (qw[1] - qw[0])


def _acc(qw, _, p):
    return p["w_acc"] * (qw[2] - 2.0 * qw[1] + qw[0])


ARM = BandedProblem(costs=(Cost(_unary, 0, "pose"), Cost(_vel, 1, "vel"), Cost(_acc, 2, "acc")))


def _arm_instance(seed=0, T=T_KEYS, N=N_LINKS):
    rng = np.random.default_rng(seed)
    ts = jnp.linspace(0.0, 1.0, T)[:, None]
    phase = jnp.asarray(rng.uniform(0, 2 * np.pi, N), jnp.float32)
    q_true = 0.4 * jnp.sin(2.0 * ts + phase) + 0.2
    targets = jax.vmap(_fk)(q_true)
    params = dict(
        w_pose=jnp.float32(5.0), w_rest=jnp.float32(0.1), w_vel=jnp.float32(1.0), w_acc=jnp.float32(0.5)
    )
    x0 = jnp.full((T, N), 0.1, jnp.float32)
    return x0, (targets, None, None), params


TIGHT = SolverConfig(termination=TerminationConfig(cost_tolerance=1e-7, gradient_tolerance=1e-5))


def test_assembly_matches_dense_normal_equations():
    """Banded J^T J and J^T r equal the dense products of the full Jacobian (b = 0, 1, 2 terms)."""
    x0, data, params = _arm_instance()
    x = x0 + 0.3 * jax.random.normal(jax.random.key(0), x0.shape)
    lam = 0.3

    @jax.jit
    def run(x):
        lin = _linearise(ARM, x, data, params)
        J = jax.jacfwd(lambda y: ARM.residual_vector(y, data, params))(x).reshape(-1, x.size)
        r = ARM.residual_vector(x, data, params)
        step = banded_solve(lin.bands.at[:, 0].add(lam * jnp.eye(x.shape[1])), -lin.grad)
        return lin, J, r, banded_to_dense(lin.bands), step

    lin, J, r, JtJ_banded, step = run(x)
    np.testing.assert_allclose(JtJ_banded, J.T @ J, atol=1e-4, rtol=1e-4)
    np.testing.assert_allclose(lin.grad.reshape(-1), J.T @ r, atol=1e-4, rtol=1e-4)
    np.testing.assert_allclose(lin.cost, jnp.sum(r**2), rtol=1e-5)
    # One damped LM step = dense solve of the same normal equations.
    dense = np.linalg.solve(np.asarray(J.T @ J, np.float64) + lam * np.eye(x.size), -np.asarray(J.T @ r))
    np.testing.assert_allclose(step.reshape(-1), dense, atol=1e-4, rtol=1e-3)


def test_custom_jacobian_equals_autodiff():
    """A Cost with an analytic Jacobian assembles the same normal equations as jacfwd."""

    def unary_jac(q, target, p):
        r = _unary(q, target, p)
        return r, jax.jacfwd(_unary)(q, target, p) * 1.0  # any (R, D) function of the inputs

    def vel_jac(qw, _, p):
        eye = jnp.eye(qw.shape[1]) * p["w_vel"]
        return _vel(qw, None, p), jnp.stack([-eye, eye], axis=1)

    custom = BandedProblem(
        costs=(Cost(_unary, 0, "pose", jac=unary_jac), Cost(_vel, 1, "vel", jac=vel_jac), Cost(_acc, 2, "acc"))
    )
    x0, data, params = _arm_instance(3)
    x = x0 + 0.2
    a, b = jax.jit(lambda x: (_linearise(ARM, x, data, params), _linearise(custom, x, data, params)))(x)
    np.testing.assert_allclose(a.bands, b.bands, atol=1e-5)
    np.testing.assert_allclose(a.grad, b.grad, atol=1e-5)


def test_arm_matches_optimistix_and_jaxopt():
    optx = pytest.importorskip("optimistix")
    jaxopt = pytest.importorskip("jaxopt")
    x0, data, params = _arm_instance()
    sol = solve_lm(ARM, x0, data, params, TIGHT)
    assert sol.result == LMResult.converged

    fn = lambda y, _: ARM.residual_vector(y, data, params)  # noqa: E731
    ref = optx.least_squares(fn, optx.LevenbergMarquardt(rtol=1e-8, atol=1e-8), x0, max_steps=500, throw=False)
    lm = jaxopt.LevenbergMarquardt(
        residual_fun=lambda v: ARM.residual_vector(v.reshape(x0.shape), data, params),
        maxiter=200,
        tol=1e-6,
        solver="cholesky",
        materialize_jac=True,
    )
    ref2 = lm.run(x0.reshape(-1)).params.reshape(x0.shape)
    for y in (ref.value, ref2):
        c_ref = ARM.cost(y, data, params)
        assert abs(float(sol.cost) - float(c_ref)) <= 1e-4 * float(c_ref)
        np.testing.assert_allclose(sol.x, y, atol=3e-3)
    # and it is a stationary point
    assert float(sol.gradient_max) < 1e-3


def test_rosenbrock_known_optimum():
    def rosen(x, _, p):
        return jnp.stack([10.0 * (x[1] - x[0] ** 2), 1.0 - x[0]])

    prob = BandedProblem(costs=(Cost(rosen),))
    sol = solve_lm(prob, jnp.array([[-1.2, 1.0]]))
    assert sol.result == LMResult.converged
    np.testing.assert_allclose(sol.x, [[1.0, 1.0]], atol=1e-3)
    assert float(sol.cost) < 1e-8
    # cost history is non-increasing (only accepted steps change it) and starts at f(x0) = 24.2
    h = np.asarray(sol.cost_history)
    np.testing.assert_allclose(h[0], 24.2, rtol=1e-5)
    assert np.all(np.diff(h) <= 0)


def test_chained_rosenbrock_banded():
    """Extended (chained) Rosenbrock: r = (10 (x_t - x_{t-1}^2), 1 - x_{t-1}); optimum all ones."""

    def link(xw, _, p):
        return jnp.stack([10.0 * (xw[1, 0] - xw[0, 0] ** 2), 1.0 - xw[0, 0]])

    prob = BandedProblem(costs=(Cost(link, 1, "chain"),))
    x0 = jnp.tile(jnp.array([[-1.2], [1.0]]), (6, 1))
    sol = solve_lm(prob, x0, config=SolverConfig(termination=TerminationConfig(max_iterations=300)))
    assert sol.result == LMResult.converged
    np.testing.assert_allclose(sol.x, 1.0, atol=2e-3)


def test_manifold_retract_so3_smoothing():
    """SO(3) keyframes (wxyz, P=4, D=3) with jaxlie retraction: stays on the manifold and reaches a
    point where no tangent perturbation lowers the cost."""
    T = 4
    key = jax.random.key(3)
    targets = jax.vmap(lambda k: jaxlie.SO3.exp(0.8 * jax.random.normal(k, (3,))).wxyz)(jax.random.split(key, T))

    def unary(q, tgt, p):
        return (jaxlie.SO3(tgt).inverse() @ jaxlie.SO3(q)).log()

    def smooth(qw, _, p):
        return p * (jaxlie.SO3(qw[0]).inverse() @ jaxlie.SO3(qw[1])).log()

    retract = lambda q, d: (jaxlie.SO3(q) @ jaxlie.SO3.exp(d)).wxyz  # noqa: E731
    prob = BandedProblem(costs=(Cost(unary), Cost(smooth, 1)), retract=retract, tangent_dim=3)
    x0 = jnp.tile(jnp.array([1.0, 0.0, 0.0, 0.0]), (T, 1))
    sol = solve_lm(prob, x0, (targets, None), jnp.float32(2.0), TIGHT)
    assert sol.result == LMResult.converged
    np.testing.assert_allclose(jnp.linalg.norm(sol.x, axis=-1), 1.0, atol=1e-5)
    cost = jax.jit(lambda x: prob.cost(x, (targets, None), jnp.float32(2.0)))
    base = float(cost(sol.x))
    perturb = 1e-2 * jax.random.normal(jax.random.key(4), (16, T, 3))
    worse = jax.jit(jax.vmap(lambda d: cost(jax.vmap(retract)(sol.x, d))))(perturb)
    assert np.all(np.asarray(worse) >= base - 1e-5)
    # smoothing pulls neighbours together: the solution is not just the targets
    assert base > 1e-3


def test_result_nonfinite_residual():
    x0, data, params = _arm_instance()
    bad_targets = data[0].at[3, 0].set(jnp.nan)
    sol = solve_lm(ARM, x0, (bad_targets, None, None), params, TIGHT)
    assert sol.result == LMResult.nonfinite
    assert int(sol.iterations) == 0
    np.testing.assert_array_equal(sol.x, x0)


def test_result_stalled_when_every_step_is_nonfinite():
    """Finite at x0 = 1 but NaN anywhere else: every step is rejected until lambda_max."""

    def spiky(x, _, p):
        return x + jnp.where(x == 1.0, 0.0, jnp.nan)

    prob = BandedProblem(costs=(Cost(spiky),))
    cfg = SolverConfig(trust_region=TrustRegionConfig(lambda_factor=10.0, lambda_max=1e3))
    sol = solve_lm(prob, jnp.ones((3, 2)), config=cfg)
    assert sol.result == LMResult.stalled
    assert int(sol.accepted_steps) == 0
    np.testing.assert_array_equal(sol.x, 1.0)


def test_result_max_iterations_and_throw():
    def rosen(x, _, p):
        return jnp.stack([10.0 * (x[1] - x[0] ** 2), 1.0 - x[0]])

    prob = BandedProblem(costs=(Cost(rosen),))
    cfg = SolverConfig(termination=TerminationConfig(max_iterations=3))
    sol = solve_lm(prob, jnp.array([[-1.2, 1.0]]), config=cfg)
    assert sol.result == LMResult.max_iterations
    assert int(sol.iterations) == 3
    assert sol.cost_history.shape == (4,)
    with pytest.raises(Exception, match="max_iterations"):
        jax.block_until_ready(
            solve_lm(prob, jnp.array([[-1.2, 1.0]]), config=SolverConfig(termination=cfg.termination, throw=True))
        )


@pytest.mark.parametrize("loop", ["while", pytest.param("scan", marks=pytest.mark.slow)])
def test_vmap_batch_matches_individual_solves(loop):
    cfg = TIGHT if loop == "while" else SolverConfig(loop="scan", termination=TIGHT.termination)
    instances = [_arm_instance(seed) for seed in range(4)]
    x0 = jnp.stack([i[0] for i in instances]) + jnp.arange(4.0)[:, None, None] * 0.05
    targets = jnp.stack([i[1][0] for i in instances])
    params = instances[0][2]
    batch = jax.vmap(lambda x, t: solve_lm(ARM, x, (t, None, None), params, cfg))(x0, targets)
    assert batch.x.shape == x0.shape
    assert (batch.result == LMResult.converged).shape == (4,)
    for k in range(4):
        single = solve_lm(ARM, x0[k], (targets[k], None, None), params, TIGHT)
        assert bool((batch.result == single.result)[k])
        assert int(batch.iterations[k]) == int(single.iterations)
        np.testing.assert_allclose(batch.x[k], single.x, atol=1e-4)
        np.testing.assert_allclose(batch.cost[k], single.cost, rtol=1e-4)


def test_scan_loop_equals_while_loop():
    x0, data, params = _arm_instance(1)
    a = solve_lm(ARM, x0, data, params, TIGHT)
    b = solve_lm(ARM, x0, data, params, SolverConfig(loop="scan", termination=TIGHT.termination))
    assert int(a.iterations) == int(b.iterations)
    np.testing.assert_allclose(a.x, b.x, atol=1e-6)
    np.testing.assert_allclose(a.cost_history, b.cost_history, rtol=1e-6)


def test_compiles_once_across_calls():
    traces = []

    def unary(q, target, p):
        traces.append(1)  # runs at trace time only
        return _unary(q, target, p)

    prob = BandedProblem(costs=(Cost(unary), Cost(_vel, 1), Cost(_acc, 2)))
    x0, data, params = _arm_instance(0)
    solve_lm(prob, x0, data, params)
    n = len(traces)
    assert n > 0
    x1, data1, _ = _arm_instance(5)
    params1 = {k: v * 1.5 for k, v in params.items()}
    cfg = SolverConfig(
        trust_region=TrustRegionConfig(lambda_initial=0.1, lambda_factor=3.0),
        termination=TerminationConfig(cost_tolerance=1e-6, gradient_tolerance=1e-3),
    )
    solve_lm(prob, x1 + 0.2, data1, params1, cfg)
    assert len(traces) == n


def test_implicit_gradient_matches_finite_differences():
    x0, data, params = _arm_instance(2)
    cfg = TIGHT

    def f(w_vel, targets):
        p = dict(params, w_vel=w_vel)
        x = solve_lm(ARM, x0, (targets, None, None), p, cfg).x
        return jnp.sum(jnp.sin(x[2:5]))

    w, targets = jnp.float32(1.0), data[0]
    gw, gt = jax.grad(f, argnums=(0, 1))(w, targets)
    eps = 1e-2
    fd_w = (f(w + eps, targets) - f(w - eps, targets)) / (2 * eps)
    np.testing.assert_allclose(gw, fd_w, rtol=5e-2, atol=1e-3)
    e = jnp.zeros_like(targets).at[4, 1].set(eps)
    fd_t = (f(w, targets + e) - f(w, targets - e)) / (2 * eps)
    np.testing.assert_allclose(gt[4, 1], fd_t, rtol=5e-2, atol=1e-3)



@pytest.mark.slow
def test_unrolled_scan_gradient_matches_implicit():
    x0, data, params = _arm_instance(2)
    term = TerminationConfig(cost_tolerance=1e-9, gradient_tolerance=1e-6)

    def f(w, cfg):
        return jnp.sum(jnp.sin(solve_lm(ARM, x0, data, dict(params, w_vel=w), cfg).x[2:5]))

    w = jnp.float32(1.0)
    g_implicit = jax.grad(f)(w, SolverConfig(termination=term))
    g_unrolled = jax.grad(f)(w, SolverConfig(loop="scan", implicit_diff=False, termination=term))
    np.testing.assert_allclose(g_unrolled, g_implicit, rtol=2e-2, atol=1e-3)


def test_host_boundary_errors():
    x0, data, params = _arm_instance()
    with pytest.raises((ValueError, jaxtyping.TypeCheckError)):  # jaxtyping catches it first under pytest
        solve_lm(ARM, x0[0], data, params)
    with pytest.raises(ValueError, match="one entry per cost"):
        solve_lm(ARM, x0, data[:2], params)
    with pytest.raises(ValueError, match="'pose'.*leading axis"):
        solve_lm(ARM, x0, (data[0][:-1], None, None), params)
    with pytest.raises(ValueError, match="'acc'.*needs T > 2"):
        solve_lm(ARM, x0[:2], (data[0][:2], None, None), params)


@pytest.mark.slow
def test_yumi_trajectory_matches_optimistix_and_jaxopt():
    """The bimanual YuMi problem (both TCP poses, rest, limits, velocity smoothness), small T."""
    optx = pytest.importorskip("optimistix")
    from rsrd_jax.robot import load_yumi, tcp_poses

    model = load_yumi()
    T = 6

    def pose(q, target, p):
        T_tcp = jaxlie.SE3(tcp_poses(model, q, check_finite=False))
        T_tgt = jaxlie.SE3(target)
        rot = (T_tgt.rotation().inverse() @ T_tcp.rotation()).log()
        limit = jax.nn.relu(q - model.upper) + jax.nn.relu(model.lower - q)
        pos = T_tcp.translation() - T_tgt.translation()
        return jnp.concatenate([5.0 * pos.reshape(-1), rot.reshape(-1), 100.0 * limit, 0.01 * (q - model.home)])

    prob = BandedProblem(costs=(Cost(pose, 0, "pose"), Cost(lambda qw, _, p: qw[1] - qw[0], 1, "vel")))
    ts = jnp.linspace(0.0, 1.0, T)[:, None]
    q_true = model.home + 0.2 * jnp.sin(2.0 * ts + jnp.arange(16.0)).at[:, 14:].set(0.0)
    targets = tcp_poses(model, q_true)
    data = (targets, None)
    x0 = jnp.tile(model.home, (T, 1))
    sol = solve_lm(prob, x0, data, None, TIGHT)
    assert sol.result == LMResult.converged
    fn = lambda y, _: prob.residual_vector(y, data, None)  # noqa: E731
    ref = optx.least_squares(fn, optx.LevenbergMarquardt(rtol=1e-7, atol=1e-7), x0, max_steps=300, throw=False)
    jaxopt = pytest.importorskip("jaxopt")
    lm = jaxopt.LevenbergMarquardt(
        residual_fun=lambda v: prob.residual_vector(v.reshape(x0.shape), data, None),
        maxiter=100,
        tol=1e-4,
        solver="cholesky",
        materialize_jac=True,
    )
    ref2 = lm.run(x0.reshape(-1)).params.reshape(x0.shape)
    for y in (ref.value, ref2):
        c_ref = float(prob.cost(y, data, None))
        assert abs(float(sol.cost) - c_ref) <= 1e-3 * c_ref + 1e-7
        np.testing.assert_allclose(sol.x, y, atol=5e-3)
