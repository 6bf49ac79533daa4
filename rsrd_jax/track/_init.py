"""Object pose initialisation: feature matching -> ray -> distance prior -> vmapped multi-seed
optimisation. Serves the demo's first frame (relative mono-depth) and robot-view registration
(metric depth)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import optax
from jaxtyping import Array, Float

from ..splat import RenderConfig, choose_config, rest_part_poses, apply_part_poses
from ..geometry import Camera
from ._dpm import FrameObs, TrackModel, lr_schedule, render_posed
from ._losses import feature_loss


def seed_rotations(yaw_seeds: int, altitudes_deg) -> Float[Array, "s 3 3"]:
    """`R_cam_obj` hypotheses for an object standing on its z-up base seen from a camera looking
    down at elevation e: object +z maps to camera (0, −cos e, −sin e) (image up, tilted towards
    the camera), then `yaw_seeds` distinct yaws about the object's z."""
    out = []
    for e in np.deg2rad(np.asarray(altitudes_deg, np.float64)):
        base = np.stack([[1, 0, 0], [0, -np.sin(e), np.cos(e)], [0, -np.cos(e), -np.sin(e)]], axis=1)
        for yaw in np.arange(yaw_seeds) * 2 * np.pi / yaw_seeds:
            Rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
            out.append(base @ Rz)
    return jnp.asarray(np.stack(out), jnp.float32)


def mutual_nn_pixels(g_feats: np.ndarray, f_feats: np.ndarray, f_uv: np.ndarray) -> np.ndarray:
    """Pixels of frame features that are mutual nearest neighbours (cosine) of Gaussian features."""
    a = g_feats / (np.linalg.norm(g_feats, axis=1, keepdims=True) + 1e-8)
    b = f_feats / (np.linalg.norm(f_feats, axis=1, keepdims=True) + 1e-8)
    sim = a @ b.T
    nn_ab = sim.argmax(1)
    nn_ba = sim.argmax(0)
    mutual = nn_ba[nn_ab] == np.arange(len(a))
    return f_uv[nn_ab[mutual]]


def centred(T_seed: jaxlie.SE3, delta: Float[Array, "6"], c: Float[Array, "3"]) -> jaxlie.SE3:
    """`T_seed @ Tr(c) @ exp(δ) @ Tr(−c)`: a tangent update about the object centroid c."""
    Tc = jaxlie.SE3.from_translation(c)
    return T_seed @ Tc @ jaxlie.SE3.exp(delta) @ Tc.inverse()


class InitResult(eqx.Module):
    T_cam_obj: jaxlie.SE3
    seed_losses: Float[Array, " s"]
    best_seed: int = eqx.field(static=True)
    distance_m: float = eqx.field(static=True)
    num_matches: int = eqx.field(static=True)


def _pose_objective(tm, T_cam_obj, obs: FrameObs, config, metric_depth, depth_weight):
    r = render_posed(tm, rest_part_poses(tm.part_centroids), T_cam_obj, obs.intrinsics, obs.bg_feature, config)
    loss = feature_loss(r.features, obs.features, obs.weight)
    if metric_depth is not None:
        m = (r.alpha > 0.5) & (metric_depth > 0) & (obs.weight > 0)
        err = jnp.clip(jnp.abs(r.depth - metric_depth), 0.0, 0.1)
        loss = loss + depth_weight * 10.0 * jnp.sum(m * err) / jnp.maximum(m.sum(), 1.0)
    return loss


def adam_about_centroid(loss_at, T_seed: jaxlie.SE3, c, lrs, units=None) -> jaxlie.SE3:
    """Adam (optax) on a tangent update δ about the centroid `c` of `T_seed` (`centred`), one
    step per learning rate in `lrs` (a `lax.scan`); traced inside the caller's jit and vmap.

    Args:
        loss_at: `T_cam_obj -> scalar` objective.
        T_seed: the starting pose.
        c: (3,) object centroid (object frame).
        lrs: (n,) learning rates.
        units: optional (6,) scale of δ's components (e.g. translation in object sizes).

    Returns:
        The optimised pose.
    """
    opt = optax.scale_by_adam()
    u6 = jnp.ones(6) if units is None else units

    def step(carry, lr):
        d, st = carry
        g = jax.grad(lambda d: loss_at(centred(T_seed, d * u6, c)))(d)
        g = jnp.where(jnp.isfinite(g), g, 0.0)
        upd, st = opt.update(g, st)
        return (d - lr * upd, st), None

    d0 = jnp.zeros(6)
    (d, _), _ = jax.lax.scan(step, (d0, opt.init(d0)), lrs)
    return centred(T_seed, d * u6, c)


@eqx.filter_jit
def _optimise_seeds(tm, T_seeds: jaxlie.SE3, c, obs, lrs, config, metric_depth, depth_weight):
    def one(T_seed):
        loss_at = lambda T: _pose_objective(tm, T, obs, config, metric_depth, depth_weight)  # noqa: E731
        T = adam_about_centroid(loss_at, T_seed, c, lrs)
        return T.wxyz_xyz, loss_at(T)

    return jax.vmap(one)(T_seeds)


def estimate_distance(uv: np.ndarray, fx: float, radius: float) -> float:
    """Distance at which an object of `radius` spans the matched pixels' extent."""
    if len(uv) < 4:
        return 8.0 * radius
    ext = np.percentile(uv, 90, axis=0) - np.percentile(uv, 10, axis=0)
    ext_px = max(float(ext.max()), 8.0)
    return float(np.clip(fx * 1.6 * radius / ext_px, 2.0 * radius, 60.0 * radius))


def initialize_pose(
    tm: TrackModel,
    observe,
    frame: np.ndarray,
    K,
    cfg,
    full_box,
    roi_box_fn,
    metric_depth_full: np.ndarray | None = None,
    progress=None,
) -> tuple[InitResult, dict]:
    """Estimates `T_cam_obj` on one frame.

    Args:
        tm: the tracking model (parts at rest).
        observe: `box -> FrameObs` for this frame.
        frame: the RGB frame (H×W×3 uint8).
        K: full-frame intrinsics.
        cfg: `InitConfig`.
        full_box: the letterbox covering the whole frame.
        roi_box_fn: `T_cam_obj -> box` around the object's projection.
        metric_depth_full: optional metric depth (H×W metres, 0 unknown) for registration.

    Returns:
        (InitResult, info dict with timings-free diagnostics).
    """
    from ._observe import crop

    obs = observe(full_box)
    g = obs.features.shape[0]
    x0, y0, s = full_box
    jj, ii = np.meshgrid(np.arange(g), np.arange(g))
    uv_cells = np.stack([x0 + (jj + 0.5) * s / g, y0 + (ii + 0.5) * s / g], -1).reshape(-1, 2)
    w = np.asarray(obs.weight).reshape(-1) > 0
    feats = np.asarray(obs.features).reshape(g * g, -1)
    rng = np.random.default_rng(0)
    n = tm.gaussians.num_gaussians
    pick = rng.choice(n, min(cfg.match_gaussians, n), replace=False)
    gf = np.asarray(jax.vmap(tm.decoder)(tm.gaussians.features[pick, : tm.num_features]))
    # drop frame cells that look like the background: they cannot match the object
    bg = np.asarray(obs.bg_feature)
    fg = w & (np.linalg.norm(feats - bg, axis=1) > np.percentile(np.linalg.norm(feats - bg, axis=1), 50))
    uv = mutual_nn_pixels(gf, feats[fg], uv_cells[fg])
    if len(uv) == 0:
        uv = uv_cells[fg] if fg.any() else uv_cells
    u, v = np.median(uv, axis=0)
    means = np.asarray(tm.gaussians.means)
    c = means.mean(0)
    radius = float(np.percentile(np.linalg.norm(means - c, axis=1), 90))
    ray = np.array([(u - float(K.cx)) / float(K.fx), (v - float(K.cy)) / float(K.fy), 1.0])
    if cfg.distance_m is not None:
        dist = float(cfg.distance_m)
    elif metric_depth_full is not None:
        d = metric_depth_full[np.clip(uv[:, 1].astype(int), 0, frame.shape[0] - 1), np.clip(uv[:, 0].astype(int), 0, frame.shape[1] - 1)]
        d = d[d > 0]
        dist = float(np.median(d)) + 0.5 * radius if len(d) else estimate_distance(uv, float(K.fx), radius)
    else:
        dist = estimate_distance(uv, float(K.fx), radius)
    p_cam = ray / np.linalg.norm(ray) * dist
    R = np.asarray(seed_rotations(cfg.yaw_seeds, cfg.altitudes_deg))
    t = p_cam[None] - np.einsum("sij,j->si", R, c)
    T_seeds = jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.from_matrix(jnp.asarray(R)), jnp.asarray(t, jnp.float32))

    def render_config(T_list, intr):
        posed = apply_part_poses(tm.gaussians, rest_part_poses(tm.part_centroids), tm.part_centroids)
        cams = [Camera(intr, jaxlie.SE3(T)) for T in T_list]
        return choose_config(posed, cams, headroom=1.5)

    # optimise the seeds on a crop around the matched region (the object fills it, unlike the
    # whole frame), sized for the object's apparent extent at the prior distance
    side_px = 2.0 * radius * float(K.fx) / dist * 1.6
    seed_box = (float(u) - side_px / 2, float(v) - side_px / 2, side_px)
    obs_s = observe(seed_box)
    md = None
    if metric_depth_full is not None:
        md = jnp.asarray(crop(metric_depth_full.astype(np.float32), seed_box, g, 0))  # nearest
    cfg_full = render_config([T_seeds.wxyz_xyz[i] for i in range(0, len(R), max(1, len(R) // 4))], obs_s.intrinsics)
    lrs = lr_schedule(cfg.lr_start, cfg.lr_end, cfg.iters)
    c32 = jnp.asarray(c, jnp.float32)
    n_screen = cfg.screen_iters if 0 < cfg.screen_iters < cfg.iters else cfg.iters
    Ts, losses = _optimise_seeds(tm, T_seeds, c32, obs_s, lrs[:n_screen], cfg_full, md, cfg.depth_weight)
    survivors = np.arange(len(R))
    final_losses = losses
    if n_screen < cfg.iters and cfg.keep_seeds < len(R):
        # successive halving: the best `keep_seeds` continue (fresh Adam moments, same schedule)
        survivors = np.argsort(np.asarray(losses))[: max(cfg.keep_seeds, 1)]
        Ts, final_losses = _optimise_seeds(tm, jaxlie.SE3(Ts[survivors]), c32, obs_s, lrs[n_screen:], cfg_full, md, cfg.depth_weight)
    elif n_screen < cfg.iters:
        Ts, final_losses = _optimise_seeds(tm, jaxlie.SE3(Ts), c32, obs_s, lrs[n_screen:], cfg_full, md, cfg.depth_weight)
    k = int(jnp.argmin(final_losses))
    best = int(survivors[k])
    T_best = jaxlie.SE3(Ts[k])
    # refine the best seed on an ROI around it
    box = roi_box_fn(T_best)
    obs_roi = observe(box)
    md_roi = jnp.asarray(crop(metric_depth_full.astype(np.float32), box, g, 0)) if metric_depth_full is not None else None
    cfg_roi = render_config([T_best.wxyz_xyz], obs_roi.intrinsics)
    lrs2 = lr_schedule(cfg.lr_end, cfg.lr_end * 0.5, cfg.refine_iters)
    Ts2, losses2 = _optimise_seeds(tm, jaxlie.SE3(T_best.wxyz_xyz[None]), c32, obs_roi, lrs2, cfg_roi, md_roi, cfg.depth_weight)
    res = InitResult(jaxlie.SE3(Ts2[0]), losses, best, dist, int(len(uv)))
    info = {"seed_losses": np.asarray(losses).tolist(), "screen_iters": int(n_screen),
            "survivors": [int(i) for i in survivors], "survivor_losses": np.asarray(final_losses).tolist(),
            "best_seed": best, "distance_prior_m": dist,
            "matches": int(len(uv)), "refined_loss": float(losses2[0]), "match_pixel": [float(u), float(v)]}  # fmt: skip
    return res, info
