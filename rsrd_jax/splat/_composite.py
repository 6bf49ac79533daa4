"""Front-to-back alpha compositing of fixed-capacity per-tile Gaussian lists, with a hand-written VJP.

Layout: `[tiles, pixels-per-tile, K]` with the list axis K minor, so that
- σ is evaluated in tile-centred pixel coordinates (small numbers, little float32 cancellation);
- the cumulative sum of log(1 − α) along K is a blocked triangular matmul (XLA's CPU cumsum is slow);
- channels are one batched GEMM `w[t, p, k] · feat[t, k, c]`, and so are their transposes.

Forward (gsplat's rules): α = min(MAX_ALPHA, o·e^(−σ)); a pair is kept if σ ≥ 0 and
α ≥ ALPHA_THRESHOLD; L_k = Σ_{j≤k, kept} log(1 − α_j); the pair is *used* if kept and
L_k > log(TRANSMITTANCE_THRESHOLD) (inclusive transmittance only falls, so this reproduces the
exclusive stop); weight w_k = used·α_k·exp(L_k − l_k); out = Σ_k w_k·feat_k.

Backward (the analytic form of gsplat's replay, in vectorised form): with g_k = ⟨dout, feat_k⟩ and
S_k = Σ_{j>k} w_j g_j, dα_k = used·(T_k g_k − S_k / (1 − α_k)); dσ = −α·dα where α is not capped;
dfeat = wᵀ·dout. The reductions over pixels are GEMMs against the basis [1, u, v, u², uv, v²].
Masks (kept, used, capped) carry no gradient, as in gsplat.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp

from ._project import ALPHA_THRESHOLD, MAX_ALPHA, TRANSMITTANCE_THRESHOLD

_LOG_T_STOP = math.log(TRANSMITTANCE_THRESHOLD)


def pixel_offsets(tile_size: int, dtype) -> tuple[jax.Array, jax.Array]:
    """Tile-centred coordinates (u, v) of the pixel centres of a tile, row-major, shape (P,)."""
    r = jnp.arange(tile_size, dtype=dtype) + 0.5 - 0.5 * tile_size
    v, u = jnp.meshgrid(r, r, indexing="ij")
    return u.reshape(-1), v.reshape(-1)


def _block_size(k: int) -> int:
    for b in (32, 16, 8):
        if k % b == 0:
            return b
    return k


def blocked_cumsum(x: jax.Array, reverse: bool = False) -> jax.Array:
    """Inclusive cumulative sum along the last axis as a blocked triangular matmul."""
    *lead, k = x.shape
    b = _block_size(k)
    nb = k // b
    xb = x.reshape(*lead, nb, b)
    idx = jnp.arange(b)
    # within[i] = Σ_j xb[j]·tri[j, i]; forward: j ≤ i, reverse: j ≥ i.
    tri = (idx[:, None] >= idx[None, :]) if reverse else (idx[:, None] <= idx[None, :])
    within = xb @ tri.astype(x.dtype)
    if nb > 1:
        jb = jnp.arange(nb)
        strict = (jb[:, None] > jb[None, :]) if reverse else (jb[:, None] < jb[None, :])
        carry = jnp.sum(xb, axis=-1) @ strict.astype(x.dtype)
        within = within + carry[..., None]
    return within.reshape(*lead, k)


def _alpha(params: jax.Array, tile_size: int):
    """α (capped), kept mask, capped mask for every (tile, pixel, entry)."""
    u, v = pixel_offsets(tile_size, params.dtype)
    m, n, a, b, c, o = (params[:, None, :, i] for i in range(6))
    dx = m - u[None, :, None]
    dy = n - v[None, :, None]
    sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
    raw = o * jnp.exp(-sigma)
    capped = raw > MAX_ALPHA
    alpha = jnp.minimum(raw, MAX_ALPHA)
    keep = (sigma >= 0) & (alpha >= ALPHA_THRESHOLD)
    return alpha, keep, capped


def _forward(params, feat, tile_size):
    alpha, keep, capped = _alpha(params, tile_size)
    l = jnp.where(keep, jnp.log1p(-alpha), 0.0)
    L = blocked_cumsum(l)
    used = keep & (L > _LOG_T_STOP)
    w = jnp.where(used, alpha * jnp.exp(L - l), 0.0)
    out = jnp.einsum("tpk,tkc->tpc", w, feat)
    # A tile whose every pixel hit the transmittance stop cannot be changed by dropped entries.
    saturated = jnp.all(L[..., -1] <= _LOG_T_STOP, axis=-1)
    # Signed α of used pairs: negative where capped (no σ/opacity gradient there).
    alpha_s = jnp.where(used, jnp.where(capped, -alpha, alpha), 0.0)
    return out, saturated, (L - l, used), (w, alpha_s)


@functools.partial(jax.custom_vjp, nondiff_argnums=(2,))
def composite(params: jax.Array, feat: jax.Array, tile_size: int):
    """Composites per-tile lists.

    Args:
        params: (tiles, K, 6) per entry: mean offset from the tile centre (m, n) in pixels, conic
            (a, b, c) in 1/px², opacity o (0 marks an empty slot). Entries sorted near to far.
        feat: (tiles, K, C) channels to composite.
        tile_size: tile side in pixels (P = tile_size²).

    Returns:
        (out (tiles, P, C), saturated (tiles,) bool): Σ w·feat per pixel, and whether every pixel
        of the tile reached the transmittance stop within the list.
    """
    out, saturated, _, _ = _forward(params, feat, tile_size)
    return out, saturated


def composite_stats(params: jax.Array, feat: jax.Array, tile_size: int):
    """Counts without gradient: contributing entries per pixel (tiles, P), and entries each pixel
    walks before its stop (tiles, P), for capacity choice and benchmarks."""
    _, _, (L_excl, used), _ = _forward(params, feat, tile_size)
    n_used = jnp.sum(used, axis=-1)
    n_walked = jnp.sum(L_excl > _LOG_T_STOP, axis=-1)
    return n_used, n_walked


def _composite_fwd(params, feat, tile_size):
    out, saturated, _, (w, alpha_s) = _forward(params, feat, tile_size)
    return (out, saturated), (params, feat, w, alpha_s)


def _composite_bwd(tile_size, res, cts):
    params, feat, w, alpha_s = res
    dout = cts[0]
    g = jnp.einsum("tpc,tkc->tpk", dout, feat)
    dfeat = jnp.einsum("tpk,tpc->tkc", w, dout)
    wg = w * g
    S = blocked_cumsum(wg, reverse=True) - wg  # Σ_{j>k} w_j g_j
    alpha = jnp.abs(alpha_s)
    used = alpha_s != 0
    safe_a = jnp.where(used, alpha, 0.5)
    dalpha = jnp.where(used, (w / safe_a) * g - S / (1.0 - safe_a), 0.0)
    dsigma = jnp.where(alpha_s > 0, -alpha * dalpha, 0.0)
    u, v = pixel_offsets(tile_size, params.dtype)
    basis = jnp.stack([jnp.ones_like(u), u, v, u * u, u * v, v * v], axis=-1)  # (P, 6)
    Q = jnp.einsum("tpk,pj->tkj", dsigma, basis)
    q0, q1, q2, q3, q4, q5 = (Q[..., i] for i in range(6))
    m, n, a, b, c, o = (params[..., i] for i in range(6))
    sx = m * q0 - q1
    sy = n * q0 - q2
    sxx = m * m * q0 - 2.0 * m * q1 + q3
    sxy = m * n * q0 - m * q2 - n * q1 + q4
    syy = n * n * q0 - 2.0 * n * q2 + q5
    do = jnp.where(o > 0, -q0 / jnp.where(o > 0, o, 1.0), 0.0)
    dparams = jnp.stack([a * sx + b * sy, b * sx + c * sy, 0.5 * sxx, sxy, 0.5 * syy, do], -1)
    return dparams, dfeat


composite.defvjp(_composite_fwd, _composite_bwd)
