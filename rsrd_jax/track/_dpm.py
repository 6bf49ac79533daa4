"""The 4D Differentiable Part Model: render the posed model at an ROI grid and score it against a
frame's observations; per-frame Adam solve and joint temporal smoothing.

Frames: the object frame is the scan's world frame; part p's frame has its origin at the rest
centroid c_p (`splat.apply_part_poses`). A tracked state is `T_obj_part` (P poses) per frame and
one `T_cam_obj` for the video (RSRD's release optimises only part poses after initialisation;
whole-object motion is absorbed by the parts).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import optax
from jaxtyping import Array, Float, Int

from ..geometry import Camera, Intrinsics
from ..parts import decode_rendered
from ..splat import Bins, Gaussians, RenderConfig, apply_part_poses, bins_for, render
from ._lod import merge_gaussians
from ._losses import arap_loss, depth_ranking_loss, feature_loss, hand_depth_loss, hand_loss, pose_smoothness, prismatic_loss, revolute_loss, support_loss, touch_loss

_trace_counts = {"frame": 0, "smooth": 0}


class TrackModel(eqx.Module):
    """What tracking needs of an ObjectModel, as arrays (the constant side of `f(model, state)`)."""

    gaussians: Gaussians
    """Rest-pose Gaussians (object frame) whose features are [learned features | one-hot part]."""
    decoder: eqx.Module
    """Per-pixel feature decoder F -> D (PCA space)."""
    part_centroids: Float[Array, "p 3"]
    part_pivots: Float[Array, "p 3"]
    """Pivot of each part's tangent update, in the part frame (metres from the rest centroid): the
    centre of the part's ARAP contact pairs (a hinge's rotation is then one coordinate of the
    update instead of a coupled rotation + translation, which a diagonal optimiser like Adam
    follows badly); zero (the centroid) for parts without pairs and for the largest part (except
    in joint discovery's second pass on a two-part object, `contact_pivots`)."""
    arap_pairs: Int[Array, "m 2"]
    arap_weight: Float[Array, " m"]
    touch_points: Int[Array, " e"]
    """Contact Gaussians (both ends of every ARAP pair) of the as-touching term."""
    touch_candidates: Int[Array, "e k"]
    """For each contact Gaussian, the K nearest Gaussians of the *other* part at rest."""
    touch_rest: Float[Array, " e"]
    """Rest distance of each contact Gaussian to its nearest candidate."""
    touch_weight: Float[Array, " e"]
    touch_direction: Int[Array, " e"]
    """Ordered part pair (q → r) of each contact Gaussian."""
    touch_pairs: Int[Array, "u 2"]
    """The two directions of each touching part pair (the term takes the smaller of the two)."""
    slide_parts: Int[Array, "q 2"]
    """Slide joints of the prismatic term (`prismatic_loss`): (part, neighbour) per joint."""
    slide_axes: Float[Array, "q 3"]
    """Unit slide direction of each joint (object frame at rest)."""
    slide_lengths: Float[Array, " q"]
    """Radius of each sliding part (metres; converts its rotation residual to a length)."""
    slide_weight: Float[Array, " q"]
    """Weight of each slide joint (one zero-weight dummy entry when there are none)."""
    hinge_parts: Int[Array, "r 2"]
    """Hinge axes of the revolute term (`revolute_loss`): (part, neighbour) per joint."""
    hinge_axes: Float[Array, "r 3"]
    """Unit hinge axis of each joint (object frame at rest)."""
    hinge_lengths: Float[Array, " r"]
    """Radius of each hinged part (metres; converts its off-axis rotation to a length)."""
    hinge_weight: Float[Array, " r"]
    """Weight of each hinge axis (one zero-weight dummy entry when there are none)."""
    support_plane: Float[Array, "4"]
    """(n, d): the table the object rests on, n·x = d in the object frame (`support_loss`); a
    plane 1 km below the object when unknown (the term is then zero)."""
    num_features: int = eqx.field(static=True)
    num_parts: int = eqx.field(static=True)

    @staticmethod
    def from_object_model(model, max_gaussians: int, seed: int = 0, voxel_m: float | None = None,
                          touch: bool = False, support_plane=None) -> TrackModel:  # fmt: skip
        """Host-side: optionally merge Gaussians per part on a `voxel_m` grid (level of detail for
        the tracker's render resolution), subsample to `max_gaussians` (keeping ARAP pairs whose
        ends survive), append one-hot part channels to the features. `touch`: set up the
        as-touching term's candidates (otherwise one zero-weight dummy entry, no cost per step).
        `support_plane`: (n, d) of the support term (None: none, the plane lies 1 km below)."""
        g = model.gaussians
        rng = np.random.default_rng(seed)
        pairs = np.asarray(model.arap_pairs, np.int64).reshape(-1, 2)
        if voxel_m:
            g, inv = merge_gaussians(g, float(voxel_m))
            pairs = inv[pairs] if len(pairs) else pairs
            if len(pairs):
                pairs = np.unique(np.sort(pairs[pairs[:, 0] != pairs[:, 1]], axis=1), axis=0)
        n = g.num_gaussians
        if n > max_gaussians:
            # keep every Gaussian that is in an ARAP pair (boundary), fill up by opacity-weighted draw
            must = np.unique(pairs.reshape(-1))[: max_gaussians // 2]
            rest = np.setdiff1d(np.arange(n), must)
            op = np.asarray(jax.nn.sigmoid(g.opacity_logits))[rest] + 1e-3
            extra = rng.choice(rest, max_gaussians - len(must), replace=False, p=op / op.sum())
            keep = np.sort(np.concatenate([must, extra]))
        else:
            keep = np.arange(n)
        remap = -np.ones(n, np.int64)
        remap[keep] = np.arange(len(keep))
        pairs = remap[pairs] if len(pairs) else pairs
        pairs = pairs[(pairs >= 0).all(axis=1)] if len(pairs) else np.zeros((0, 2), np.int64)
        if len(pairs) == 0:  # keep shapes non-empty; a zero-weight dummy pair contributes nothing
            pairs_w = np.zeros(1, np.float32)
            pairs = np.zeros((1, 2), np.int64)
        else:
            pairs_w = np.ones(len(pairs), np.float32)
        P = int(model.num_parts)
        sub = jax.tree_util.tree_map(lambda x: jnp.asarray(np.asarray(x)[keep]), g)  # host gathers: no compilation
        touch = touch_candidates(np.asarray(sub.means), np.asarray(sub.part_ids), pairs, pairs_w if touch else 0 * pairs_w)
        pivots = contact_pivots(np.asarray(sub.means), np.asarray(sub.part_ids), pairs, pairs_w, np.asarray(model.part_centroids), P)
        onehot = jax.nn.one_hot(sub.part_ids, P, dtype=sub.features.dtype)
        sub = eqx.tree_at(lambda x: x.features, sub, jnp.concatenate([sub.features, onehot], axis=-1))
        return TrackModel(
            gaussians=sub,
            decoder=model.decoder,
            part_centroids=jnp.asarray(model.part_centroids, jnp.float32),
            part_pivots=jnp.asarray(pivots, jnp.float32),
            arap_pairs=jnp.asarray(pairs, jnp.int32),
            arap_weight=jnp.asarray(pairs_w),
            touch_points=jnp.asarray(touch[0], jnp.int32),
            touch_candidates=jnp.asarray(touch[1], jnp.int32),
            touch_rest=jnp.asarray(touch[2], jnp.float32),
            touch_weight=jnp.asarray(touch[3], jnp.float32),
            touch_direction=jnp.asarray(touch[4], jnp.int32),
            touch_pairs=jnp.asarray(touch[5], jnp.int32),
            slide_parts=jnp.zeros((1, 2), jnp.int32),
            slide_axes=jnp.asarray([[1.0, 0.0, 0.0]], jnp.float32),
            slide_lengths=jnp.zeros(1, jnp.float32),
            slide_weight=jnp.zeros(1, jnp.float32),
            hinge_parts=jnp.zeros((1, 2), jnp.int32),
            hinge_axes=jnp.asarray([[0.0, 0.0, 1.0]], jnp.float32),
            hinge_lengths=jnp.zeros(1, jnp.float32),
            hinge_weight=jnp.zeros(1, jnp.float32),
            support_plane=jnp.asarray([0.0, 0.0, 1.0, -1e3] if support_plane is None else support_plane, jnp.float32),
            num_features=int(g.num_features),
            num_parts=P,
        )


TOUCH_CANDIDATES = 1024
"""K: candidates (nearest Gaussians of the other part at rest) per contact Gaussian of the
as-touching term; they cover the region a contact can slide into (≈ 4–6 cm on studio objects)."""


def touch_candidates(means, part_ids, pairs, pair_w, k: int = TOUCH_CANDIDATES):
    """Host-side set-up of the as-touching term. For every ordered part pair (q, r) that has
    weighted ARAP pairs, q's contact Gaussians (its ends of those pairs), their K nearest
    Gaussians of part r at rest, and the rest distance to the nearest one.

    Returns (points (e,), candidates (e, k), rest (e,), weight (e,), direction (e,) index of the
    ordered pair (q, r), directions (u, 2): the two direction indices of each unordered part pair
    (−1 if a direction has no entries)). One zero-weight dummy entry when there are no pairs."""
    from scipy.spatial import cKDTree

    sel = pairs[pair_w > 0] if len(pairs) else pairs
    pts, cands, rest, dirs = [], [], [], []
    order: dict[tuple[int, int], int] = {}
    for q, r in sorted({(int(part_ids[i]), int(part_ids[j])) for i, j in sel} | {(int(part_ids[j]), int(part_ids[i])) for i, j in sel}):
        mine = np.unique(np.concatenate([sel[(part_ids[sel[:, 0]] == q) & (part_ids[sel[:, 1]] == r), 0],
                                         sel[(part_ids[sel[:, 1]] == q) & (part_ids[sel[:, 0]] == r), 1]]))  # fmt: skip
        other = np.flatnonzero(part_ids == r)
        kk = min(k, len(other))
        d, j = cKDTree(means[other]).query(means[mine], k=kk)
        d, j = np.asarray(d).reshape(len(mine), kk), np.asarray(j).reshape(len(mine), kk)
        order[(q, r)] = len(order)
        pts.append(mine)
        cands.append(np.pad(other[j], ((0, 0), (0, k - kk)), mode="edge"))
        rest.append(d[:, 0])
        dirs.append(np.full(len(mine), order[(q, r)]))
    if not pts:
        z = np.zeros(1, np.int64)
        return z, np.zeros((1, k), np.int64), np.zeros(1), np.zeros(1), z, -np.ones((1, 2), np.int64)
    unordered = sorted({tuple(sorted(x)) for x in order})
    pair_dirs = np.array([[order.get((q, r), -1), order.get((r, q), -1)] for q, r in unordered], np.int64)
    p = np.concatenate(pts)
    return p, np.concatenate(cands), np.concatenate(rest), np.ones(len(p)), np.concatenate(dirs), pair_dirs


def contact_pivots(means, part_ids, pairs, pair_w, centroids, P: int, root_too: bool = False) -> np.ndarray:
    """Per part: mean midpoint of its cross-part ARAP pairs of weight > 0 minus its centroid (P×3, part
    frame); zero for parts without pairs and for the largest part (the root) unless `root_too`
    (joint discovery ties a two-part object at one joint, about which either part may turn: the
    stapler's arm has more Gaussians than its base)."""
    piv = np.zeros((P, 3))
    counts = np.bincount(part_ids, minlength=P)
    root = int(np.argmax(counts))
    pairs = pairs[pair_w > 0]
    for k in range(P):
        if k == root and not root_too:
            continue
        sel = (part_ids[pairs[:, 0]] == k) | (part_ids[pairs[:, 1]] == k)
        if sel.any():
            mid = 0.5 * (means[pairs[sel, 0]] + means[pairs[sel, 1]])
            piv[k] = mid.mean(0) - centroids[k]
    return piv


def compose_update(T_init: jaxlie.SE3, delta: Float[Array, "*b p 6"], pivots: Float[Array, "p 3"]) -> jaxlie.SE3:
    """`T_init @ Tr(q) @ exp(δ) @ Tr(−q)` per part: a tangent update about pivot q (part frame)."""
    Tq = jaxlie.SE3.from_translation(jnp.broadcast_to(pivots, delta.shape[:-1] + (3,)))
    return jaxlie.SE3(T_init.wxyz_xyz) @ Tq @ jaxlie.SE3.exp(delta) @ Tq.inverse()


class Rendered(eqx.Module):
    features: Float[Array, "h w d"]
    """Decoded features composited over the background feature."""
    depth: Float[Array, "h w"]
    alpha: Float[Array, "h w"]
    rgb: Float[Array, "h w 3"]
    part_weight: Float[Array, "h w p"]
    means: Float[Array, "n 3"]
    truncated: Int[Array, ""]
    """Tiles whose dropped list entries or chunks could have changed a pixel, plus the (Gaussian,
    tile) pairs dropped beyond the pair budget: 0 when the render is exact under its budgets."""


def render_posed(
    tm: TrackModel,
    T_obj_part: jaxlie.SE3,
    T_cam_obj: jaxlie.SE3,
    intrinsics: Intrinsics,
    bg_feature: Float[Array, " d"],
    config: RenderConfig,
    bins: Bins | None = None,
) -> Rendered:
    """Renders the model with parts at `T_obj_part` seen from `T_cam_obj` at `intrinsics`' grid
    (with `bins`: the per-tile lists of an earlier pose, `posed_bins`; see `splat.render`)."""
    posed = apply_part_poses(tm.gaussians, T_obj_part, tm.part_centroids)
    out = render(posed, Camera(intrinsics, T_cam_obj), config, jnp.zeros(3), bins)
    F = tm.num_features
    dec = decode_rendered(tm.decoder, out.features[..., :F], out.alpha)
    a = out.alpha[..., None]
    feats = a * dec + (1.0 - a) * bg_feature
    truncated = jnp.sum(out.tile_truncated).astype(jnp.int32) + out.pairs_overflow.astype(jnp.int32)
    return Rendered(feats, out.depth, out.alpha, out.rgb, out.features[..., F:], posed.means, truncated)


class FrameObs(eqx.Module):
    """One frame's observations on the ROI grid (all shapes static for a video)."""

    intrinsics: Intrinsics
    """Camera of the ROI feature grid (crop and stride folded into the intrinsics)."""
    features: Float[Array, "h w d"]
    """Observed features, PCA space."""
    weight: Float[Array, "h w"]
    """1 where the pixel is usable (inside the image, not occluded by a hand), else 0."""
    rgb: Float[Array, "h w 3"]
    """Observed colour on the grid, [0, 1]."""
    mono: Float[Array, "h w"]
    """Monocular relative depth (larger = farther; only its order is used)."""
    bg_feature: Float[Array, " d"]
    """Feature assigned to pixels the object does not cover."""
    bg_rgb: Float[Array, "3"]
    """Colour assigned to pixels the object does not cover."""
    hand_uv: Float[Array, "k 2"]
    """Each hand's pinch point (midpoint of its detected thumb and index tips, `FingertipSource`)
    in ROI-grid pixels (0 where not detected)."""
    hand_seen: Float[Array, " k"]
    """1 where the hand's two fingertips were detected in this frame."""
    hand_part: Int[Array, " k"]
    """Part each hand pinches (`track._hands`; meaningful where `hand_weight` > 0)."""
    hand_point: Float[Array, "k 3"]
    """The pinched point, in that part's frame (metres from its rest centroid)."""
    hand_weight: Float[Array, " k"]
    """Weight of each hand in the hand term: detected and anchored (0 otherwise)."""
    hand_surface: Float[Array, "k 3"]
    """The held part's visible surface at the pinch point, in that part's frame (metres;
    `HandAnchors.surface`), which the hand depth term places."""
    hand_depth: Float[Array, " k"]
    """Each hand's pinch point depth (camera z, m) read off the table (`Observer.hand_depths`),
    for the hand depth term."""
    hand_depth_seen: Float[Array, " k"]
    """1 where that depth is known (the hand seen, the table's depths bracket it), else 0."""


class Weights(eqx.Module):
    feature: Float[Array, ""]
    depth_rank: Float[Array, ""]
    arap: Float[Array, ""]
    touch: Float[Array, ""]
    rgb: Float[Array, ""]
    arap_alpha: Float[Array, ""]
    arap_scale: Float[Array, ""]
    alpha_mask: Float[Array, ""]
    step_scale: Float[Array, "6"]
    """Per tangent coordinate step multiplier: translations in units of the object radius."""
    support: Float[Array, ""]
    hand: Float[Array, ""]
    hand_alpha: Float[Array, ""]
    hand_scale: Float[Array, ""]
    """Barron scale of the hand term, ROI-grid pixels (feature cells)."""
    motion: Float[Array, ""]
    hand_depth: Float[Array, ""]
    hand_depth_scale: Float[Array, ""]
    """Cauchy scale of the hand depth term, metres."""
    part_step: Float[Array, " p"] | None = None
    """Per part step multiplier (0 holds a part where its solve starts, `TrackConfig.still_root`);
    None: 1 for every part."""

    @staticmethod
    def from_config(cfg, separable: bool, object_radius: float) -> Weights:
        a = cfg.arap_alpha if cfg.arap_alpha is not None else (0.1 if separable else 1.0)
        f = lambda v: jnp.asarray(v, jnp.float32)  # noqa: E731
        w = cfg.weights
        ts = cfg.translation_scale if cfg.translation_scale is not None else object_radius
        scale = f([ts, ts, ts, 1.0, 1.0, 1.0])
        arap = w.arap if not separable or cfg.separable_arap is None else cfg.separable_arap
        motion = w.motion if not separable or cfg.separable_motion is None else cfg.separable_motion
        return Weights(f(w.feature), f(w.depth_rank), f(arap), f(w.touch), f(w.rgb), f(a), f(cfg.arap_scale), f(cfg.alpha_mask), scale,
                       f(w.support), f(w.hand), f(cfg.hand_alpha), f(cfg.hand_scale_cells), f(motion), f(w.hand_depth if separable or cfg.hand_depth_attached else 0.0),
                       f(cfg.hand_depth_scale))  # fmt: skip


def _erode(mask: Float[Array, "h w"]) -> Float[Array, "h w"]:
    return -jax.lax.reduce_window(-mask, -jnp.inf, jax.lax.max, (3, 3), (1, 1), "SAME")


def posed_bins(tm: TrackModel, T_obj_part: jaxlie.SE3, T_cam_obj: jaxlie.SE3, intrinsics: Intrinsics, config: RenderConfig) -> Bins:
    """The rasterizer's per-tile lists of the model posed at `T_obj_part` (`splat.bins_for`; no
    gradient: binning stops it)."""
    posed = apply_part_poses(tm.gaussians, T_obj_part, tm.part_centroids)
    return bins_for(posed, Camera(intrinsics, T_cam_obj), config)


def frame_objective(
    tm: TrackModel,
    T_obj_part: jaxlie.SE3,
    T_cam_obj: jaxlie.SE3,
    obs: FrameObs,
    w: Weights,
    key: jax.Array,
    config: RenderConfig,
    num_pairs: int,
    bins: Bins | None = None,
) -> tuple[Float[Array, ""], dict]:
    """Per-frame loss of part poses `T_obj_part` (P) and its terms (with `bins`: rendered on the
    per-tile lists of an earlier pose, see `splat.render`)."""
    r = render_posed(tm, T_obj_part, T_cam_obj, obs.intrinsics, obs.bg_feature, config, bins)
    l_feat = feature_loss(r.features, obs.features, obs.weight)
    # full-ROI photometric L1 with the background colour composited behind the object (comparing
    # only inside the rendered silhouette would reward shrinking it)
    rgb = r.rgb + (1.0 - r.alpha)[..., None] * obs.bg_rgb
    l_rgb = jnp.sum(obs.weight[..., None] * jnp.abs(rgb - obs.rgb)) / jnp.maximum(3 * jnp.sum(obs.weight), 1.0)
    # depth ranking on random pairs inside the eroded rendered mask, hand-free
    m = jax.lax.stop_gradient(_erode((r.alpha > w.alpha_mask).astype(jnp.float32)) * obs.weight).reshape(-1)
    idx = jax.random.choice(key, m.shape[0], (num_pairs, 2), p=m / jnp.maximum(m.sum(), 1e-6))
    pair_w = (m.sum() > 1).astype(jnp.float32) * jnp.ones(num_pairs)
    l_rank = depth_ranking_loss(r.depth.reshape(-1), obs.mono.reshape(-1), idx, pair_w)
    l_arap = arap_loss(r.means, tm.gaussians.means, tm.arap_pairs, tm.arap_weight, w.arap_alpha, w.arap_scale)
    l_touch = touch_loss(r.means, tm.touch_points, tm.touch_candidates, tm.touch_rest, tm.touch_weight,
                         tm.touch_direction, tm.touch_pairs, w.arap_alpha, w.arap_scale)  # fmt: skip
    l_slide = prismatic_loss(T_obj_part, tm.part_centroids, tm.slide_parts, tm.slide_axes, tm.slide_lengths,
                             tm.slide_weight, w.arap_alpha, w.arap_scale)  # fmt: skip
    l_hinge = revolute_loss(T_obj_part, tm.hinge_parts, tm.hinge_axes, tm.hinge_lengths, tm.hinge_weight,
                            w.arap_alpha, w.arap_scale)  # fmt: skip
    l_support = support_loss(r.means, tm.gaussians.means, tm.support_plane, w.arap_scale)
    l_hand = hand_loss(T_obj_part, T_cam_obj, obs.intrinsics, obs.hand_part, obs.hand_point, obs.hand_uv, obs.hand_weight,
                       w.hand_alpha, w.hand_scale)  # fmt: skip
    l_hand_depth = hand_depth_loss(T_obj_part, T_cam_obj, obs.hand_part, obs.hand_surface, obs.hand_depth,
                                   obs.hand_weight * obs.hand_depth_seen, w.hand_depth_scale)  # fmt: skip
    total = (w.feature * l_feat + w.rgb * l_rgb + w.depth_rank * l_rank + w.arap * (l_arap + l_slide + l_hinge) + w.touch * l_touch
             + w.support * l_support + w.hand * l_hand + w.hand_depth * l_hand_depth)
    # per-part residual: feature error weighted by each part's rendered share of the pixel
    err = jnp.sqrt(jnp.sum((r.features - obs.features) ** 2, axis=-1) + 1e-12) * obs.weight
    pw = r.part_weight * obs.weight[..., None]
    part_res = jnp.einsum("hw,hwp->p", err, pw) / jnp.maximum(pw.sum((0, 1)), 1e-6)
    part_vis = pw.sum((0, 1)) / jnp.maximum(r.part_weight.sum((0, 1)), 1e-6)
    aux = {"feature": l_feat, "rgb": l_rgb, "rank": l_rank, "arap": l_arap, "touch": l_touch, "slide": l_slide, "hinge": l_hinge, "support": l_support, "hand": l_hand, "hand_depth": l_hand_depth, "part_residual": part_res, "part_visible": part_vis,
           "render_truncated": r.truncated}
    return total, aux


def motion_prior(delta: Float[Array, "p 6"], step_scale: Float[Array, "6"]) -> Float[Array, ""]:
    """Mean over parts of ‖δ / step_scale‖²: the squared tangent update of a frame's solve, its
    translations in object radii (`LossWeights.motion`)."""
    return jnp.mean(jnp.sum((delta / step_scale) ** 2, axis=-1))


def lr_schedule(lr0, lr1, n: int) -> Float[Array, " n"]:
    """Exponential decay from lr0 to lr1 over n steps (array: sweeping lr does not recompile)."""
    t = jnp.arange(n, dtype=jnp.float32) / max(n - 1, 1)
    return lr0 * (lr1 / lr0) ** t


@eqx.filter_jit
def solve_frame(
    tm: TrackModel,
    T_init: jaxlie.SE3,
    T_cam_obj: jaxlie.SE3,
    obs: FrameObs,
    w: Weights,
    lrs: Float[Array, " s"],
    key: jax.Array,
    config: RenderConfig,
    num_pairs: int,
    rebin_every: int = 1,
) -> tuple[jaxlie.SE3, dict]:
    """Per-frame Adam on tangent updates of every part pose: `T = T_init @ exp(δ)`, δ ∈ R^{P×6}
    (about the part centroid, in the part frame). One compiled function per video.

    `rebin_every` > 1: the rasterizer bins the Gaussians on the first of every `rebin_every`
    steps and renders the following ones on those per-tile lists (`TrackConfig.rebin_every`);
    the final render, which scores the result, is always binned afresh."""
    _trace_counts["frame"] += 1
    if rebin_every < 1:
        raise ValueError(f"rebin_every must be ≥ 1, got {rebin_every}")
    P = T_init.wxyz_xyz.shape[0]
    opt = optax.scale_by_adam()

    def loss_fn(delta, k, bins):
        T = compose_update(T_init, delta, tm.part_pivots)
        loss, aux = frame_objective(tm, T, T_cam_obj, obs, w, k, config, num_pairs, bins)
        return loss + w.motion * motion_prior(delta, w.step_scale), aux

    def bins_at(delta):
        return posed_bins(tm, compose_update(T_init, delta, tm.part_pivots), T_cam_obj, obs.intrinsics, config)

    def step(carry, xs):
        delta, state, bins = carry
        lr, k, i = xs
        if rebin_every > 1:
            bins = jax.lax.cond((i > 0) & (i % rebin_every == 0), bins_at, lambda _: bins, delta)
        (loss, aux), g = jax.value_and_grad(loss_fn, has_aux=True)(delta, k, bins)
        g = jnp.where(jnp.isfinite(g), g, 0.0)
        upd, state = opt.update(g, state)
        held = 1.0 if w.part_step is None else w.part_step[:, None]
        return (delta - lr * w.step_scale * held * upd, state, bins), loss

    delta0 = jnp.zeros((P, 6))
    keys = jax.random.split(key, lrs.shape[0] + 1)
    bins0 = bins_at(delta0) if rebin_every > 1 else None
    steps = jnp.arange(lrs.shape[0], dtype=jnp.int32)
    (delta, _, _), losses = jax.lax.scan(step, (delta0, opt.init(delta0), bins0), (lrs, keys[1:], steps))
    T = compose_update(T_init, delta, tm.part_pivots)
    final, aux = frame_objective(tm, T, T_cam_obj, obs, w, keys[0], config, num_pairs)
    aux["loss"] = final
    aux["loss_curve"] = losses
    return T, aux


@eqx.filter_jit
def smooth_step(
    tm: TrackModel,
    delta: Float[Array, "t p 6"],
    T_base: jaxlie.SE3,
    T_cam_obj: jaxlie.SE3,
    obs: FrameObs,
    w: Weights,
    frames: Int[Array, " b"],
    smooth_weight: Float[Array, ""],
    key: jax.Array,
    config: RenderConfig,
    num_pairs: int,
) -> tuple[Float[Array, ""], Float[Array, "t p 6"]]:
    """Loss and gradient of the joint smoothing objective: data terms on a frame minibatch
    (vmapped renders) + first-difference smoothness over all frames."""
    _trace_counts["smooth"] += 1

    def loss_fn(delta):
        T_all = compose_update(T_base, delta, tm.part_pivots)
        sm = pose_smoothness(T_all)
        T_b = jaxlie.SE3(T_all.wxyz_xyz[frames])
        obs_b = jax.tree_util.tree_map(lambda x: x[frames], obs)
        keys = jax.random.split(key, frames.shape[0])
        data, _ = jax.vmap(lambda T, o, k: frame_objective(tm, T, T_cam_obj, o, w, k, config, num_pairs))(T_b, obs_b, keys)
        return jnp.mean(data) + smooth_weight * sm * delta.shape[0]

    return jax.value_and_grad(loss_fn)(delta)


def extrapolate(prev: jaxlie.SE3, prev2: jaxlie.SE3 | None, factor: float) -> jaxlie.SE3:
    """Damped constant velocity: `prev @ exp(factor · log(prev2⁻¹ prev))` per part."""
    if prev2 is None or factor == 0:
        return prev
    d = (prev2.inverse() @ prev).log()
    return prev @ jaxlie.SE3.exp(factor * d)


def stack_obs(obs: list[FrameObs]) -> FrameObs:
    """T per-frame observations -> one batched FrameObs (leading axis T)."""
    return jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *obs)

