"""Training the per-Gaussian feature field (DiG-style) with the geometry frozen.

Each Gaussian carries an F-dim vector; the rasterizer composites them like colour at the
extractor's grid resolution (the image camera with intrinsics divided by the stride, so a grid
cell is one rendered pixel); the rendered map is divided by alpha and decoded per pixel by a
bias-free ReLU MLP into the PCA space of the extractor's features. Loss: MSE on object cells
whose rendered alpha ≥ `alpha_threshold` (low-alpha pixels masked), plus `smooth_weight` × the
variance of each Gaussian's feature over itself and its k nearest neighbours.
"""

from __future__ import annotations

import dataclasses
import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import optax
from scipy.spatial import cKDTree

from ..geometry import Camera, Intrinsics
from ..splat import Gaussians, render
from ..splat._fit import size_render_config
from ._model import FeatureDecoder, decode_rendered


GRID_TILE_SIZE = 4
"""Rasterizer tile side used at feature-grid resolution. A grid cell covers a stride² pixel
block, so a whole object falls into few 8×8 tiles and their nearest-K lists overflow (measured on
red_box, 16k Gaussians, 40×30 grid: only 67 of 126 object cells reach alpha 0.8 with 8×8 tiles
and K = 256, 149 with K = 1024; 123 with 4×4 tiles and K = 256 at 43 ms per render)."""


class FieldConfig(eqx.Module):
    """Options of the feature-field fit."""

    feature_dim: int = 32
    """F: learnable feature per Gaussian."""
    decoder_width: int = 64
    """Hidden width of the decoder MLP."""
    decoder_layers: int = 4
    """Linear layers of the decoder MLP."""
    iterations: int = 600
    """Adam steps (one view each, at grid resolution)."""
    lr: float = 1e-2
    """Initial learning rate (features and decoder), decayed exponentially to `lr_final`."""
    lr_final: float = 1e-3
    """Final learning rate."""
    smooth_weight: float = 0.01
    """Weight of the kNN feature-variance regulariser."""
    knn: int = 3
    """Neighbours in the regulariser."""
    alpha_threshold: float = 0.8
    """Rendered-alpha threshold below which a cell is excluded from the loss."""
    seed: int = 0
    """Initialisation and view-order seed."""


def grid_intrinsics(intrinsics: Intrinsics, grid_hw: tuple[int, int]) -> Intrinsics:
    """Intrinsics of a camera whose pixels are the feature grid cells (stride = size ratio)."""
    return intrinsics.scaled(int(grid_hw[1]), int(grid_hw[0]))


def _stack_intrinsics(view_intrinsics) -> jax.Array:
    return jnp.asarray([[float(k.fx), float(k.fy), float(k.cx), float(k.cy)] for k in view_intrinsics], jnp.float32)


def _view_intrinsics(kvec: jax.Array, grid_hw: tuple[int, int]) -> Intrinsics:
    return Intrinsics(kvec[0], kvec[1], kvec[2], kvec[3], int(grid_hw[1]), int(grid_hw[0]))


def _fit_render_config(gaussians: Gaussians, view_intrinsics, T_cam_world: np.ndarray):
    """One render budget covering every given view (each may have its own intrinsics)."""
    cfgs = [size_render_config(gaussians, k, np.asarray(T)[None], GRID_TILE_SIZE)
            for k, T in zip(view_intrinsics, T_cam_world)]  # fmt: skip
    return dataclasses.replace(cfgs[0], max_chunks=max(c.max_chunks for c in cfgs),
                               max_pairs=max(c.max_pairs for c in cfgs))  # fmt: skip


def _per_view_grid_intrinsics(intrinsics, grid_hw, V, view_intrinsics):
    if view_intrinsics is None:
        return [grid_intrinsics(intrinsics, grid_hw)] * V
    view_intrinsics = list(view_intrinsics)
    if len(view_intrinsics) != V:
        raise ValueError(f"view_intrinsics: {len(view_intrinsics)} entries for {V} views")
    for i, k in enumerate(view_intrinsics):
        if (k.height, k.width) != tuple(grid_hw):
            raise ValueError(f"view_intrinsics[{i}] is {k.width}×{k.height}, expected the grid {grid_hw[1]}×{grid_hw[0]}")
    return view_intrinsics


def _smooth(features, knn_idx):
    nb = features[knn_idx]  # n, k+1, F
    return jnp.mean(jnp.var(nb, axis=1))


@eqx.filter_jit
def _field_block(feats, decoder, opt_state, views, gaussians, targets, valid, Ts, kvecs, rcfg, knn_idx, optimizer, cfg_arr):
    alpha_thr, smooth_w = cfg_arr[0], cfg_arr[1]
    grid_hw = targets.shape[1:3]

    def loss_fn(params, v):
        f, dec = params
        g = eqx.tree_at(lambda x: x.features, gaussians, f)
        cam = Camera(_view_intrinsics(kvecs[v], grid_hw), jaxlie.SE3(Ts.wxyz_xyz[v]))
        out = render(g, cam, rcfg)
        pred = decode_rendered(dec, out.features, out.alpha)
        w = valid[v] & (jax.lax.stop_gradient(out.alpha) >= alpha_thr)
        err = jnp.sum((pred - targets[v]) ** 2, -1)
        mse = jnp.sum(jnp.where(w, err, 0.0)) / (jnp.maximum(jnp.sum(w), 1) * targets.shape[-1])
        return mse + smooth_w * _smooth(f, knn_idx), mse

    def body(i, carry):
        f, dec, s, tot = carry
        (_, mse), gr = jax.value_and_grad(loss_fn, has_aux=True)((f, dec), views[i])
        upd, s = optimizer.update(gr, s, (f, dec))
        f, dec = optax.apply_updates((f, dec), upd)
        return f, dec, s, tot + mse

    f, dec, s, tot = jax.lax.fori_loop(0, views.shape[0], body, (feats, decoder, opt_state, jnp.zeros(())))
    return f, dec, s, tot / views.shape[0]


def fit_feature_field(
    gaussians: Gaussians,
    targets: np.ndarray,
    valid: np.ndarray,
    intrinsics: Intrinsics,
    T_cam_world: np.ndarray,
    config: FieldConfig = FieldConfig(),
    progress: bool = False,
    view_intrinsics=None,
) -> tuple[Gaussians, FeatureDecoder, dict]:
    """Fits per-Gaussian features and the decoder to PCA-space feature maps.

    Args:
        gaussians: fitted geometry (world frame); its features are replaced.
        targets: V×h×w×D PCA-space features of the views (grid resolution).
        valid: V×h×w bool object cells.
        intrinsics: full-resolution image intrinsics (the grid camera is derived from them).
        T_cam_world: V×4×4 view poses.
        view_intrinsics: optional V per-view intrinsics *at grid resolution* (e.g. object crops,
            `box_intrinsics(K, box, grid)`); replaces the grid camera derived from `intrinsics`.

    Returns:
        (Gaussians with N×F features, decoder, history).
    """
    V, gh, gw, D = targets.shape
    key = jax.random.key(config.seed)
    k1, k2 = jax.random.split(key)
    n = gaussians.num_gaussians
    feats = 0.1 * jax.random.normal(k1, (n, config.feature_dim), jnp.float32)
    decoder = FeatureDecoder.create(config.feature_dim, D, config.decoder_width, config.decoder_layers, k2)
    g = eqx.tree_at(lambda x: x.features, gaussians, feats)
    gis = _per_view_grid_intrinsics(intrinsics, (gh, gw), V, view_intrinsics)
    rng = np.random.default_rng(config.seed)
    sample = rng.choice(V, min(V, 6), replace=False)
    rcfg = _fit_render_config(g, [gis[i] for i in sample], np.asarray(T_cam_world)[sample])
    means = np.asarray(gaussians.means)
    k = min(config.knn + 1, n)
    _, idx = cKDTree(means).query(means, k=k)
    knn_idx = jnp.asarray(np.asarray(idx).reshape(n, k), jnp.int32)
    sched = optax.exponential_decay(config.lr, max(config.iterations, 1), config.lr_final / config.lr)
    optimizer = optax.adam(sched)
    opt_state = optimizer.init((feats, decoder))
    Ts = jaxlie.SE3.from_matrix(jnp.asarray(T_cam_world, jnp.float32))
    tj, vj = jnp.asarray(targets, jnp.float32), jnp.asarray(valid)
    cfg_arr = jnp.asarray([config.alpha_threshold, config.smooth_weight], jnp.float32)
    kvecs = _stack_intrinsics(gis)
    hist = []
    done = 0
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=config.iterations, desc="feature field", leave=False)
    while done < config.iterations:
        nb = min(200, config.iterations - done)
        views = jnp.asarray(rng.integers(0, V, nb), jnp.int32)
        feats, decoder, opt_state, mse = _field_block(
            feats, decoder, opt_state, views, g, tj, vj, Ts, kvecs, rcfg, knn_idx, optimizer, cfg_arr
        )
        done += nb
        hist.append({"iteration": done, "mse": float(mse)})
        if bar is not None:
            bar.update(nb)
            bar.set_postfix(mse=f"{float(mse):.4f}")
    if bar is not None:
        bar.close()
    return eqx.tree_at(lambda x: x.features, gaussians, feats), decoder, {"blocks": hist, "render_config": str(rcfg)}


def render_decoded(
    gaussians: Gaussians,
    decoder: FeatureDecoder,
    intrinsics: Intrinsics,
    T_cam_world: np.ndarray,
    grid_hw: tuple[int, int],
    view_intrinsics=None,
) -> tuple[np.ndarray, np.ndarray]:
    """Decoded PCA-space feature maps (V×h×w×D) and alphas (V×h×w) at grid resolution
    (`view_intrinsics` as in `fit_feature_field`)."""
    T_cam_world = np.asarray(T_cam_world)
    gis = _per_view_grid_intrinsics(intrinsics, grid_hw, len(T_cam_world), view_intrinsics)
    rcfg = _fit_render_config(gaussians, gis, T_cam_world)
    fs, als = [], []
    for gi, T in zip(gis, T_cam_world):
        cam = Camera(gi, jaxlie.SE3.from_matrix(jnp.asarray(T, jnp.float32)))
        out = render(gaussians, cam, rcfg)
        fs.append(np.asarray(decode_rendered(decoder, out.features, out.alpha)))
        als.append(np.asarray(out.alpha))
    return np.stack(fs), np.stack(als)
