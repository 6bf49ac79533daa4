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


def _tri_inverse(L: Array) -> Array:
    return solve_triangular(L, jnp.eye(L.shape[-1], dtype=L.dtype), lower=True)


# Each diagonal factor L[t,t] is inverted once (a D x D triangular solve); every other block
# operation is then a matmul, which runs about twice as fast on CPU as per-block triangular solves
# and batches better under vmap.


def _factor_forward(
    bands: Float[Array, "T B1 D D"], rhs: Float[Array, "T D"]
) -> tuple[Float[Array, "T B1 D D"], Float[Array, "T D D"], Float[Array, "T D"]]:
    """Band Cholesky factor L (layout of ``bands``), inverses of its diagonal blocks, and
    y = L^{-1} rhs, in one scan over block rows."""
    T, B1, D, _ = bands.shape
    B = B1 - 1
    if B == 0:
        L0 = jnp.linalg.cholesky(bands[:, 0])
        Linv = jax.vmap(_tri_inverse)(L0)
        return L0[:, None], Linv, jnp.einsum("tij,tj->ti", Linv, rhs)

    # Fictitious rows before t = 0 have identity diagonal blocks, so the (zero) couplings of the
    # first B rows to them solve to zero instead of dividing by zero.
    eye = jnp.eye(D, dtype=bands.dtype)
    L_prev0 = jnp.zeros((B, B1, D, D), bands.dtype).at[:, 0].set(eye)
    Linv_prev0 = jnp.broadcast_to(eye, (B, D, D))
    y_prev0 = jnp.zeros((B, D), bands.dtype)

    def step(carry, inputs):
        L_prev, Linv_prev, y_prev = carry  # rows t-B..t-1 (index B-1 is row t-1)
        a_row, b_t = inputs
        row = [None] * B1
        # Off-diagonal blocks, leftmost column first: L[t,c] = (A[t,c] - sum L[t,m] L[c,m]^T) L[c,c]^-T
        for k in range(B, 0, -1):
            prev_c = L_prev[B - k]  # row c = t - k
            s = a_row[k]
            for m in range(k + 1, B1):
                s = s - row[m] @ prev_c[m - k].T
            row[k] = s @ Linv_prev[B - k].T
        d = a_row[0]
        v = b_t
        for k in range(1, B1):
            d = d - row[k] @ row[k].T
            v = v - row[k] @ y_prev[B - k]
        row[0] = jnp.linalg.cholesky(d)
        Linv_t = _tri_inverse(row[0])
        y_t = Linv_t @ v
        L_row = jnp.stack(row)
        shift = lambda buf, new: jnp.concatenate([buf[1:], new[None]], axis=0)  # noqa: E731
        return (shift(L_prev, L_row), shift(Linv_prev, Linv_t), shift(y_prev, y_t)), (L_row, Linv_t, y_t)

    _, (L, Linv, y) = jax.lax.scan(step, (L_prev0, Linv_prev0, y_prev0), (bands, rhs))
    return L, Linv, y


def _backward(
    L: Float[Array, "T B1 D D"], Linv: Float[Array, "T D D"], y: Float[Array, "T D"]
) -> Float[Array, "T D"]:
    """Solve L^T x = y for a band Cholesky factor L (with its inverted diagonal blocks)."""
    T, B1, D, _ = L.shape
    B = B1 - 1
    if B == 0:
        return jnp.einsum("tji,tj->ti", Linv, y)
    # below[t, k-1] = L[t+k, t] (zero past the end): the blocks of column t under the diagonal.
    below = jnp.stack(
        [jnp.concatenate([L[k:, k], jnp.zeros((k, D, D), L.dtype)], axis=0) for k in range(1, B1)],
        axis=1,
    )

    def step(x_next, inputs):  # x_next[k-1] = x_{t+k}
        Linv_t, y_t, below_t = inputs
        v = y_t - jnp.einsum("kij,ki->j", below_t, x_next)
        x_t = Linv_t.T @ v
        return jnp.concatenate([x_t[None], x_next[:-1]], axis=0), x_t

    _, x = jax.lax.scan(step, jnp.zeros((B, D), L.dtype), (Linv, y, below), reverse=True)
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
    Linv = jax.vmap(_tri_inverse)(L[:, 0])
    if B == 0:
        y = jnp.einsum("tij,tj->ti", Linv, rhs)
    else:

        def fwd(y_prev, inputs):
            L_row, Linv_t, b_t = inputs
            v = b_t - jnp.einsum("kij,kj->i", L_row[:0:-1], y_prev)
            y_t = Linv_t @ v
            return jnp.concatenate([y_prev[1:], y_t[None]], axis=0), y_t

        _, y = jax.lax.scan(fwd, jnp.zeros((B, D), L.dtype), (L, Linv, rhs))
    return _backward(L, Linv, y)


def banded_solve(bands: Float[Array, "T B1 D D"], rhs: Float[Array, "T D"]) -> Float[Array, "T D"]:
    """Exact solve of ``A x = rhs`` for symmetric positive-definite block-banded ``A``.

    Args:
        bands: lower bands ``bands[t, k] = A[t, t-k]``, shape (T, B+1, D, D).
        rhs: right-hand side, shape (T, D).

    Returns:
        x, shape (T, D); NaN where ``A`` is not positive definite.
    """
    L, Linv, y = _factor_forward(bands, rhs)
    return _backward(L, Linv, y)


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
