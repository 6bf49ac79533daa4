"""Symmetric positive-definite block-banded linear algebra.

A symmetric matrix ``A`` with ``T x T`` blocks of size ``D x D`` whose blocks vanish more than
``B`` block-diagonals away from the main one is stored by its lower bands:

    bands[t, k] = A[t, t - k]          for k = 0..B   (zero where t - k < 0)

so ``bands`` has shape ``(T, B + 1, D, D)``. Its Cholesky factor ``A = L L^T`` has the same lower
band structure (no fill-in outside the band), which makes an exact solve cost O(T B^2 D^3) instead
of O(T^3 D^3). The factorisation and the forward substitution run in one ``lax.scan`` over block
rows, the back substitution in a second, reversed one (block version of Golub & Van Loan,
*Matrix Computations*, 4th ed., Alg. 4.3.5 "band Cholesky").
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.scipy.linalg import solve_triangular
from jaxtyping import Array, Float


def _tri_lower(L: Array, b: Array) -> Array:
    return solve_triangular(L, b, lower=True)


def _factor_forward(
    bands: Float[Array, "T B1 D D"], rhs: Float[Array, "T D"]
) -> tuple[Float[Array, "T B1 D D"], Float[Array, "T D"]]:
    """Band Cholesky factor L (same layout as ``bands``) and y = L^{-1} rhs, in one scan."""
    T, B1, D, _ = bands.shape
    B = B1 - 1
    eye = jnp.eye(D, dtype=bands.dtype)
    if B == 0:
        L0 = jnp.linalg.cholesky(bands[:, 0])
        y = jax.vmap(_tri_lower)(L0, rhs[..., None])[..., 0]
        return L0[:, None], y

    # Fictitious rows before t = 0 have identity diagonal blocks, so the (zero) couplings of the
    # first B rows to them solve to zero instead of dividing by zero.
    L_prev0 = jnp.zeros((B, B1, D, D), bands.dtype).at[:, 0].set(eye)
    y_prev0 = jnp.zeros((B, D), bands.dtype)

    def step(carry, inputs):
        L_prev, y_prev = carry  # rows t-B..t-1 (index B-1 is row t-1)
        a_row, b_t = inputs
        row = [None] * B1
        # Off-diagonal blocks, leftmost column first: L[t,c] = (A[t,c] - sum L[t,m] L[c,m]^T) L[c,c]^-T
        for k in range(B, 0, -1):
            prev_c = L_prev[B - k]  # row c = t - k
            s = a_row[k]
            for m in range(k + 1, B1):
                s = s - row[m] @ prev_c[m - k].T
            row[k] = _tri_lower(prev_c[0], s.T).T
        d = a_row[0]
        for k in range(1, B1):
            d = d - row[k] @ row[k].T
        row[0] = jnp.linalg.cholesky(d)
        v = b_t
        for k in range(1, B1):
            v = v - row[k] @ y_prev[B - k]
        y_t = _tri_lower(row[0], v[:, None])[:, 0]
        L_row = jnp.stack(row)
        L_prev = jnp.concatenate([L_prev[1:], L_row[None]], axis=0)
        y_prev = jnp.concatenate([y_prev[1:], y_t[None]], axis=0)
        return (L_prev, y_prev), (L_row, y_t)

    _, (L, y) = jax.lax.scan(step, (L_prev0, y_prev0), (bands, rhs))
    return L, y


def _backward(L: Float[Array, "T B1 D D"], y: Float[Array, "T D"]) -> Float[Array, "T D"]:
    """Solve L^T x = y for a band Cholesky factor L."""
    T, B1, D, _ = L.shape
    B = B1 - 1
    if B == 0:
        solve_t = lambda Lt, yt: solve_triangular(Lt, yt, lower=True, trans="T")  # noqa: E731
        return jax.vmap(solve_t)(L[:, 0], y)
    # below[t, k-1] = L[t+k, t] (zero past the end): the blocks of column t under the diagonal.
    below = jnp.stack(
        [jnp.concatenate([L[k:, k], jnp.zeros((k, D, D), L.dtype)], axis=0) for k in range(1, B1)],
        axis=1,
    )

    def step(x_next, inputs):  # x_next[k-1] = x_{t+k}
        L_tt, y_t, below_t = inputs
        v = y_t - jnp.einsum("kij,ki->j", below_t, x_next)
        x_t = solve_triangular(L_tt, v, lower=True, trans="T")
        return jnp.concatenate([x_t[None], x_next[:-1]], axis=0), x_t

    _, x = jax.lax.scan(step, jnp.zeros((B, D), L.dtype), (L[:, 0], y, below), reverse=True)
    return x


def banded_cholesky(bands: Float[Array, "T B1 D D"]) -> Float[Array, "T B1 D D"]:
    """Block-banded Cholesky factor.

    Args:
        bands: lower bands of a symmetric positive-definite block-banded matrix,
            ``bands[t, k] = A[t, t-k]`` (blocks with ``t - k < 0`` are ignored and should be 0).

    Returns:
        The lower bands of ``L`` with ``A = L L^T``, same layout. Not positive definite -> NaN.
    """
    return _factor_forward(bands, jnp.zeros(bands.shape[:1] + bands.shape[-1:], bands.dtype))[0]


def banded_cholesky_solve(L: Float[Array, "T B1 D D"], rhs: Float[Array, "T D"]) -> Float[Array, "T D"]:
    """Solve ``A x = rhs`` given the band Cholesky factor ``L`` of ``A``."""
    T, B1, D, _ = L.shape
    B = B1 - 1
    if B == 0:
        y = jax.vmap(_tri_lower)(L[:, 0], rhs[..., None])[..., 0]
    else:

        def fwd(y_prev, inputs):
            L_row, b_t = inputs
            v = b_t - jnp.einsum("kij,kj->i", L_row[:0:-1], y_prev)
            y_t = _tri_lower(L_row[0], v[:, None])[:, 0]
            return jnp.concatenate([y_prev[1:], y_t[None]], axis=0), y_t

        _, y = jax.lax.scan(fwd, jnp.zeros((B, D), L.dtype), (L, rhs))
    return _backward(L, y)


def banded_solve(bands: Float[Array, "T B1 D D"], rhs: Float[Array, "T D"]) -> Float[Array, "T D"]:
    """Exact solve of ``A x = rhs`` for symmetric positive-definite block-banded ``A``.

    Args:
        bands: lower bands ``bands[t, k] = A[t, t-k]``, shape (T, B+1, D, D).
        rhs: right-hand side, shape (T, D).

    Returns:
        x, shape (T, D); NaN where ``A`` is not positive definite.
    """
    L, y = _factor_forward(bands, rhs)
    return _backward(L, y)


def banded_matvec(bands: Float[Array, "T B1 D D"], x: Float[Array, "T D"]) -> Float[Array, "T D"]:
    """``A @ x`` for a symmetric block-banded ``A`` given by its lower bands."""
    T, B1, D, _ = bands.shape
    out = jnp.einsum("tij,tj->ti", bands[:, 0], x)
    for k in range(1, B1):
        # lower block A[t, t-k] x_{t-k} and its transpose A[t-k, t] x_t
        out = out.at[k:].add(jnp.einsum("tij,tj->ti", bands[k:, k], x[:-k]))
        out = out.at[:-k].add(jnp.einsum("tji,tj->ti", bands[k:, k], x[k:]))
    return out


def banded_to_dense(bands: Float[Array, "T B1 D D"]) -> Float[Array, "TD TD"]:
    """Dense symmetric ``(T*D, T*D)`` matrix from lower bands (for tests and small problems)."""
    T, B1, D, _ = bands.shape
    A = jnp.zeros((T, D, T, D), bands.dtype)
    t = jnp.arange(T)
    for k in range(B1):
        rows, cols = t[k:], t[k:] - k
        A = A.at[rows, :, cols, :].set(bands[k:, k])
        if k > 0:
            A = A.at[cols, :, rows, :].set(jnp.swapaxes(bands[k:, k], -1, -2))
    return A.reshape(T * D, T * D)
