"""Front-to-back alpha compositing of per-tile Gaussian lists cut into fixed-size chunks, with a
hand-written VJP.

Each tile's depth-sorted list is split into chunks of B entries; only non-empty chunks exist, so
the work follows the real per-tile counts (a dense `[tiles, K]` layout would pay the busiest tile's
count everywhere). Per chunk the layout is `[chunks, pixels-per-tile, B]` with the list axis minor:
- σ is a contraction of 6 per-entry coefficients with the pixel basis [1, u, v, u², uv, v²] in
  tile-centred coordinates (small numbers, little float32 cancellation), with −log(o) folded into
  the constant term so that α = min(MAX_ALPHA, e^(−σ'));
- the cumulative sum of log(1 − α) along a chunk is a B×B triangular matmul, and the carry from
  earlier chunks of the same tile is a short static loop over chunk offsets;
- channels are one batched GEMM `w[c, p, k] · feat[c, k, :]`, summed per tile.

Forward (gsplat's rules): α = min(MAX_ALPHA, o·e^(−σ)); a pair is kept if α ≥ ALPHA_THRESHOLD;
L_k = Σ_{j≤k, kept} log(1 − α_j); the pair is *used* if kept and L_k > log(TRANSMITTANCE_THRESHOLD)
(inclusive transmittance only falls, so this reproduces gsplat's exclusive stop);
w_k = used·α_k·exp(L_k − l_k); out = Σ_k w_k·feat_k. (gsplat also skips σ < 0, which only rounding
can produce for a positive-definite conic; here such a pair gets α = min(MAX_ALPHA, o).)

Backward (the analytic form of gsplat's replay, vectorised): with g_k = ⟨dout, feat_k⟩ and
S_k = Σ_{j>k} w_j g_j over the tile's list, dα_k = used·(T_k g_k − S_k / (1 − α_k)), so
dσ = −α·dα = α/(1 − α)·S_k − w_k g_k where α is not capped (0 where capped); dfeat = wᵀ·dout;
the 6 reductions over pixels against the basis are one unrolled sum. Masks (kept, used, capped)
carry no gradient, as in gsplat.

Memory matters for speed on CPU: XLA allocates one temporary arena per call, and glibc serves
arenas above 32 MiB with a fresh mmap each time, so every call then pays page faults on the
whole arena (≈ 10 ms at 10k Gaussians, 128², 34 channels). Hence the backward keeps only w and
the signed α (used ⇔ w > 0), stored once (`materialise`), and `composite_rows` takes the channels
as a table plus row ids so that the channel cotangent goes straight into table rows, computed as
an unrolled sum over pixels written with a unit window axis (a batched GEMM output needs an
extra (NC, B, C) layout copy before XLA's scatter). XLA CPU also runs reductions and small GEMMs
as single-threaded library calls, so short sums over pixels are written out as elementwise
fusions, which it splits across threads. `composite_rows` also composites depth and alpha apart
from the channel GEMM, which keeps its width as given (32 is much faster than 34).
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ._project import ALPHA_THRESHOLD, MAX_ALPHA, TRANSMITTANCE_THRESHOLD

_LOG_T_STOP = math.log(TRANSMITTANCE_THRESHOLD)
_EMPTY_SIGMA = 1e4  # σ' of an empty slot: e^(−1e4) == 0


class ChunkLayout(NamedTuple):
    """Where each chunk sits (all int32; produced by binning, no gradient)."""

    tile: jax.Array
    """(NC,) tile of each chunk (any valid tile for unused chunks)."""
    index: jax.Array
    """(NC,) position of the chunk in its tile's list (0 = nearest)."""
    count: jax.Array
    """(NC,) number of chunks of that tile (0 for unused chunks)."""
    last: jax.Array
    """(tiles,) index of each tile's last chunk (−1 if the tile has none)."""


def pixel_basis(tile_size: int, dtype) -> jax.Array:
    """(P, 6) basis [1, u, v, u², uv, v²] at tile-centred pixel-centre coordinates, row-major."""
    r = jnp.arange(tile_size, dtype=dtype) + 0.5 - 0.5 * tile_size
    v, u = jnp.meshgrid(r, r, indexing="ij")
    u, v = u.reshape(-1), v.reshape(-1)
    return jnp.stack([jnp.ones_like(u), u, v, u * u, u * v, v * v], axis=-1)


_CARRY_UNROLL = 8
"""Steps of the chunk carry's loop per iteration (`lax.scan(unroll=)`)."""


def _chunk_carry(tot: jax.Array, layout: ChunkLayout, max_chunks_per_tile: int, reverse: bool):
    """Σ of `tot` over the earlier (or, reversed, later) chunks of the same tile, (NC, P).

    The chunk d places away is added for d = 1, 2, ... in turn (the summation order fixes the
    rounding, which the tracking's outcome is sensitive to), in a `lax.scan` over d: unrolled in
    Python the loop traced ~100 steps for a tile budget of 3328 entries (0.4–0.9 s of tracing
    per compiled solve)."""
    nc = tot.shape[0]
    kc = max_chunks_per_tile
    if kc <= 1:
        return jnp.zeros_like(tot)
    pad = jnp.zeros((kc, *tot.shape[1:]), tot.dtype)
    ext = jnp.concatenate([tot, pad]) if reverse else jnp.concatenate([pad, tot])

    def add(carry, d):
        src = jax.lax.dynamic_slice_in_dim(ext, d if reverse else kc - d, nc, 0)  # tot shifted by d, zeros beyond
        ok = (layout.index + d < layout.count) if reverse else (layout.index >= d)
        return carry + jnp.where(ok[:, None], src, 0.0), None

    steps = jnp.arange(1, kc, dtype=jnp.int32)
    return jax.lax.scan(add, jnp.zeros_like(tot), steps, unroll=min(_CARRY_UNROLL, kc - 1))[0]


def _sigma(params: jax.Array, tile_size: int) -> jax.Array:
    """σ' = σ − log o for every (chunk, pixel, entry) as one GEMM."""
    m, n, a, b, c, o = (params[..., i] for i in range(6))
    valid = o > 0
    logo = jnp.log(jnp.where(valid, o, 1.0))
    c0 = jnp.where(valid, 0.5 * a * m * m + b * m * n + 0.5 * c * n * n - logo, _EMPTY_SIGMA)
    coef = jnp.stack([c0, -(a * m + b * n), -(b * m + c * n), 0.5 * a, b, 0.5 * c], axis=-1)
    coef = jnp.where(valid[..., None], coef, jnp.asarray([_EMPTY_SIGMA, 0, 0, 0, 0, 0], coef.dtype))
    # A K=6 GEMM (measured faster than a fused broadcast-multiply-sum or a Horner form, which
    # also change XLA's fusion so that the backward keeps more forward intermediates alive).
    basis = pixel_basis(tile_size, params.dtype)
    return jnp.einsum("ckj,pj->cpk", coef, basis)


def _tri(b: int, reverse: bool, dtype) -> jax.Array:
    i = jnp.arange(b)
    return ((i[:, None] >= i[None, :]) if reverse else (i[:, None] <= i[None, :])).astype(dtype)


def _forward(params, feat, layout: ChunkLayout, n_tiles: int, tile_size: int, kc: int, z=None):
    b = params.shape[1]
    raw = jnp.exp(-_sigma(params, tile_size))
    alpha = jnp.minimum(raw, MAX_ALPHA)
    keep = alpha >= ALPHA_THRESHOLD
    l = jnp.where(keep, jnp.log(1.0 - alpha), 0.0)
    # Signed α of kept pairs (negative where capped).
    alpha_s = jnp.where(keep, jnp.where(raw > MAX_ALPHA, -alpha, alpha), 0.0)
    within = l @ _tri(b, False, l.dtype)
    L = within + _chunk_carry(within[..., -1], layout, kc, reverse=False)[..., None]
    used = (alpha_s != 0) & (L > _LOG_T_STOP)
    w = jnp.where(used, jnp.abs(alpha_s) * jnp.exp(L - l), 0.0)
    out_c = jnp.einsum("cpk,ckd->cpd", w, feat)
    out = jax.ops.segment_sum(out_c, layout.tile, n_tiles, indices_are_sorted=True)
    sat_c = jnp.all(L[..., -1] <= _LOG_T_STOP, axis=-1)
    saturated = jnp.where(layout.last >= 0, sat_c[jnp.maximum(layout.last, 0)], True)
    if z is not None:  # (Σ w·z, Σ w) apart from the channel GEMM
        zk = jnp.stack([z, jnp.ones_like(z)], -1)
        aux = jnp.einsum("cpk,ckj->cpj", w, zk)
        out = (out, jax.ops.segment_sum(aux, layout.tile, n_tiles, indices_are_sorted=True))
    return out, saturated, (L - l, used), (w, alpha_s)


def _backward(params, layout: ChunkLayout, w, alpha_s, g, tile_size: int, kc: int):
    """Gradient of the entry parameters (NC, B, 6) given g = ⟨dout, feat⟩ per (chunk, pixel,
    entry) and the residuals w and signed α."""
    b = params.shape[1]
    wg = w * g
    within = wg @ _tri(b, True, wg.dtype)
    S = within - wg + _chunk_carry(within[..., 0], layout, kc, reverse=True)[..., None]
    # dσ = −α·dα with dα = T·g − S/(1 − α) and α·T = w, where used (w > 0) and α is not capped.
    a = jnp.abs(alpha_s)
    r = jnp.where(alpha_s > 0, a / (1.0 - a), 0.0)
    dsigma = jnp.where((w > 0) & (alpha_s > 0), r * S - wg, 0.0)
    basis = pixel_basis(tile_size, params.dtype)
    # The 6 reductions over pixels against the basis as one unrolled sum (an elementwise fusion
    # split across threads; reductions go to single-threaded calls on XLA CPU).
    dsigma = materialise(dsigma)
    q = sum(dsigma[:, p, :, None] * basis[p] for p in range(basis.shape[0]))
    q0, q1, q2, q3, q4, q5 = (q[..., j] for j in range(6))
    m, n, a_, bb, c, o = (params[..., i] for i in range(6))
    sx = m * q0 - q1
    sy = n * q0 - q2
    sxx = m * m * q0 - 2.0 * m * q1 + q3
    sxy = m * n * q0 - m * q2 - n * q1 + q4
    syy = n * n * q0 - 2.0 * n * q2 + q5
    do = jnp.where(o > 0, -q0 / jnp.where(o > 0, o, 1.0), 0.0)
    return jnp.stack([a_ * sx + bb * sy, bb * sx + c * sy, 0.5 * sxx, sxy, 0.5 * syy, do], -1)


def _zero_layout(layout):
    return jax.tree.map(lambda x: np.zeros(x.shape, jax.dtypes.float0), layout)


@functools.partial(jax.custom_vjp, nondiff_argnums=(3, 4, 5))
def composite(
    params: jax.Array,
    feat: jax.Array,
    layout: ChunkLayout,
    n_tiles: int,
    tile_size: int,
    max_chunks_per_tile: int,
):
    """Composites chunked per-tile lists.

    Args:
        params: (NC, B, 6) per entry: mean offset from its tile's centre (m, n) in pixels, conic
            (a, b, c) in 1/px², opacity o (0 marks an empty slot). Chunks of a tile are
            consecutive and ordered near to far, as are the entries inside a chunk.
        feat: (NC, B, C) channels to composite.
        layout: chunk → tile bookkeeping (`ChunkLayout`).
        n_tiles: number of tiles T; tile_size: tile side (P = tile_size²);
        max_chunks_per_tile: static bound on chunks per tile.

    Returns:
        (out (T, P, C), saturated (T,) bool): Σ w·feat per pixel, and whether every pixel of the
        tile reached the transmittance stop within its list (dropped entries cannot matter).
    """
    out, saturated, _, _ = _forward(params, feat, layout, n_tiles, tile_size, max_chunks_per_tile)
    return out, saturated


def composite_stats(params, feat, layout, n_tiles, tile_size, max_chunks_per_tile):
    """No-gradient counts: contributing entries per pixel (T, P) and list entries each tile's
    pixels walk before their stop (T,), for capacity choice and benchmarks."""
    _, _, (L_excl, used), _ = _forward(params, feat, layout, n_tiles, tile_size, max_chunks_per_tile)
    n_used = jax.ops.segment_sum(jnp.sum(used, -1), layout.tile, n_tiles, indices_are_sorted=True)
    walked_c = jnp.sum(L_excl > _LOG_T_STOP, axis=-1)  # (NC, P)
    walked = jax.ops.segment_sum(walked_c, layout.tile, n_tiles, indices_are_sorted=True)
    return n_used, jnp.max(walked, axis=-1)


def _composite_fwd(params, feat, layout, n_tiles, tile_size, kc):
    out, saturated, _, (w, alpha_s) = _forward(params, feat, layout, n_tiles, tile_size, kc)
    return (out, saturated), (params, feat, layout, w, alpha_s)


def _composite_bwd(n_tiles, tile_size, kc, res, cts):
    params, feat, layout, w, alpha_s = res
    dout = cts[0][layout.tile]  # (NC, P, C)
    g = jnp.einsum("cpd,ckd->cpk", dout, feat)
    dparams = _backward(params, layout, w, alpha_s, g, tile_size, kc)
    dfeat = jnp.einsum("cpk,cpd->ckd", w, dout)
    return dparams, dfeat, _zero_layout(layout)


composite.defvjp(_composite_fwd, _composite_bwd)


@functools.partial(jax.custom_vjp, nondiff_argnums=(5, 6, 7))
def composite_rows(
    params: jax.Array,
    table: jax.Array,
    depth: jax.Array,
    ids: jax.Array,
    layout: ChunkLayout,
    n_tiles: int,
    tile_size: int,
    max_chunks_per_tile: int,
):
    """`composite` with the channels given as a table (R, C) and entry row ids (NC, B), and
    depth and alpha composited apart from the channel GEMM (whose width then stays as given).

    Args:
        params, layout, n_tiles, tile_size, max_chunks_per_tile: as in `composite`.
        table: (R, C) channels per row; feat = table[ids].
        depth: (R,) camera depth per row.
        ids: (NC, B) row of every entry.

    Returns:
        (out (T, P, C), aux (T, P, 2) = (Σ w·depth, Σ w), saturated (T,)). The backward
        accumulates the channel gradient straight into table rows (less memory than gathering
        outside and scattering the (NC, B, C) cotangent).
    """
    (out, aux), saturated, _, _ = _forward(
        params, table[ids], layout, n_tiles, tile_size, max_chunks_per_tile, depth[ids]
    )
    return out, aux, saturated


def materialise(xs):
    """Identity that XLA cannot see through (CPU only): the values leave a conditional whose
    (always true) predicate is only known at run time, so they are computed once and stored.
    Later consumers then can neither re-derive them from (and so keep alive) the intermediates
    they came from, nor recompute them inside every element of a gather. Elsewhere a
    device-side predicate would cost a host sync, and fusion is left to the compiler."""
    if jax.default_backend() != "cpu":
        return xs
    return _materialise_cpu(xs)


@jax.custom_jvp
def _materialise_cpu(xs):
    return _materialise_cond(xs)


@_materialise_cpu.defjvp
def _materialise_jvp(primals, tangents):
    return _materialise_cpu(primals[0]), tangents[0]


@jax.custom_batching.custom_vmap
def _materialise_cond(xs):
    v = jax.tree.leaves(xs)[0].reshape(-1)[0]
    pred = jnp.isnan(v) | ~jnp.isnan(v)
    return jax.lax.cond(pred, lambda x: x, lambda x: jax.tree.map(jnp.zeros_like, x), xs)


@_materialise_cond.def_vmap
def _materialise_batched(axis_size, in_batched, xs):
    # Under vmap a predicate computed from batched values would be batched too, and the cond
    # would become a select that XLA sees through; applied to the whole batch it stays a cond.
    return _materialise_cond(xs), in_batched[0]


def _rows_fwd(params, table, depth, ids, layout, n_tiles, tile_size, kc):
    (out, aux), saturated, _, (w, alpha_s) = _forward(
        params, table[ids], layout, n_tiles, tile_size, kc, depth[ids]
    )
    # Stored once: keeps the backward's temporaries under the 32 MiB glibc serves from its heap.
    w, alpha_s = materialise((w, alpha_s))
    return (out, aux, saturated), (params, table, depth, ids, layout, w, alpha_s)


def _rows_bwd(n_tiles, tile_size, kc, res, cts):
    params, table, depth, ids, layout, w, alpha_s = res
    dout = cts[0][layout.tile]  # (NC, P, C)
    daux = cts[1][layout.tile]  # (NC, P, 2)
    z = depth[ids]
    g = jnp.einsum("cpd,ckd->cpk", dout, table[ids])
    g = g + daux[..., 0:1] * z[:, None, :] + daux[..., 1:2]
    dparams = _backward(params, layout, w, alpha_s, g, tile_size, kc)
    # Channel gradient per entry as an unrolled sum over pixels (one elementwise fusion, split
    # across threads; a reduction goes to a slower single-threaded call), written with a unit
    # window axis so that the scatter into table rows needs no layout copy of it.
    P = dout.shape[1]
    dfeat = sum(w[:, p, :, None, None] * dout[:, p, None, None, :] for p in range(P))
    dn = jax.lax.ScatterDimensionNumbers(
        update_window_dims=(2, 3), inserted_window_dims=(), scatter_dims_to_operand_dims=(0,)
    )
    dtable = jax.lax.scatter_add(jnp.zeros_like(table), ids[..., None], dfeat, dn)
    dz = sum(w[:, p, :] * daux[:, p, 0:1] for p in range(P))
    ddepth = jnp.zeros_like(depth).at[ids].add(dz)
    return dparams, dtable, ddepth, np.zeros(ids.shape, jax.dtypes.float0), _zero_layout(layout)


composite_rows.defvjp(_rows_fwd, _rows_bwd)
