"""Sparse Levenberg–Marquardt for block-banded nonlinear least squares.

Variables are ``T`` blocks (keyframes) ``x_t`` of ``P`` parameters with a tangent space of
dimension ``D`` (``D = P`` and additive updates unless a ``retract`` is given). Residual groups
(:class:`Cost`) are either unary, ``r_t = f(x_t, data_t, params)``, or couple a window of
``b + 1`` consecutive keyframes, ``r_t = f(x_{t-b..t}, data_t, params)``; each group is a single
vmapped function, so tracing cost does not grow with ``T``. The objective is

    cost(x) = sum_groups sum_t ||r_t||^2            (sum of squares, as in jaxls)

Each iteration linearises every term with ``jacfwd`` (vmapped over terms), so ``J^T J`` is
block-banded with bandwidth ``B = max b``, assembled directly as ``(T, B+1, D, D)`` lower bands,
and the damped normal equations

    (J^T J + lambda * S) delta = -J^T r,      S = I  or  diag(J^T J)  (Marquardt)

are solved exactly with a block-banded Cholesky in ``lax.scan`` (``_banded.py``). Damping follows
jaxls' trust-region heuristic: the step is accepted when the ratio of actual to predicted
decrease (``rho``) is at least ``step_quality_min``; then lambda is divided by ``lambda_factor``,
otherwise multiplied (Nielsen / Madsen et al., *Methods for non-linear least squares problems*,
2004, §3.2). The predicted decrease uses the normal equations, ``-g.delta + lambda delta^T S delta``
with ``g = J^T r``, so no extra matrix product is needed.

Gradients of the solution with respect to ``data`` and ``params`` come from the implicit
function theorem at the returned point, using the exact Hessian of the cost, which has the same
band structure (block-banded solve again); see :func:`solve_lm`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int, PyTree

from ._banded import banded_cholesky, banded_cholesky_solve, banded_solve


def _as_float(x: Any) -> Array:
    return jnp.asarray(x, dtype=jnp.result_type(float))


# ----------------------------------------------------------------------------------------------
# Configuration
# ----------------------------------------------------------------------------------------------


class TrustRegionConfig(eqx.Module):
    """Levenberg–Marquardt damping schedule (jaxls' defaults). All fields are array leaves, so
    changing them does not recompile."""

    lambda_initial: Float[Array, ""] = eqx.field(converter=_as_float, default=5e-4)
    """Initial damping lambda."""
    lambda_factor: Float[Array, ""] = eqx.field(converter=_as_float, default=2.0)
    """Lambda is divided by this after an accepted step and multiplied after a rejected one."""
    lambda_min: Float[Array, ""] = eqx.field(converter=_as_float, default=1e-5)
    """Lower clip of lambda."""
    lambda_max: Float[Array, ""] = eqx.field(converter=_as_float, default=1e10)
    """Upper clip of lambda; a rejected step at ``lambda_max`` ends the solve as ``stalled``."""
    step_quality_min: Float[Array, ""] = eqx.field(converter=_as_float, default=1e-3)
    """Minimum ratio of actual to predicted cost decrease for a step to be accepted."""


class TerminationConfig(eqx.Module):
    """When to stop. Tolerances are array leaves; ``max_iterations`` fixes buffer shapes and is
    static."""

    max_iterations: int = eqx.field(static=True, default=100)
    """Maximum number of LM iterations (linear solves). Static: it sizes the cost history."""
    cost_tolerance: Float[Array, ""] = eqx.field(converter=_as_float, default=1e-5)
    """Converged when an accepted step changes the cost by less than this fraction of it."""
    gradient_tolerance: Float[Array, ""] = eqx.field(converter=_as_float, default=1e-4)
    """Converged when ``max |J^T r|`` (half the cost gradient, in tangent coordinates) is below
    this."""
    parameter_tolerance: Float[Array, ""] = eqx.field(converter=_as_float, default=1e-6)
    """Converged when an accepted step has ``||delta|| < tol * (||x|| + tol)``."""


class SolverConfig(eqx.Module):
    """Everything :func:`solve_lm` needs besides the problem."""

    trust_region: TrustRegionConfig = TrustRegionConfig()
    """Damping schedule."""
    termination: TerminationConfig = TerminationConfig()
    """Stopping rules."""
    damping: Literal["identity", "marquardt"] = eqx.field(static=True, default="identity")
    """``"identity"``: add ``lambda I`` (jaxls); ``"marquardt"``: add ``lambda diag(J^T J)``
    (scale-invariant; the diagonal is floored at 1e-9)."""
    loop: Literal["while", "scan"] = eqx.field(static=True, default="while")
    """``"while"``: stop as soon as the problem terminates. ``"scan"``: always run
    ``max_iterations`` steps of a ``lax.scan``, finished problems frozen by a mask; gives a fixed
    cost per batch and is reverse-differentiable by unrolling."""
    implicit_diff: bool = eqx.field(static=True, default=True)
    """Differentiate the solution with the implicit function theorem (exact Hessian at the
    returned point) instead of through the iterations. Must be ``False`` to backpropagate
    through the unrolled ``scan`` loop; ``while`` loops are only differentiable implicitly."""
    throw: bool = eqx.field(static=True, default=False)
    """Raise (via ``eqx.error_if``) when the result is not ``converged``."""


class LMResult(eqx.Enumeration):
    """Outcome of :func:`solve_lm`."""

    converged = "converged: a cost, gradient or parameter tolerance was met"
    max_iterations = "max_iterations reached before convergence"
    stalled = "no acceptable step even at lambda_max"
    nonfinite = "non-finite cost or Jacobian at the initial point"


# ----------------------------------------------------------------------------------------------
# Problem definition
# ----------------------------------------------------------------------------------------------


class Cost(eqx.Module):
    """A group of residual terms of one shape, evaluated by one vmapped function.

    ``bandwidth == 0``: ``fn(x_t, data_t, params) -> r`` with ``x_t`` of shape (P,), one term
    per keyframe t = 0..T-1 (``data`` has leading axis T).
    ``bandwidth == b > 0``: ``fn(x_window, data_t, params) -> r`` with ``x_window`` of shape
    (b+1, P) holding ``x_{t-b}..x_t``, one term per t = b..T-1 (``data`` has leading axis T-b).
    ``r`` is a 1-D residual of fixed length. Residuals enter the cost squared: weight them by
    ``sqrt(weight)`` to mean ``weight * ||r||^2``.
    """

    fn: Callable[..., Array] = eqx.field(static=True)
    """Residual function ``(x, data_t, params) -> r``; ``data_t`` is None if no data is given."""
    bandwidth: int = eqx.field(static=True, default=0)
    """Number of earlier keyframes each term couples to (0 unary, 1 velocity, 2 acceleration)."""
    name: str = eqx.field(static=True, default="")
    """Name used in error messages."""
    jac: Callable[..., tuple[Array, Array]] | None = eqx.field(static=True, default=None)
    """Optional analytic Jacobian ``(x, data_t, params) -> (r, J)`` replacing ``jacfwd``; ``J``
    is d r / d delta in tangent coordinates, shape (R, D) for unary terms and (R, b+1, D) for
    windows. Implicit differentiation still uses autodiff of ``fn``."""


class BandedProblem(eqx.Module):
    """A least-squares problem over ``T`` keyframe blocks with block-banded coupling.

    Shapes (``T``, ``P``) come from the initial value and data; this object only holds the
    (static) functions, so reuse one instance: a new instance with new lambdas recompiles.
    """

    costs: tuple[Cost, ...] = eqx.field(static=True)
    """Residual groups; ``data`` passed to :func:`solve_lm` is a tuple aligned with them."""
    retract: Callable[[Array, Array], Array] | None = eqx.field(static=True, default=None)
    """Manifold update ``(x_t (P,), delta_t (D,)) -> x_t'`` with ``retract(x, 0) == x``;
    None for additive updates (``D == P``)."""
    tangent_dim: int | None = eqx.field(static=True, default=None)
    """Tangent dimension D when ``retract`` is given (default P)."""

    @property
    def bandwidth(self) -> int:
        """Block bandwidth B of ``J^T J`` (max over cost groups)."""
        return max((c.bandwidth for c in self.costs), default=0)

    def _tangent_dim(self, P: int) -> int:
        return P if self.tangent_dim is None else self.tangent_dim

    def _retract(self, x: Array, delta: Array) -> Array:
        if self.retract is None:
            return x + delta
        return jax.vmap(self.retract)(x.reshape(-1, x.shape[-1]), delta.reshape(-1, delta.shape[-1])).reshape(
            x.shape
        )

    def residuals(
        self, x: Float[Array, "T P"], data: tuple[PyTree, ...] | None = None, params: PyTree = None
    ) -> tuple[Float[Array, "..."], ...]:
        """Residuals of every group, each of shape (terms, residual_dim)."""
        data = _normalise_data(self, x.shape[0], data)
        out = []
        for cost, d in zip(self.costs, data):
            xw = _windows(x, cost.bandwidth)
            out.append(jax.vmap(lambda xw_t, d_t, c=cost: c.fn(xw_t, d_t, params))(xw, d))
        return tuple(out)

    def residual_vector(
        self, x: Float[Array, "T P"], data: tuple[PyTree, ...] | None = None, params: PyTree = None
    ) -> Float[Array, " R"]:
        """All residuals concatenated into one vector (for dense reference solvers)."""
        return jnp.concatenate([r.reshape(-1) for r in self.residuals(x, data, params)])

    def cost(
        self, x: Float[Array, "T P"], data: tuple[PyTree, ...] | None = None, params: PyTree = None
    ) -> Float[Array, ""]:
        """Sum of squared residuals."""
        return sum(jnp.sum(r**2) for r in self.residuals(x, data, params))


def _windows(x: Array, b: int) -> Array:
    """(T, P) -> (T, P) for b = 0, else (T-b, b+1, P) stacking x_{t-b..t}."""
    if b == 0:
        return x
    T = x.shape[0]
    return jnp.stack([x[i : T - b + i] for i in range(b + 1)], axis=1)


def _normalise_data(problem: BandedProblem, T: int, data: Any) -> tuple[Any, ...]:
    """Host-side checks of ``data`` against the cost groups; returns a tuple aligned with them."""
    n = len(problem.costs)
    if n == 0:
        raise ValueError("BandedProblem.costs is empty: nothing to minimise.")
    if data is None:
        data = (None,) * n
    if not isinstance(data, (tuple, list)) or len(data) != n:
        raise ValueError(f"data must be a tuple with one entry per cost ({n}), got {type(data).__name__}")
    for cost, d in zip(problem.costs, data):
        if cost.bandwidth < 0:
            raise ValueError(f"cost {cost.name!r}: bandwidth must be >= 0, got {cost.bandwidth}")
        terms = T - cost.bandwidth
        if terms < 1:
            raise ValueError(f"cost {cost.name!r}: bandwidth {cost.bandwidth} needs T > {cost.bandwidth}, got T={T}")
        for leaf in jax.tree.leaves(d):
            if jnp.ndim(leaf) < 1 or jnp.shape(leaf)[0] != terms:
                raise ValueError(
                    f"cost {cost.name!r}: every data leaf needs leading axis T - bandwidth = {terms}, "
                    f"got shape {jnp.shape(leaf)}"
                )
    return tuple(data)


# ----------------------------------------------------------------------------------------------
# Linearisation and assembly
# ----------------------------------------------------------------------------------------------


class _Linearisation(eqx.Module):
    cost: Float[Array, ""]
    bands: Float[Array, "T B1 D D"]  # J^T J lower bands
    grad: Float[Array, "T D"]  # J^T r
    finite: Bool[Array, ""]


def _group_jacobian(problem: BandedProblem, cost: Cost, x: Array, d: Any, params: Any, D: int):
    """Residuals (n, R) and tangent Jacobians (n, R, b+1, D) of one group."""
    b = cost.bandwidth
    xw = _windows(x, b)

    def term(xw_t, d_t):
        if cost.jac is not None:
            r, J = cost.jac(xw_t, d_t, params)
            return r, J.reshape(r.shape[0], b + 1, D)

        def f(delta):
            xr = problem._retract(xw_t if b else xw_t[None], delta)
            r = cost.fn(xr if b else xr[0], d_t, params)
            if r.ndim != 1:
                raise ValueError(f"cost {cost.name!r} must return a 1-D residual, got shape {r.shape}")
            return r, r

        J, r = jax.jacfwd(f, has_aux=True)(jnp.zeros((b + 1, D), x.dtype))
        return r, J

    return jax.vmap(term)(xw, d)


# Padding instead of `.at[].add`: scatters are slow on CPU, worst under vmap (batched scatter).
def _place_rows(blocks: Array, start: int, T: int) -> Array:
    """Rows ``start..start+n-1`` of a (T, ...) zero array set to ``blocks`` (n, ...)."""
    pad = [(start, T - start - blocks.shape[0])] + [(0, 0)] * (blocks.ndim - 1)
    return jnp.pad(blocks, pad)


def _place_band(blocks: Array, start: int, k: int, T: int, B: int) -> Array:
    """A (T, B+1, D, D) zero array with band ``k`` of rows ``start..`` set to ``blocks`` (n, D, D)."""
    rows = _place_rows(blocks, start, T)[:, None]
    return jnp.pad(rows, [(0, 0), (k, B - k), (0, 0), (0, 0)])


def _add_to_diagonal(bands: Array, diag: Array) -> Array:
    """bands with ``diag`` (T, D) added to the diagonals of the main-diagonal blocks."""
    D = bands.shape[-1]
    eye = jnp.eye(D, dtype=bands.dtype)
    main = bands[:, :1] + (diag[:, :, None] * eye)[:, None]
    return jnp.concatenate([main, bands[:, 1:]], axis=1)


def _linearise(problem: BandedProblem, x: Array, data: tuple, params: Any) -> _Linearisation:
    T, P = x.shape
    D = problem._tangent_dim(P)
    B = problem.bandwidth
    bands = jnp.zeros((T, B + 1, D, D), x.dtype)
    grad = jnp.zeros((T, D), x.dtype)
    cost = jnp.zeros((), x.dtype)
    finite = jnp.array(True)
    for c, d in zip(problem.costs, data):
        b = c.bandwidth
        r, J = _group_jacobian(problem, c, x, d, params, D)
        n, R = r.shape
        Jf = J.reshape(n, R, (b + 1) * D)
        H = jnp.einsum("nri,nrj->nij", Jf, Jf).reshape(n, b + 1, D, b + 1, D)
        gw = jnp.einsum("nri,nr->ni", Jf, r).reshape(n, b + 1, D)
        # Term t covers keyframes t-b..t; its window slot i is keyframe t-b+i, i.e. rows i..i+n-1.
        for i in range(b + 1):
            grad = grad + _place_rows(gw[:, i], i, T)
            for j in range(i + 1):
                bands = bands + _place_band(H[:, i, :, j, :], i, i - j, T, B)
        cost = cost + jnp.sum(r**2)
        finite = finite & jnp.all(jnp.isfinite(J)) & jnp.all(jnp.isfinite(r))
    finite = finite & jnp.isfinite(cost)
    return _Linearisation(cost, bands, grad, finite)


def _hessian_bands(problem: BandedProblem, x: Array, data: tuple, params: Any) -> Array:
    """Exact Hessian of ``0.5 * cost`` in tangent coordinates, as lower bands (for implicit diff)."""
    T, P = x.shape
    D = problem._tangent_dim(P)
    B = problem.bandwidth
    bands = jnp.zeros((T, B + 1, D, D), x.dtype)
    for c, d in zip(problem.costs, data):
        b = c.bandwidth
        xw = _windows(x, b)

        def half_sq(delta, xw_t, d_t, c=c, b=b):
            xr = problem._retract(xw_t if b else xw_t[None], delta)
            r = c.fn(xr if b else xr[0], d_t, params)
            return 0.5 * jnp.sum(r**2)

        zero = jnp.zeros((b + 1, D), x.dtype)
        H = jax.vmap(lambda xw_t, d_t: jax.hessian(half_sq)(zero, xw_t, d_t))(xw, d)  # (n, b+1, D, b+1, D)
        for i in range(b + 1):
            for j in range(i + 1):
                bands = bands + _place_band(H[:, i, :, j, :], i, i - j, T, B)
    return bands


def _tangent_grad(problem: BandedProblem, x: Array, data: tuple, params: Any) -> Array:
    """Gradient of ``0.5 * cost`` with respect to the tangent update at ``x``, shape (T, D)."""
    T, P = x.shape
    D = problem._tangent_dim(P)
    return jax.grad(lambda delta: 0.5 * problem.cost(problem._retract(x, delta), data, params))(
        jnp.zeros((T, D), x.dtype)
    )


# ----------------------------------------------------------------------------------------------
# Solver
# ----------------------------------------------------------------------------------------------


class LMSolution(eqx.Module):
    """Output of :func:`solve_lm`. Under ``vmap`` every field gains the batch axes."""

    x: Float[Array, "T P"]
    """Solution (the best accepted iterate)."""
    cost: Float[Array, ""]
    """Sum of squared residuals at ``x``."""
    result: LMResult
    """Why the solve stopped (``LMResult.converged`` on success)."""
    iterations: Int[Array, ""]
    """Number of LM iterations (linear solves) performed."""
    accepted_steps: Int[Array, ""]
    """Number of accepted steps."""
    cost_history: Float[Array, " max_iterations_plus_1"]
    """Cost after each iteration (entry 0 = initial cost); padded with the final cost."""
    gradient_max: Float[Array, ""]
    """``max |J^T r|`` at ``x``."""
    lambd: Float[Array, ""]
    """Final damping."""


class _State(eqx.Module):
    x: Array  # current (accepted) iterate
    lin: _Linearisation  # at x
    x_trial: Array  # proposed next iterate, evaluated at the start of the next pass
    delta: Array  # tangent step from x to x_trial
    predicted: Array  # predicted cost decrease of the step
    lambd: Array
    iteration: Array  # trial steps evaluated so far
    accepted: Array
    first: Array  # the pass that evaluates x0
    done: Array
    result: LMResult
    history: Array


def _damping_diag(config: SolverConfig, bands: Array) -> Array:
    diag = jnp.diagonal(bands[:, 0], axis1=-2, axis2=-1)
    if config.damping == "identity":
        return jnp.ones_like(diag)
    if config.damping == "marquardt":
        return jnp.maximum(diag, 1e-9)
    raise ValueError(f"SolverConfig.damping must be 'identity' or 'marquardt', got {config.damping!r}")


def _lm_pass(problem: BandedProblem, data, params, config: SolverConfig, s: _State) -> _State:
    """One pass: linearise the pending trial point (x0 on the first pass), accept or reject it,
    test termination, and solve the damped normal equations for the next trial point. Putting
    the only linearisation at the top keeps one copy of the Jacobian code in the compiled loop."""
    tr, term = config.trust_region, config.termination
    lin_t = _linearise(problem, s.x_trial, data, params)

    actual = s.lin.cost - lin_t.cost
    rho = actual / s.predicted
    step_ok = lin_t.finite & jnp.all(jnp.isfinite(s.delta))
    accept = jnp.where(s.first, lin_t.finite, step_ok & (rho >= tr.step_quality_min))
    # A step that changes nothing (cost equal to the last bit) has converged, not failed.
    useful = ~s.first & (accept | (step_ok & (actual == 0)))

    x = jnp.where(accept, s.x_trial, s.x)
    lin = jax.tree.map(lambda a, b: jnp.where(accept, a, b), lin_t, s.lin)
    lambd = jnp.where(
        s.first,
        s.lambd,
        jnp.where(
            accept,
            jnp.maximum(s.lambd / tr.lambda_factor, tr.lambda_min),
            jnp.minimum(s.lambd * tr.lambda_factor, tr.lambda_max),
        ),
    )
    rel_cost = jnp.abs(actual) / jnp.maximum(s.lin.cost, jnp.finfo(x.dtype).tiny)
    conv_cost = useful & (rel_cost < term.cost_tolerance)
    conv_param = useful & (
        jnp.linalg.norm(s.delta) < term.parameter_tolerance * (jnp.linalg.norm(s.x) + term.parameter_tolerance)
    )
    conv_grad = lin.finite & (jnp.max(jnp.abs(lin.grad)) < term.gradient_tolerance)
    converged = conv_cost | conv_param | conv_grad
    nonfinite = s.first & ~lin_t.finite
    stalled = ~s.first & ~accept & (s.lambd >= tr.lambda_max)
    iteration = s.iteration + jnp.where(s.first, 0, 1).astype(jnp.int32)
    out_of_steps = iteration >= term.max_iterations
    result = LMResult.where(
        nonfinite,
        LMResult.nonfinite,
        LMResult.where(
            converged,
            LMResult.converged,
            LMResult.where(stalled, LMResult.stalled, LMResult.max_iterations),
        ),
    )
    done = nonfinite | converged | stalled | out_of_steps
    history = jnp.where(jnp.arange(s.history.shape[0]) == iteration, lin.cost, s.history)

    # Next trial: (J^T J + lambda S) delta = -J^T r. Its predicted decrease of sum r^2 is
    # -(2 g.delta + delta^T J^T J delta) = -g.delta + lambda delta^T S delta.
    S = _damping_diag(config, lin.bands)
    damped = _add_to_diagonal(lin.bands, lambd * S)
    delta = banded_solve(damped, -lin.grad)
    predicted = -jnp.sum(lin.grad * delta) + lambd * jnp.sum(S * delta**2)
    x_trial = problem._retract(x, delta)
    return _State(
        x=x,
        lin=lin,
        x_trial=x_trial,
        delta=delta,
        predicted=predicted,
        lambd=lambd,
        iteration=iteration,
        accepted=s.accepted + (accept & ~s.first).astype(jnp.int32),
        first=jnp.array(False),
        done=done,
        result=result,
        history=history,
    )


def _solve_impl(problem: BandedProblem, x0: Array, data: tuple, params: Any, config: SolverConfig) -> LMSolution:
    term = config.termination
    T, P = x0.shape
    D = problem._tangent_dim(P)
    lin_shape = jax.eval_shape(lambda: _linearise(problem, x0, data, params))
    lin0 = jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), lin_shape)
    s0 = _State(
        x=x0,
        lin=lin0,
        x_trial=x0,
        delta=jnp.zeros((T, D), x0.dtype),
        predicted=jnp.ones((), x0.dtype),
        lambd=jnp.broadcast_to(config.trust_region.lambda_initial, ()).astype(x0.dtype),
        iteration=jnp.zeros((), jnp.int32),
        accepted=jnp.zeros((), jnp.int32),
        first=jnp.array(True),
        done=jnp.array(False),
        result=LMResult.max_iterations,
        history=jnp.zeros((term.max_iterations + 1,), x0.dtype),
    )
    step = lambda s: _lm_pass(problem, data, params, config, s)  # noqa: E731

    if config.loop == "while":
        s = jax.lax.while_loop(lambda s: ~s.done, step, s0)
    elif config.loop == "scan":

        def body(s, _):
            return jax.lax.cond(s.done, lambda s: s, step, s), None

        s, _ = jax.lax.scan(body, s0, None, length=term.max_iterations + 1)
    else:
        raise ValueError(f"SolverConfig.loop must be 'while' or 'scan', got {config.loop!r}")

    idx = jnp.arange(term.max_iterations + 1)
    history = jnp.where(idx <= s.iteration, s.history, s.lin.cost)
    sol = LMSolution(
        x=s.x,
        cost=s.lin.cost,
        result=s.result,
        iterations=s.iteration,
        accepted_steps=s.accepted,
        cost_history=history,
        gradient_max=jnp.max(jnp.abs(s.lin.grad)),
        lambd=s.lambd,
    )
    if config.throw:
        sol = eqx.tree_at(lambda z: z.x, sol, sol.result.error_if(sol.x, sol.result != LMResult.converged))
    return sol


# Implicit differentiation: at a stationary point g(x*, theta) = 0 (g = tangent gradient of
# 0.5 cost), dx*/dtheta = -H^{-1} dg/dtheta with H the exact, block-banded Hessian. The backward
# pass solves H v = xbar once (band Cholesky) and pulls -v back through g's theta dependence.
@eqx.filter_custom_vjp
def _solve_implicit(diff_args, problem, x0, config):
    data, params = diff_args
    return _solve_impl(problem, x0, data, params, config)


@_solve_implicit.def_fwd
def _solve_implicit_fwd(perturbed, diff_args, problem, x0, config):
    del perturbed
    data, params = diff_args
    sol = _solve_impl(problem, x0, data, params, config)
    return sol, sol.x


@_solve_implicit.def_bwd
def _solve_implicit_bwd(x_star, grad_obj, perturbed, diff_args, problem, x0, config):
    del perturbed, x0, config
    data, params = diff_args
    T, P = x_star.shape
    D = problem._tangent_dim(P)
    xbar = grad_obj.x
    if xbar is None:
        xbar = jnp.zeros_like(x_star)
    # Ambient cotangent -> tangent cotangent through the retraction at zero.
    _, retract_vjp = jax.vjp(lambda delta: problem._retract(x_star, delta), jnp.zeros((T, D), x_star.dtype))
    (delta_bar,) = retract_vjp(xbar)
    H = _hessian_bands(problem, x_star, data, params)
    v = banded_cholesky_solve(banded_cholesky(H), delta_bar)

    def g_of_theta(theta):
        d, p = theta
        return _tangent_grad(problem, x_star, d, p)

    _, g_vjp = jax.vjp(g_of_theta, (data, params))
    (theta_bar,) = g_vjp(-v)
    return theta_bar


@eqx.filter_jit
def _solve_jit(problem: BandedProblem, x0: Array, data: tuple, params: Any, config: SolverConfig) -> LMSolution:
    if config.implicit_diff:
        return _solve_implicit((data, params), problem, x0, config)
    return _solve_impl(problem, x0, data, params, config)


def solve_lm(
    problem: BandedProblem,
    x0: Float[Array, "T P"],
    data: tuple[PyTree, ...] | None = None,
    params: PyTree = None,
    config: SolverConfig = SolverConfig(),
) -> LMSolution:
    """Minimise ``sum ||r||^2`` of a block-banded problem with Levenberg–Marquardt.

    Jitted (compiles once per problem instance, shapes and static config fields); vmap it over
    candidate problems, e.g. ``jax.vmap(lambda x0, d: solve_lm(prob, x0, d, params, cfg))``.

    Args:
        problem: residual groups and optional manifold retraction.
        x0: initial keyframe values, shape (T, P).
        data: tuple aligned with ``problem.costs``; entry i is a pytree whose leaves have leading
            axis ``T - costs[i].bandwidth`` (sliced per term), or None.
        params: pytree shared by all terms (weights, robot model, ...), not sliced.
        config: damping, termination and loop options.

    Returns:
        :class:`LMSolution` with the solution, final cost, ``result`` enum, iteration count and
        cost history. ``jax.grad`` through ``solution.x`` with respect to floating ``data`` and
        ``params`` leaves uses the implicit function theorem (valid at a converged strict local
        minimum); ``x0`` gets no gradient.
    """
    if jnp.ndim(x0) != 2:
        raise ValueError(f"x0 must have shape (T, P), got {jnp.shape(x0)}")
    if not jnp.issubdtype(jnp.result_type(x0), jnp.floating):
        raise ValueError(f"x0 must be floating point, got dtype {jnp.result_type(x0)}")
    data = _normalise_data(problem, jnp.shape(x0)[0], data)
    return _solve_jit(problem, jnp.asarray(x0), data, params, config)
