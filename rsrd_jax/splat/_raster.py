"""Tile binning with static budgets, the `render` entry point and the host-side budget chooser.

Binning (no gradient): each visible Gaussian covers a box of tiles (opacity-aware extent); pairs
whose tile the α ≥ 1/255 ellipse misses are culled exactly. Gaussians are ordered by camera
depth (one int64 sort of `depth bits << 32 | index`), their (Gaussian, tile) pairs are expanded
into a static budget of `max_pairs` slots in that order, and integer sorts by `tile·M + slot`
(of two independent slot ranges, which XLA runs concurrently) group them per tile, near to far.
Each tile keeps its nearest `capacity` entries, cut into chunks of `chunk_size`; chunks of all
tiles share a static budget of `max_chunks`, so the work follows the real per-tile counts.
Nothing is dropped silently: entries beyond `capacity` are counted per tile (`tile_overflow`); a
tile whose dropped entries could have changed a pixel (some pixel had not reached the
transmittance stop) or that lost chunks to the chunk budget is flagged in `tile_truncated`;
excess pairs and chunks are counted in `pairs_overflow` and `chunks_overflow`.
"""

from __future__ import annotations

import math
from typing import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ..geometry import Camera
from ._composite import ChunkLayout, composite, composite_rows, composite_stats, materialise
from ._gaussians import Gaussians
from ._project import ALPHA_THRESHOLD, MAX_ALPHA, TRANSMITTANCE_THRESHOLD, Projected, project_gaussians

_SORT_PARTS = 2  # independent sorts of the pair keys (see `_sorted_pairs`)
_trace_count = 0  # incremented each time `render` is traced (tests check it stays put)


class RenderConfig(eqx.Module):
    """Static rasterizer options (all fields fix shapes or branches; changing one recompiles).

    Use `choose_config` to size `capacity`, `max_chunks` and `max_pairs` for a scene.
    """

    tile_size: int = eqx.field(static=True, default=4)
    """Tile side in pixels. Small tiles waste fewer pixel-Gaussian evaluations (gsplat uses 16 on
    GPUs); on CPU 4 measured about 2× faster than 8 for forward+backward."""
    chunk_size: int = eqx.field(static=True, default=32)
    """B: list entries per chunk; a tile's list is processed in ⌈count/B⌉ chunks."""
    capacity: int = eqx.field(static=True, default=256)
    """K: most entries (nearest Gaussians) kept per tile; a multiple of `chunk_size`."""
    max_chunks: int = eqx.field(static=True, default=2048)
    """Budget of chunks per image (Σ over tiles of ⌈min(count, K)/B⌉); chunks beyond it are
    dropped (their tiles are reported in `tile_truncated`, the excess in `chunks_overflow`)."""
    max_pairs: int = eqx.field(static=True, default=1 << 16)
    """Budget of (Gaussian, tile) pairs per image; the farthest pairs beyond it are dropped and
    counted in `RenderOutput.pairs_overflow`."""
    stats: bool = eqx.field(static=True, default=False)
    """Also return per-pixel contributor counts and per-tile needed capacity (slower)."""

    def __check_init__(self):
        ok = (
            self.tile_size >= 1
            and self.chunk_size >= 1
            and self.capacity >= self.chunk_size
            and self.capacity % self.chunk_size == 0
            and self.max_chunks >= 1
            and self.max_pairs >= 1
        )
        if not ok:
            raise ValueError(
                "RenderConfig needs positive sizes and capacity a multiple of chunk_size; got "
                f"tile_size={self.tile_size}, chunk_size={self.chunk_size}, "
                f"capacity={self.capacity}, max_chunks={self.max_chunks}, max_pairs={self.max_pairs}"
            )


class RenderOutput(eqx.Module):
    """Everything one render produces (image axes H×W; tile axes TY×TX)."""

    rgb: Float[Array, "h w 3"]
    """Composited colour plus (1 − alpha)·background."""
    features: Float[Array, "h w f"]
    """Composited features Σ w·f (no background, not divided by alpha)."""
    depth: Float[Array, "h w"]
    """Expected depth D / max(alpha, 1e-10), metres (gsplat "ED")."""
    depth_accum: Float[Array, "h w"]
    """Accumulated depth D = Σ w·z, metres (gsplat "D")."""
    alpha: Float[Array, "h w"]
    """Accumulated opacity 1 − T_final = Σ w."""
    tile_counts: Int[Array, "ty tx"]
    """Candidate Gaussians per tile (within the pair budget)."""
    tile_overflow: Int[Array, "ty tx"]
    """Candidates dropped per tile because a list holds at most `capacity` entries."""
    tile_truncated: Bool[Array, "ty tx"]
    """Tiles where dropped candidates or chunks could have contributed (render not exact)."""
    pairs_overflow: Int[Array, ""]
    """(Gaussian, tile) pairs dropped because they exceed `max_pairs`."""
    chunks_overflow: Int[Array, ""]
    """Chunks dropped because they exceed `max_chunks`."""
    n_contrib: Int[Array, "h w"] | None = None
    """With `stats`: Gaussians that contributed to each pixel."""
    tile_needed: Int[Array, "ty tx"] | None = None
    """With `stats`: list entries each tile needs for an exact render (walked before the stop)."""


def _grid(camera: Camera, tile_size: int) -> tuple[int, int]:
    return -(-camera.width // tile_size), -(-camera.height // tile_size)


def _depth_order(depth: jax.Array, visible: jax.Array) -> jax.Array:
    """Indices sorting Gaussians near to far (invisible last), via one int64 sort of
    (float32 depth bits << 32 | index): integer sorts are several times faster than key-value
    sorts on XLA CPU, and positive float bit patterns order like the floats."""
    n = depth.shape[0]
    with jax.enable_x64(True):
        bits = jax.lax.bitcast_convert_type(depth.astype(jnp.float32), jnp.int32)
        bits = jnp.where(visible, bits, jnp.iinfo(jnp.int32).max).astype(jnp.int64)
        key = (bits << 32) | jnp.arange(n, dtype=jnp.int64)
        order = (jnp.sort(key) & 0xFFFFFFFF).astype(jnp.int32)
    return order


def _expand(counts: jax.Array, size: int) -> tuple[jax.Array, jax.Array, jax.Array]:
    """For `size` slots laid out as consecutive runs of `counts[i]` slots per owner i: each
    slot's owner, its index within the run, and the run offsets."""
    off = jnp.cumsum(counts) - counts
    owner = jnp.arange(counts.shape[0], dtype=jnp.int32)
    marks = jnp.full((size,), -1, jnp.int32).at[off].max(jnp.where(counts > 0, owner, -1), mode="drop")
    who = jnp.maximum(jax.lax.cummax(marks), 0)
    return who, jnp.arange(size, dtype=jnp.int32) - off[who], off


class Bins(eqx.Module):
    """Result of `bin_gaussians` (integers, no gradient)."""

    ids: Int[Array, "nc b"]
    """Gaussian index of every chunk entry (N marks an empty slot)."""
    layout: ChunkLayout
    """Chunk → tile bookkeeping."""
    counts: Int[Array, " t"]
    """Candidates per tile (within the pair budget)."""
    lost_chunks: Bool[Array, " t"]
    """Tiles that lost chunks to the chunk budget."""
    total_pairs: Int[Array, ""]
    """All (Gaussian, tile) pairs (may exceed `max_pairs`)."""
    total_chunks: Int[Array, ""]
    """All chunks needed (may exceed `max_chunks`)."""


def _ellipse_meets_tile(proj: Projected, g, tx, ty, ts: int):
    """Whether any pixel centre of tile (tx, ty) has α ≥ ALPHA_THRESHOLD for Gaussian g, i.e.
    σ ≤ log(255·o) somewhere on the rectangle of pixel centres (gsplat's "AccuTile" idea with
    the exact per-Gaussian threshold). The minimum of the convex σ over the rectangle is 0 if
    the mean is inside, else on an edge, where it is a clamped 1D quadratic minimum."""
    a, b, c = proj.conic[g, 0], proj.conic[g, 1], proj.conic[g, 2]
    thr = jnp.log(jnp.maximum(255.0 * proj.opacity[g], 1e-30))
    lo_x = tx * ts + 0.5 - proj.xy[g, 0]
    hi_x = lo_x + (ts - 1)
    lo_y = ty * ts + 0.5 - proj.xy[g, 1]
    hi_y = lo_y + (ts - 1)
    a_s = jnp.where(a > 0, a, 1.0)
    c_s = jnp.where(c > 0, c, 1.0)

    def sig(dx, dy):
        return 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy

    def on_vertical(dx):  # edge x = dx, y free in [lo_y, hi_y]
        return sig(dx, jnp.clip(-b * dx / c_s, lo_y, hi_y))

    def on_horizontal(dy):
        return sig(jnp.clip(-b * dy / a_s, lo_x, hi_x), dy)

    edge = jnp.minimum(
        jnp.minimum(on_vertical(lo_x), on_vertical(hi_x)),
        jnp.minimum(on_horizontal(lo_y), on_horizontal(hi_y)),
    )
    inside = (lo_x <= 0) & (hi_x >= 0) & (lo_y <= 0) & (hi_y >= 0)
    smin = jnp.where(inside, 0.0, edge)
    return smin <= thr * (1.0 + 1e-3) + 1e-3


def _sorted_pairs(proj: Projected, camera: Camera, ts: int, M: int):
    """(Gaussian, tile) pairs grouped by tile, near to far inside each tile: returns the
    Gaussian of every depth-ordered slot `g` (M,), a list of parts (slot of every sorted entry
    (Mp,), tile start offsets (tiles + 1,) into them), whose per-tile runs concatenated in part
    order are the tile's list, and the total pair count."""
    TX, TY = _grid(camera, ts)
    n_tiles = TX * TY
    u, v = proj.xy[:, 0], proj.xy[:, 1]
    ex, ey = proj.extent[:, 0], proj.extent[:, 1]

    def tile_range(lo, hi, count):
        lo = jnp.clip(jnp.floor(lo / ts), 0, count - 1).astype(jnp.int32)
        hi = jnp.clip(jnp.floor(hi / ts), 0, count - 1).astype(jnp.int32)
        return lo, hi

    x0, x1 = tile_range(u - ex, u + ex, TX)
    y0, y1 = tile_range(v - ey, v + ey, TY)
    nx = x1 - x0 + 1
    n_pairs = jnp.where(proj.visible, nx * (y1 - y0 + 1), 0)

    # Pairs in depth order, then a stable grouping by tile (one integer sort).
    order = _depth_order(proj.depth, proj.visible)
    cnt = n_pairs[order]
    r, local, _ = _expand(cnt, M)
    total = jnp.sum(cnt)
    s = jnp.arange(M, dtype=jnp.int32)
    g = order[r]
    tx = x0[g] + local % nx[g]
    ty = y0[g] + local // nx[g]
    tile = ty * TX + tx
    valid = (s < total) & _ellipse_meets_tile(proj, g, tx, ty, ts)
    if (n_tiles + 1) * M < 2**31 - 1:
        # Unique int32 keys (invalid pairs after every tile). The slots are sorted in
        # `_SORT_PARTS` independent ranges (XLA's sort is single-threaded; independent sorts run
        # concurrently): a tile's entries are its entries of part 0, then of part 1, ..., since
        # earlier parts hold nearer slots.
        key = jnp.where(valid, tile * M, n_tiles * M) + s
        q = jnp.arange(n_tiles + 1, dtype=jnp.int32) * M
        cuts = [i * M // _SORT_PARTS for i in range(_SORT_PARTS + 1)]
        parts = []
        for a, b in zip(cuts[:-1], cuts[1:]):
            if b > a:
                skey = jnp.sort(key[a:b])
                parts.append((skey % M, jnp.searchsorted(skey, q).astype(jnp.int32)))
    else:
        with jax.enable_x64(True):
            key = jnp.where(valid, (tile.astype(jnp.int64) << 32) | s, jnp.iinfo(jnp.int64).max)
            skey = jnp.sort(key)
            q = jnp.arange(n_tiles + 1, dtype=jnp.int64) << 32
            bounds = jnp.searchsorted(skey, q).astype(jnp.int32)
            parts = [((skey & 0xFFFFFFFF).astype(jnp.int32), bounds)]
    return g, parts, total


def bin_gaussians(proj: Projected, camera: Camera, config: RenderConfig) -> Bins:
    """Per-tile near-to-far lists of the Gaussians whose boxes overlap each tile, cut into
    chunks (no gradient). See the module docstring."""
    proj = jax.lax.stop_gradient(proj)
    ts, B, K, NC, M = config.tile_size, config.chunk_size, config.capacity, config.max_chunks, config.max_pairs
    n = proj.depth.shape[0]
    g, parts, total = _sorted_pairs(proj, camera, ts, M)
    counts = sum(b[1:] - b[:-1] for _, b in parts).astype(jnp.int32)

    # Chunks: tile t owns ⌈min(count, K)/B⌉ consecutive chunks.
    kept = jnp.minimum(counts, K)
    n_chunks = (kept + B - 1) // B
    ct, cj, coff = _expand(n_chunks, NC)
    total_chunks = jnp.sum(n_chunks)
    c_valid = jnp.arange(NC) < total_chunks
    e = cj[:, None] * B + jnp.arange(B, dtype=jnp.int32)[None, :]
    slot = jnp.zeros(e.shape, jnp.int32)
    before = jnp.zeros(ct.shape, jnp.int32)  # entries of the tile in earlier parts
    for part_slot, bounds in parts:
        r = e - before[:, None]
        here = (r >= 0) & (r < (bounds[ct + 1] - bounds[ct])[:, None])
        pos = jnp.clip(bounds[ct][:, None] + r, 0, part_slot.shape[0] - 1)
        slot = jnp.where(here, part_slot[pos], slot)
        before = before + bounds[ct + 1] - bounds[ct]
    gid = g[jnp.clip(slot, 0, M - 1)]
    ids = jnp.where(c_valid[:, None] & (e < kept[ct][:, None]), gid, n)
    last = coff + n_chunks - 1
    layout = ChunkLayout(
        tile=ct,
        index=cj,
        count=jnp.where(c_valid, n_chunks[ct], 0),
        last=jnp.where((n_chunks > 0) & (last < NC), last, -1),
    )
    return Bins(
        ids=ids,
        layout=layout,
        counts=counts,
        lost_chunks=(n_chunks > 0) & (last >= NC),
        total_pairs=total,
        total_chunks=total_chunks,
    )


def _tile_inputs(gaussians: Gaussians, proj: Projected, bins: Bins, camera: Camera, ts: int):
    """(NC, B, 6) geometry of the listed Gaussians, and the channel table (N + 1, 3 + F) and
    depth table (N + 1,) they are read from (row N is the empty slot)."""
    TX, _ = _grid(camera, ts)
    dtype = proj.xy.dtype
    pad = lambda x: jnp.concatenate([x, jnp.zeros((1, *x.shape[1:]), x.dtype)], 0)  # noqa: E731
    tile = bins.layout.tile
    centre = jnp.stack([(tile % TX) * ts + 0.5 * ts, (tile // TX) * ts + 0.5 * ts], -1)
    geo = jnp.concatenate([proj.xy, proj.conic, proj.opacity[:, None]], axis=-1)
    geo = pad(geo)[bins.ids]
    params = jnp.concatenate([geo[..., :2] - centre.astype(dtype)[:, None, :], geo[..., 2:]], -1)
    chans = jnp.concatenate([gaussians.colours.astype(dtype), gaussians.features.astype(dtype)], -1)
    return params, pad(chans), pad(proj.depth)


def _untile(x: jax.Array, camera: Camera, ts: int) -> jax.Array:
    """(tiles, P, ...) -> (H, W, ...)."""
    TX, TY = _grid(camera, ts)
    rest = x.shape[2:]
    x = x.reshape(TY, TX, ts, ts, *rest)
    x = jnp.moveaxis(x, 2, 1).reshape(TY * ts, TX * ts, *rest)
    return x[: camera.height, : camera.width]


def bins_for(gaussians: Gaussians, camera: Camera, config: RenderConfig = RenderConfig()) -> Bins:
    """The per-tile lists `render` would build for `gaussians` seen by `camera` (no gradient):
    pass them to `render(..., bins=)` to render Gaussians that have since moved a little
    without binning again (traceable; jit the caller)."""
    return bin_gaussians(materialise(project_gaussians(gaussians, camera)), camera, config)


@eqx.filter_jit
def render(
    gaussians: Gaussians,
    camera: Camera,
    config: RenderConfig = RenderConfig(),
    background: Float[Array, "3"] | None = None,
    bins: Bins | None = None,
) -> RenderOutput:
    """Renders RGB, features, depth and alpha of `gaussians` seen by `camera` in one pass.

    Differentiable (plain autodiff around a hand-written compositing VJP) with respect to every
    float leaf of `gaussians` and the camera pose; binning and the compositing masks carry no
    gradient. Jitted once per (image size, N, F, config); vmap it over cameras or poses.

    Args:
        gaussians: N Gaussians in the world frame (apply part poses first).
        camera: intrinsics (static size H×W) and `T_cam_world` (OpenCV axes).
        config: tile size and static budgets (see `choose_config`).
        background: optional RGB added as (1 − alpha)·background.
        bins: per-tile lists from `bins_for` at an earlier pose of the same Gaussians and camera
            size, used instead of binning again (binning is most of a forward pass's cost on
            CPU). An approximation once the Gaussians have moved: a Gaussian's footprint is
            cut to the tiles it met then, and each tile keeps that depth order; the capacity
            diagnostics are those of the earlier pose. None: bin these Gaussians (exact).

    Returns:
        `RenderOutput` (images H×W; capacity diagnostics per tile).
    """
    global _trace_count
    _trace_count += 1
    ts = config.tile_size
    TX, TY = _grid(camera, ts)
    kc = config.capacity // config.chunk_size
    F = gaussians.num_features
    # Stored once, else XLA recomputes the projection inside every element of the gathers below.
    proj = materialise(project_gaussians(gaussians, camera))
    if bins is None:
        bins = bin_gaussians(proj, camera, config)
    elif bins.ids.shape != (config.max_chunks, config.chunk_size) or bins.counts.shape != (TX * TY,):
        raise ValueError(f"bins for {bins.ids.shape[0]} chunks of {bins.ids.shape[1]} and {bins.counts.shape[0]} tiles do not fit "
                         f"this render ({config.max_chunks} chunks of {config.chunk_size}, {TX * TY} tiles)")
    params, table, depth = _tile_inputs(gaussians, proj, bins, camera, ts)
    out, aux, saturated = composite_rows(params, table, depth, bins.ids, bins.layout, TX * TY, ts, kc)
    img = _untile(out, camera, ts)
    rgb, feats = img[..., :3], img[..., 3 : 3 + F]
    aux = _untile(aux, camera, ts)
    d_acc, alpha = aux[..., 0], aux[..., 1]
    if background is not None:
        rgb = rgb + (1.0 - alpha)[..., None] * jnp.asarray(background, rgb.dtype)
    overflow = jnp.maximum(bins.counts - config.capacity, 0)
    truncated = ((overflow > 0) & ~saturated) | bins.lost_chunks
    n_contrib = tile_needed = None
    if config.stats:
        n_used, n_walked = composite_stats(
            jax.lax.stop_gradient(params), jax.lax.stop_gradient(table)[bins.ids], bins.layout, TX * TY, ts, kc
        )
        n_contrib = _untile(n_used, camera, ts)
        tile_needed = jnp.minimum(n_walked, bins.counts).reshape(TY, TX)
    return RenderOutput(
        rgb=rgb,
        features=feats,
        depth=d_acc / jnp.maximum(alpha, 1e-10),
        depth_accum=d_acc,
        alpha=alpha,
        tile_counts=bins.counts.reshape(TY, TX),
        tile_overflow=overflow.reshape(TY, TX),
        tile_truncated=truncated.reshape(TY, TX),
        pairs_overflow=jnp.maximum(bins.total_pairs - config.max_pairs, 0),
        chunks_overflow=jnp.maximum(bins.total_chunks - config.max_chunks, 0),
        n_contrib=n_contrib,
        tile_needed=tile_needed,
    )


def _host_pairs(proj: Projected, TX: int, TY: int, ts: int) -> tuple[np.ndarray, np.ndarray, int]:
    """numpy version of `_sorted_pairs` for sizing: the Gaussian of every entry of the per-tile
    near-to-far lists, tile start offsets, and the total pair count before ellipse culling.
    Boxes use float32 arithmetic like the device code; the ellipse test is slightly looser than
    the device's, so lists here are a superset and budgets err on the safe side."""
    xy = np.asarray(proj.xy, np.float32)
    ext = np.asarray(proj.extent, np.float32)
    vis = np.asarray(proj.visible)
    lo = np.clip(np.floor((xy - ext) / np.float32(ts)), 0, [TX - 1, TY - 1]).astype(np.int64)
    hi = np.clip(np.floor((xy + ext) / np.float32(ts)), 0, [TX - 1, TY - 1]).astype(np.int64)
    nxy = np.where(vis[:, None], hi - lo + 1, 0)
    n_pairs = nxy[:, 0] * nxy[:, 1]
    total = int(n_pairs.sum())
    g = np.repeat(np.arange(xy.shape[0]), n_pairs)
    local = np.arange(total) - np.repeat(np.cumsum(n_pairs) - n_pairs, n_pairs)
    tx = lo[g, 0] + local % np.maximum(nxy[g, 0], 1)
    ty = lo[g, 1] + local // np.maximum(nxy[g, 0], 1)
    # Minimum of σ over the tile's rectangle of pixel centres (see `_ellipse_meets_tile`).
    conic = np.asarray(proj.conic, np.float64)[g]
    a, b, c = conic[:, 0], conic[:, 1], conic[:, 2]
    u, v = xy[g, 0].astype(np.float64), xy[g, 1].astype(np.float64)
    lo_x, lo_y = tx * ts + 0.5 - u, ty * ts + 0.5 - v
    hi_x, hi_y = lo_x + (ts - 1), lo_y + (ts - 1)
    a_s, c_s = np.where(a > 0, a, 1.0), np.where(c > 0, c, 1.0)

    def sig(dx, dy):
        return 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy

    edge = np.minimum.reduce(
        [
            sig(lo_x, np.clip(-b * lo_x / c_s, lo_y, hi_y)),
            sig(hi_x, np.clip(-b * hi_x / c_s, lo_y, hi_y)),
            sig(np.clip(-b * lo_y / a_s, lo_x, hi_x), lo_y),
            sig(np.clip(-b * hi_y / a_s, lo_x, hi_x), hi_y),
        ]
    )
    inside = (lo_x <= 0) & (hi_x >= 0) & (lo_y <= 0) & (hi_y >= 0)
    thr = np.log(np.maximum(255.0 * np.asarray(proj.opacity, np.float64)[g], 1e-30))
    keep = np.where(inside, 0.0, edge) <= thr * (1.0 + 1e-2) + 1e-2
    g, tile = g[keep], (ty * TX + tx)[keep]
    depth = np.asarray(proj.depth, np.float32)[g]
    order = np.lexsort((g, depth, tile))
    bounds = np.searchsorted(tile[order], np.arange(TX * TY + 1))
    return g[order], bounds, total
_project_jit = jax.jit(project_gaussians)


def _round_up(x: float, m: int) -> int:
    return int(max(m, m * math.ceil(x / m)))


def _walked_entries(proj: Projected, gid_sorted, bounds, TX: int, ts: int, block: int = 128) -> np.ndarray:
    """Host-side (numpy, float64) count per tile of the list entries its pixels walk before
    gsplat's transmittance stop, plus one entry of margin for float32 rounding in `render`.
    Same rules as the compositor: α = min(MAX_ALPHA, o·e^(−σ)), kept if α ≥ ALPHA_THRESHOLD, a
    pixel walks entry k while the transmittance before it, Σ_{j<k} log(1 − α_j), is above the
    stop. Tiles are processed in blocks so memory stays at block × K × P."""
    xy = np.asarray(proj.xy, np.float64)
    conic = np.asarray(proj.conic, np.float64)
    opac = np.asarray(proj.opacity, np.float64)
    bounds = np.asarray(bounds)
    counts = np.diff(bounds)
    gid_sorted = gid_sorted if gid_sorted.shape[0] else np.zeros(1, np.int64)
    n_tiles = counts.shape[0]
    r = np.arange(ts) + 0.5
    py, px = np.meshgrid(r, r, indexing="ij")
    px, py = px.reshape(-1), py.reshape(-1)
    log_stop = math.log(TRANSMITTANCE_THRESHOLD)
    out = np.zeros(n_tiles, np.int64)
    for t0 in range(0, n_tiles, block):
        t = np.arange(t0, min(t0 + block, n_tiles))
        kd = int(counts[t].max())
        if kd == 0:
            continue
        k = np.arange(kd)
        mask = k[None, :] < counts[t][:, None]
        gid = gid_sorted[np.minimum(bounds[t][:, None] + k[None, :], gid_sorted.shape[0] - 1)]
        dx = (t % TX * ts)[:, None, None] + px[None, None, :] - xy[gid, 0][..., None]
        dy = (t // TX * ts)[:, None, None] + py[None, None, :] - xy[gid, 1][..., None]
        a, b, c = (conic[gid, i][..., None] for i in range(3))
        sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
        alpha = np.minimum(MAX_ALPHA, np.where(mask, opac[gid], 0.0)[..., None] * np.exp(-sigma))
        l = np.where(alpha >= ALPHA_THRESHOLD, np.log1p(-alpha), 0.0)
        excl = np.cumsum(l, axis=1) - l
        walked = np.sum((excl > log_stop) & mask[..., None], axis=1).max(axis=-1)
        out[t] = np.minimum(walked + 1, counts[t])
    return out


def choose_config(
    gaussians: Gaussians,
    cameras: Camera | Sequence[Camera],
    tile_size: int = 4,
    chunk_size: int = 32,
    headroom: float = 1.25,
    exact: bool = False,
    capacity_headroom: float | None = None,
    pairs_headroom: float | None = None,
) -> RenderConfig:
    """Host-side choice of the static budgets (K, chunks, pairs) for a scene and its cameras.

    Projects the Gaussians into each camera (jitted; compiled once per N and image size), builds
    the per-tile lists on the host (numpy, no compilation) and measures per tile how many list
    entries the pixels walk before the transmittance stop
    (`exact=False`: the smallest K that renders these views exactly, plus one entry for rounding)
    or how many candidates there are (`exact=True`: no list is ever cut). K is that maximum
    times `headroom` (for poses that move), rounded up to a multiple of `chunk_size`;
    `max_chunks` and `max_pairs` are the largest totals times `headroom`.

    Args:
        gaussians: the posed Gaussians (world frame).
        cameras: one camera or a sequence of (unbatched) cameras.
        tile_size: tile side in pixels.
        chunk_size: list entries per chunk.
        headroom: multiplicative margin (≥ 1).
        exact: size K from candidate counts instead of the transmittance stop.
        capacity_headroom, pairs_headroom: margins of K and `max_pairs` alone (default
            `headroom`). The work of a render follows `max_chunks`; a larger K or pair budget
            costs little (measured on a 28×28 tracking grid, 5.9k Gaussians: 2× K +4 %, 2× pairs
            +3 %, 1.5× chunks +15 % per forward + backward).
    """
    capacity_headroom = headroom if capacity_headroom is None else capacity_headroom
    pairs_headroom = headroom if pairs_headroom is None else pairs_headroom
    for name, h in (("headroom", headroom), ("capacity_headroom", capacity_headroom), ("pairs_headroom", pairs_headroom)):
        if not h >= 1:
            raise ValueError(f"{name} must be ≥ 1, got {h}")
    if isinstance(cameras, Camera):
        cameras = [cameras]
    B = chunk_size
    need_k, need_m, all_counts = B, 1, []
    for cam in cameras:
        proj = _project_jit(gaussians, cam)
        TX, TY = _grid(cam, tile_size)
        gid_sorted, bounds, total = _host_pairs(proj, TX, TY, tile_size)
        counts = np.diff(np.asarray(bounds))
        if exact:
            k = int(counts.max())
        else:
            k = int(_walked_entries(proj, gid_sorted, bounds, TX, tile_size).max())
        need_k, need_m = max(need_k, k), max(need_m, total)
        all_counts.append(counts)
    K = _round_up(need_k * capacity_headroom, B)
    nc = max(int(np.sum(-(-np.minimum(c, K) // B))) for c in all_counts)
    return RenderConfig(
        tile_size=tile_size,
        chunk_size=B,
        capacity=K,
        max_chunks=_round_up(nc * headroom, 8),
        max_pairs=_round_up(need_m * pairs_headroom, 1024),
    )
