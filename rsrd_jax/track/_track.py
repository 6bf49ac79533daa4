"""`track_video`: initialise on frame 0, solve every frame, smooth jointly, return a PartTrajectory."""

from __future__ import annotations

import time
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import optax
from tqdm.auto import tqdm

from .._cache import CompileClock
from .._threads import worker_pool
from ..geometry import Camera, project_points
from ..io import ArtefactError, Demo, PartTrajectory
from ..splat import apply_part_poses, choose_config, rest_part_poses
from ._config import InitConfig, TrackConfig
from ._dpm import TrackModel, Weights, compose_update, contact_pivots, extrapolate, lr_schedule, smooth_step, solve_frame, stack_obs
from ._joints import (fit_joint_point, hand_hinge_residual, hand_slide_residual, hinge_axis, is_slide_candidate, joint_slots, relative_turn_deg,
                      slide_axes, slide_directions, with_joint_slots)
from ._init import initialize_pose, widest
from ._hands import HandAnchors, surface_depths, update_hand_anchors, with_hand_anchors, with_hand_depth_offset
from ._observe import model_extractor, FingertipSource, MonoDepthSource, Observer, OccluderSource, full_frame_box, plane_depth, roi_box


SLIDE_HAND_FLOOR_PX = 1.0
"""Pixels added to `TrackConfig.slide_hand_ratio` × the hinge's residual before a slide hypothesis
is ruled out by the hand (a tolerance for a pinch track that every hypothesis fits to a pixel)."""


class _HandTrack(NamedTuple):
    """The demonstrator's hands over the video, for joint discovery's hand tests."""

    pinch_uv: np.ndarray
    """T×H×2 pinch points (full-frame pixels, `Observer.pinch_points`)."""
    seen: np.ndarray
    """T×H: both fingertips detected."""
    T_cam_obj: np.ndarray
    """(7,) the object's pose in the camera (wxyz_xyz)."""
    intrinsics: object
    """The video's camera."""


class _Pass(NamedTuple):
    """One per-frame pass over the video."""

    T_parts: list
    obs: list
    residual: list
    visible: list
    loss: list
    """Final loss per frame."""
    data_loss: list
    """Data terms (feature, rgb, rank, hand, hand depth) of the final loss per frame: hypotheses compare these."""
    logged: list
    """Deferred rerun log entries (emitted for the pass that is kept)."""
    switched: int
    """Frames where the second start won."""
    key: jax.Array
    anchors: HandAnchors
    """Fingertip anchors at the end of the pass."""


def _roi_for(tm: TrackModel, T_obj_part: jaxlie.SE3, T_cam_obj: jaxlie.SE3, K, margin: float):
    posed = apply_part_poses(tm.gaussians, T_obj_part, tm.part_centroids)
    uv, z = project_points(K, T_cam_obj @ posed.means)
    uv = np.asarray(uv)[np.asarray(z) > 0]
    return roi_box(uv, K.width, K.height, margin)


def _lod_voxel(model, config: TrackConfig, grid_size: int) -> float | None:
    """The level-of-detail voxel (m) for `config.lod_cells` feature cells of the ROI grid."""
    if not config.lod_cells:
        return None
    mp = np.asarray(model.gaussians.means)
    r = float(np.percentile(np.linalg.norm(mp - mp.mean(0), axis=1), 90))
    return config.lod_cells * 2 * r * (1 + 2 * config.roi_margin) / grid_size


def _initialize(tm: TrackModel, obsr: Observer, demo: Demo, init: InitConfig, roi_margin: float):
    """The object's pose on the demo's first frame (`initialize_pose` on the full frame)."""
    frame0, K = demo.frames[0], demo.intrinsics
    rest = rest_part_poses(tm.part_centroids)
    res, info = initialize_pose(tm, lambda box: obsr.observe(0, frame0, box), frame0, K, init,
                                full_frame_box(K.width, K.height), lambda T: _roi_for(tm, rest, T, K, roi_margin))  # fmt: skip
    return res.T_cam_obj, info


def initialize_demo(
    model,
    demo: Demo,
    config: TrackConfig = TrackConfig(),
    init: InitConfig = InitConfig(),
    occluder: OccluderSource | None = None,
    mono: MonoDepthSource | None = None,
    extractor=None,
) -> tuple[jaxlie.SE3, dict]:
    """The object's pose on the demo's first frame alone: what :func:`track_video` starts from
    (same observations, model sizes and initialiser), for evaluating the initialisation.

    Args:
        model: an `ObjectModel`.
        demo: the decoded demo video (only frame 0 is used).
        config: tracking options (ROI size and margin, Gaussian budget, seed).
        init: initialisation options.
        occluder, mono: as in :func:`track_video`.
        extractor: the feature extractor; default rebuilt from `model.feature_backend`.

    Returns:
        (`T_cam_obj` on frame 0, the initialiser's diagnostics with `init_s`, the wall time).
    """
    if demo.num_frames < 1:
        raise ArtefactError(f"{demo.video_path}: the demo has no frames")
    t0 = time.perf_counter()
    obsr = Observer(model_extractor(model, extractor), model.pca, demo.intrinsics, config.roi_size, occluder, mono)
    tm = TrackModel.from_object_model(model, config.max_gaussians, config.seed, _lod_voxel(model, config, obsr.grid_size))
    T, info = _initialize(tm, obsr, demo, init, config.roi_margin)
    return T, {**info, "init_s": time.perf_counter() - t0}


def track_video(
    model,
    demo: Demo,
    config: TrackConfig = TrackConfig(),
    init: InitConfig = InitConfig(),
    occluder: OccluderSource | None = None,
    mono: MonoDepthSource | None = None,
    separable: bool | None = None,
    extractor=None,
    progress: bool = True,
    log=None,
    T_cam_obj_init: jaxlie.SE3 | None = None,
    fingertips: FingertipSource | None = None,
) -> PartTrajectory:
    """Tracks every part of `model` through `demo` (4D-DPM, RSRD §4).

    Args:
        model: an `ObjectModel` (rsrd_jax.parts).
        demo: the decoded demo video with its intrinsics.
        config, init: tracking and initialisation options.
        occluder: hand/person mask source (default none).
        mono: monocular relative depth source (default none: no ranking term).
        separable: object parts come apart (ARAP α 0.1); default from the model's metadata.
        extractor: the feature extractor; default rebuilt from `model.feature_backend`.
        progress: show a progress bar.
        log: optional callback `log(stage, t, dict)` (rerun logging in the CLI).
        T_cam_obj_init: a known object pose on frame 0 (e.g. from another registration); skips
            the initialisation.
        fingertips: 2D fingertip detections for the hand term (default none: no hand term).

    Returns:
        PartTrajectory with per-frame part poses, object pose, residuals and metadata
        (timings: init, per-frame, smoothing, compile).
    """
    if not config.render_headroom >= 1.0 or not np.isfinite(config.render_headroom):
        raise ValueError(f"TrackConfig.render_headroom must be a finite number ≥ 1, got {config.render_headroom}")
    if config.rebin_every < 1:
        raise ValueError(f"TrackConfig.rebin_every must be ≥ 1, got {config.rebin_every}")
    if config.hinge_refine_deg is not None and not 0.0 < config.hinge_refine_deg < 90.0:  # also refuses NaN
        raise ValueError(f"TrackConfig.hinge_refine_deg must be None or degrees in (0, 90), got {config.hinge_refine_deg}")
    if config.slide_baseline not in ("first", "joint"):
        raise ValueError(f"TrackConfig.slide_baseline must be 'first' or 'joint', got {config.slide_baseline!r}")
    if config.joints and config.slides and config.still_root and not config.still_root_first and config.slide_baseline == "first":
        raise ValueError("TrackConfig.still_root holds the root from the second pass on, and slide_baseline='first' would "
                         "compare the slide hypotheses with the first pass, whose root moves freely: use "
                         "slide_baseline='joint' (or still_root_first=True)")
    if demo.num_frames < 1:
        raise ArtefactError(f"{demo.video_path}: the demo has no frames")
    f = np.asarray(demo.frames)
    if f.ndim != 4 or f.shape[1:] != (demo.intrinsics.height, demo.intrinsics.width, 3) or f.dtype != np.uint8:
        raise ArtefactError(
            f"{demo.video_path}: frames must be T×{demo.intrinsics.height}×{demo.intrinsics.width}×3 uint8 "
            f"(the camera's size), got {f.shape} {f.dtype}"
        )
    extractor = model_extractor(model, extractor)
    if separable is None:
        separable = bool(model.meta.get("separable", False))
    K = demo.intrinsics
    t_start = time.perf_counter()
    obsr = Observer(extractor, model.pca, K, config.roi_size, occluder, mono, fingertips, config.table_pairs)
    voxel = _lod_voxel(model, config, obsr.grid_size)
    use_joints = config.joints and not separable
    neighbour: dict[int, int] = {}
    if use_joints:
        r_pair = float(model.meta.get("arap_radius_m", 0.0025))
        model, neighbour = with_joint_slots(model, r_pair, max(4 * r_pair, 0.08 * float(model.meta.get("scale_m", 0.05))))
    plane = _support_plane(model, config) if config.weights.support > 0 else None
    tm = TrackModel.from_object_model(model, config.max_gaussians, config.seed, voxel, touch=config.weights.touch > 0,
                                      support_plane=plane)  # fmt: skip
    if not config.contact_pivots:
        tm = eqx.tree_at(lambda m: m.part_pivots, tm, jnp.zeros_like(tm.part_pivots))
    rest = rest_part_poses(tm.part_centroids)
    timings: dict[str, float] = {}

    # ---- initialisation on frame 0
    t0 = time.perf_counter()
    with CompileClock() as clock:
        if T_cam_obj_init is None:
            T_cam_obj, init_info = _initialize(tm, obsr, demo, init, config.roi_margin)
        else:
            T_cam_obj, init_info = jaxlie.SE3(jnp.asarray(T_cam_obj_init.wxyz_xyz, jnp.float32)), {"given": True}
    timings["init_s"] = time.perf_counter() - t0
    timings["init_compile_s"] = clock.seconds  # inside init_s: tracing, lowering, XLA compilation or cache loads

    # ---- per-frame pass
    means = np.asarray(tm.gaussians.means)
    radius = float(np.percentile(np.linalg.norm(means - means.mean(0), axis=1), 90))
    w = Weights.from_config(config, separable, radius)
    lrs = lr_schedule(config.lr_start, config.lr_end, config.steps_per_frame)
    box0 = _roi_for(tm, rest, T_cam_obj, K, config.roi_margin)
    posed0 = apply_part_poses(tm.gaussians, rest, tm.part_centroids)
    # the render budgets, widened where a frame's render was not exact (`TrackConfig.render_headroom`)
    budgets = dict(headroom=config.render_headroom, capacity_headroom=2.0 * config.render_headroom, pairs_headroom=2.0 * config.render_headroom)
    rc = [choose_config(posed0, Camera(obsr.grid_intrinsics(box0), T_cam_obj), **budgets)]
    growths: list[dict] = []
    key = jax.random.key(config.seed)

    use_hands = fingertips is not None and config.weights.hand > 0
    table = config.support_plane if config.support_plane is not None else model.meta.get("support_plane")
    if use_hands and float(w.hand_depth) > 0 and mono is not None and table is not None:
        # the hand depth term's table: the support plane's depth along every pixel's ray
        obsr.table_depth = plane_depth(K, T_cam_obj, np.asarray(table, np.float64))
    compile_s = [0.0]  # first-call excess of the jitted per-frame solve (compilation), all passes
    pool = worker_pool() if config.parallel_starts else None

    def per_frame_pass(tm, w, key, desc, record=True, lrs=lrs, vh=config.velocity_hypothesis, hold_root=config.still_root):
        T_parts: list[jaxlie.SE3] = []
        obs_all, residual, visible, losses, data, logged = [], [], [], [], [], []
        switched = 0  # frames where the second start won
        warm: set = set()  # render budgets the solve has run with in this pass (compiled)
        solve_s: list[float] = []
        anchors = HandAnchors.empty(obsr.fingertips.num_hands)
        # the hand depth term's calibration: each hand's depth read off the table is biased (the
        # pinch pixel sees the part's surface or a finger, not the anchored point), so the term
        # uses it shifted by the median offset to the tracked surface point over the first
        # `hand_depth_calibration` frames where it was known: only the hand's depth *changes* act
        calib = [[] for _ in range(obsr.fingertips.num_hands)]
        offset = np.full(obsr.fingertips.num_hands, np.nan)
        w_first = w_rest = w
        if hold_root and tm.num_parts > 1:
            # the root solved on frame 0 only; both carry a `part_step` array so that the
            # per-frame solve keeps one pytree structure (one compilation)
            w_first, w_rest = _held_root(w, tm.num_parts, False), _held_root(w, tm.num_parts, True)
        bar = tqdm(range(demo.num_frames), desc=desc, disable=not progress)
        for t in bar:
            prev = T_parts[-1] if T_parts else rest
            prev2 = T_parts[-2] if len(T_parts) > 1 else None
            T_guess = extrapolate(prev, prev2, config.velocity_factor)
            box = _roi_for(tm, T_guess, T_cam_obj, K, config.roi_margin)
            obs = with_hand_anchors(obsr.observe(t, demo.frames[t], box), anchors)
            raw = obs
            obs = with_hand_depth_offset(obs, offset)
            key, sub = jax.random.split(key)

            def solve(T_guess=T_guess, obs=obs, sub=sub, prev=prev, prev2=prev2, wt=w_first if t == 0 else w_rest):
                starts = [T_guess]
                if vh is not None and prev2 is not None:
                    # a second start (e.g. full constant velocity) on the same observations and
                    # pair sample: the lower final loss wins
                    starts.append(extrapolate(prev, prev2, vh))
                cfg = rc[0]

                def run(T0):
                    return jax.block_until_ready(solve_frame(tm, T0, T_cam_obj, obs, wt, lrs, sub, cfg, config.rank_pairs, config.rebin_every))

                if len(starts) > 1 and pool is not None and cfg in warm:
                    # both starts at once, one thread each (`TrackConfig.parallel_starts`); only
                    # once compiled for these budgets, so that no two threads trace it
                    (T, aux), (T2, aux2) = pool.map(run, starts)
                else:
                    (T, aux), *rest = [run(T0) for T0 in starts]
                    T2, aux2 = rest[0] if rest else (None, None)
                warm.add(cfg)
                truncated, second = int(aux["render_truncated"]), False
                if T2 is not None:
                    truncated = max(truncated, int(aux2["render_truncated"]))
                    if float(aux2["loss"]) < float(aux["loss"]):
                        T, aux, second = T2, aux2, True
                return jaxlie.SE3(T.wxyz_xyz), aux, truncated, second

            tf = time.perf_counter()
            T, aux, truncated, second = solve()
            solve_s.append(time.perf_counter() - tf)
            if truncated:
                # the budgets were too small at this frame's solution: widen them there (one more
                # compilation, reported as such) and solve the frame again
                grown = widest(rc[0], choose_config(apply_part_poses(tm.gaussians, T, tm.part_centroids),
                                                    Camera(obs.intrinsics, T_cam_obj), **budgets))  # fmt: skip
                if grown is not rc[0]:
                    before, rc[0] = rc[0], grown
                    tg = time.perf_counter()
                    T, aux, truncated, second = solve()
                    typical = float(np.median(solve_s[1:])) if len(solve_s) > 1 else 0.0
                    compile_s[0] += max(time.perf_counter() - tg - typical, 0.0)
                    growths.append({"pass": desc, "frame": t, **{k: [getattr(before, k), getattr(grown, k)] for k in ("capacity", "max_chunks", "max_pairs")},
                                    "still_truncated": bool(truncated)})  # fmt: skip
            switched += int(second)
            if use_hands:
                known = (np.asarray(raw.hand_depth_seen) > 0) & anchors.anchored & ~np.isfinite(offset)
                if known.any():
                    z = surface_depths(tm, T, T_cam_obj, anchors)
                    for h in np.flatnonzero(known):
                        calib[h].append(z[h] - float(raw.hand_depth[h]))
                        if len(calib[h]) >= config.hand_depth_calibration:
                            offset[h] = float(np.median(calib[h]))
                anchors = update_hand_anchors(anchors, tm, T, T_cam_obj, obs, t, config.hand_anchor_cells,
                                                  anchor_by=config.hand_anchor_by)
            T_parts.append(T)
            obs_all.append(obs)
            residual.append(np.asarray(aux["part_residual"]))
            visible.append(np.asarray(aux["part_visible"]))
            losses.append(float(aux["loss"]))
            data.append(_data_loss(w, aux))
            bar.set_postfix(loss=f"{losses[-1]:.3g}")
            if log is not None and record:
                logged.append(("frame", t, {"T_obj_part": T, "T_cam_obj": T_cam_obj, "obs": obs, "aux": aux}))
        compile_s[0] += _first_call_excess(solve_s)
        return _Pass(T_parts, obs_all, residual, visible, losses, data, logged, switched, key, anchors)

    t_frames = time.perf_counter()
    joint_info: dict = {}
    candidates: list = []
    if use_joints:
        up = model.meta.get("support_plane") if config.support_plane is None else config.support_plane
        hands = None
        if use_hands and config.hinge_hands:
            pinch = [obsr.pinch_points(t, demo.frames[t]) for t in range(demo.num_frames)]
            hands = _HandTrack(np.stack([u for u, _ in pinch]), np.stack([s for _, s in pinch]),
                               np.asarray(T_cam_obj.wxyz_xyz, np.float64), K)  # fmt: skip
        tm, joint_info, key, candidates, first = _discover_joints(tm, neighbour, w, config, key, per_frame_pass,
                                                           None if up is None else np.asarray(up, np.float64)[:3], hands)  # fmt: skip
        timings["joint_pass_s"] = time.perf_counter() - t_frames
    if candidates:
        # slide hypotheses against `slide_baseline`; the kept pass is the winner's
        t_h = time.perf_counter()
        best, tm, chosen, trials = _slide_hypotheses(
            first, tm, candidates, config,
            lambda tm_k, k, nb, a, length, pair_mask, slot_pair: _with_slide(tm_k, k, nb, a, length, pair_mask, slot_pair, config.contact_pivots),
            lambda tm_h, desc, vh: per_frame_pass(tm_h, w, key, desc, vh=vh),
            frozenset(joint_info.get("hinges_ruled_out_by_hand", ())))  # fmt: skip
        for k, axis in chosen.items():
            joint_info[str(k)]["slide_axis"] = axis
        joint_info["slide_hypotheses"] = trials
        timings["slide_hypotheses_s"] = time.perf_counter() - t_h
    else:
        best = per_frame_pass(tm, w, key, "track")
    T_parts, obs_all, residual, visible, losses, key = best.T_parts, best.obs, best.residual, best.visible, best.loss, best.key
    for entry in best.logged:
        log(*entry)
    timings["frames_s"] = time.perf_counter() - t_frames
    timings["frame_compile_s"] = compile_s[0]

    # ---- joint temporal smoothing
    T_stack = jaxlie.SE3(jnp.stack([T.wxyz_xyz for T in T_parts]))
    t_sm = time.perf_counter()
    if config.smooth_iters > 0 and demo.num_frames > 2:
        obs_b = stack_obs(obs_all)
        delta = jnp.zeros(T_stack.wxyz_xyz.shape[:2] + (6,))
        opt = optax.adam(config.smooth_lr)
        state = opt.init(delta)
        rng = np.random.default_rng(config.seed)
        B = min(config.smooth_batch, demo.num_frames)
        sw = jnp.asarray(config.smooth_weight, jnp.float32)
        # the update's scale per part and coordinate (the root's 0 with `still_root`)
        scale = w.step_scale * (_held_root(w, tm.num_parts, True).part_step[:, None] if config.still_root and tm.num_parts > 1 else 1.0)
        step_s: list[float] = []
        for it in tqdm(range(config.smooth_iters), desc="smooth", disable=not progress):
            frames = jnp.asarray(rng.choice(demo.num_frames, B, replace=False), jnp.int32)
            key, sub = jax.random.split(key)
            ts = time.perf_counter()
            val, g = jax.block_until_ready(smooth_step(tm, delta, T_stack, T_cam_obj, obs_b, w, frames, sw, sub, rc[0], config.rank_pairs))
            step_s.append(time.perf_counter() - ts)
            g = jnp.where(jnp.isfinite(g), g, 0.0)
            upd, state = opt.update(g, state)
            delta = optax.apply_updates(delta, upd * scale)
        T_stack = compose_update(T_stack, delta, tm.part_pivots)
        timings["smooth_compile_s"] = _first_call_excess(step_s)
    timings["smooth_s"] = time.perf_counter() - t_sm
    timings["total_s"] = time.perf_counter() - t_start

    # tracking rate: per-frame passes (observation processing included) and smoothing, without
    # the one-off compilation of their jitted functions (reported apart, as `*_compile_s`)
    run_s = timings["frames_s"] + timings["smooth_s"] - timings["frame_compile_s"] - timings.get("smooth_compile_s", 0.0)
    T_obj_part = np.asarray(T_stack.wxyz_xyz, np.float64)
    T_co = jnp.broadcast_to(T_cam_obj.wxyz_xyz, (demo.num_frames, 7))
    rest_inv = rest.inverse()
    T_cwp = jaxlie.SE3(T_co[:, None]) @ T_stack @ jaxlie.SE3(jnp.broadcast_to(rest_inv.wxyz_xyz, T_stack.wxyz_xyz.shape))
    meta = {
        "num_frames": demo.num_frames,
        "num_parts": tm.num_parts,
        "video": str(demo.video_path),
        "fps": demo.fps,
        "part_centroids": np.asarray(tm.part_centroids).tolist(),
        "init": init_info,
        "timings_s": timings,
        "frames_per_second": demo.num_frames / max(run_s, 1e-9),
        "frames_per_second_with_compile": demo.num_frames / max(timings["frames_s"] + timings["smooth_s"], 1e-9),
        "render_budgets": {"capacity": rc[0].capacity, "max_chunks": rc[0].max_chunks, "max_pairs": rc[0].max_pairs},
        "render_budget_growths": growths,
        "occluder": getattr(obsr.occluder, "name", "?"),
        "mono_depth": getattr(obsr.mono, "name", "?"),
        "hand_depth_table": obsr.table_depth is not None,
        "fingertips": getattr(obsr.fingertips, "name", "?") if use_hands else "none",
        "hand_anchors": best.anchors.summary() if use_hands else [],
        "separable": separable,
        "support_plane": plane,
        "config": _config_dict(config),
        "joints": joint_info,
        "velocity_hypothesis_frames": best.switched,
        "init_config": _config_dict(init),
    }
    return PartTrajectory(
        T_obj_part=T_obj_part,
        T_cam_obj=np.asarray(T_co, np.float64),
        T_cam_world_part=np.asarray(T_cwp.wxyz_xyz, np.float64),
        residual=np.stack(residual).astype(np.float64),
        visible=np.stack(visible).astype(np.float64),
        loss=np.asarray(losses, np.float64),
        meta=meta,
    )


def _discover_joints(tm: TrackModel, neighbour: dict[int, int], w: Weights, config, key, per_frame_pass, up=None,
                     hands: _HandTrack | None = None):  # fmt: skip
    """`TrackConfig.joints`: first pass on the contact band (weak, saturating ARAP), joint points
    fitted from it, and the TrackModel of the second pass (tied at the joints, pivoting there;
    with `config.hinge_axes` also turning about a fitted axis; `up`: the support plane's normal,
    a candidate axis; `hands`: the pinch track, whose anchored hands also score the axes)."""
    slots = joint_slots(tm)
    ids = np.asarray(tm.gaussians.part_ids)
    pairs = np.asarray(tm.arap_pairs)
    is_slot = np.zeros(len(pairs), bool)
    is_slot[[p for _, _, p in slots.values()]] = True
    band_w = np.where(is_slot, 0.0, 1.0).astype(np.float32)
    means = np.asarray(tm.gaussians.means, np.float64)
    cents = np.asarray(tm.part_centroids, np.float64)
    P = tm.num_parts
    use = 1.0 if config.contact_pivots else 0.0  # contact_pivots=False: every part turns about its centroid
    tm_a = eqx.tree_at(lambda m: (m.arap_weight, m.part_pivots), tm,
                       (jnp.asarray(band_w), jnp.asarray(use * contact_pivots(means, ids, pairs, band_w, cents, P), jnp.float32)))  # fmt: skip
    w_a = eqx.tree_at(lambda x: (x.arap, x.arap_alpha, x.motion), w, (jnp.asarray(config.joint_first_arap, jnp.float32), jnp.asarray(-2.0, jnp.float32),
                                                                    jnp.asarray(config.joint_first_motion, jnp.float32)))  # fmt: skip
    steps = config.joint_first_steps or config.steps_per_frame
    lrs_a = lr_schedule(config.lr_start, config.lr_end, steps)
    first = per_frame_pass(tm_a, w_a, key, "track (joint pass)", record=False, lrs=lrs_a,
                           hold_root=config.still_root and config.still_root_first)
    key = first.key
    T_a = np.stack([np.asarray(T.wxyz_xyz) for T in first.T_parts])
    # how far the first pass moved the root's centroid from its frame-0 place (0 when it held it)
    root_moved = float(np.linalg.norm(T_a[:, 0, 4:] - T_a[:1, 0, 4:], axis=-1).max())
    # second pass: jointed parts tied only at their joint; others keep the weak band
    weak = config.joint_first_arap / max(float(config.weights.arap), 1e-12)
    pw = np.where(is_slot, 0.0, weak).astype(np.float32)
    info = {}
    candidates: list = []
    hinges: list = []
    hand_ref: dict[int, tuple] = {}  # part -> (hand, held part, other part, frames, chosen hinge's pixel residual)
    slot_gaussian = np.zeros(len(means), bool)
    slot_gaussian[[x for i, j, _ in slots.values() for x in (i, j)]] = True
    for k, (i, j, p) in slots.items():
        nb = neighbour.get(k)
        X = None if nb is None else fit_joint_point(T_a, cents, k, nb, means[i], config.joint_min_angle_deg)
        info[str(k)] = {"neighbour": nb, "point": None if X is None else [float(v) for v in X]}
        mine = ((ids[pairs[:, 0]] == k) & (ids[pairs[:, 1]] == nb)) | ((ids[pairs[:, 1]] == k) & (ids[pairs[:, 0]] == nb))
        part = means[(ids == k) & ~slot_gaussian]
        radius = float(np.percentile(np.linalg.norm(part - cents[k], axis=1), 90))
        if nb is not None and config.slides and is_slide_candidate(T_a, cents, X, means[i], k, nb, radius, config.slide_min_m, config.slide_point_ratio):
            candidates.append((k, nb, radius, slide_directions(part, cents[k] - cents[nb], up), mine & ~is_slot, p))
        if X is None:
            continue
        means[i] = means[j] = X
        pw[p] = 1.0
        pw[mine & ~is_slot] = 0.0
        if config.hinge_axes:
            cand = slide_axes(part) if up is None else np.concatenate([slide_axes(part), [up / np.linalg.norm(up)]])
            hand_px = None
            h = _hand_on(first.anchors, (k, nb)) if hands is not None else None
            if h is not None:
                held = int(first.anchors.part[h])
                other = nb if held == k else k
                f = np.arange(int(first.anchors.frame[h]), len(T_a))
                f = f[hands.seen[f, h]]
                if len(f):
                    hand_px = hand_hinge_residual(T_a, cents, held, other, X, cents[held] + first.anchors.point[h],
                                                  hands.T_cam_obj, hands.intrinsics, hands.pinch_uv[:, h], f, cand)  # fmt: skip
                    info[str(k)]["hinge_hand_px"] = np.round(hand_px, 2).tolist()
            a, rms = hinge_axis(T_a, cents, k, nb, X, part, cand, prefer_last=0.0 if up is None else config.hinge_up_tolerance,
                                hand_px=hand_px, refine_deg=config.hinge_refine_deg)  # fmt: skip
            if config.hinge_refine_deg:  # how far the refinement turned the chosen candidate
                cu = cand / np.linalg.norm(cand, axis=1, keepdims=True)
                info[str(k)]["hinge_refined_deg"] = round(float(np.degrees(np.arccos(min(1.0, float(np.max(np.abs(cu @ a))))))), 2)
            if hand_px is not None:
                hand_ref[k] = (h, held, other, f, float(hand_px[int(np.argmax(np.abs(cand @ a)))]))
            hinges.append((k, nb, a, radius))
            info[str(k)].update(hinge_axis=[float(v) for v in a], hinge_candidates=np.round(cand, 4).tolist(),
                                hinge_rms_mm=np.round(1e3 * rms, 2).tolist())  # fmt: skip
    held = sorted({int(k) for k in first.anchors.part[first.anchors.anchored]})
    if config.slide_held_only and held:
        # a hand moves what it holds: a part nobody held that seemed to slide in the first pass
        # (its few-mm drift, a static limb) gets no slide hypothesis
        info["slide_candidates_not_held"] = [int(c[0]) for c in candidates if c[0] not in held]
        candidates = [c for c in candidates if c[0] in held]
    if config.slide_max_turn_deg is not None:
        # a part the first pass turned through a wide angle relative to its neighbour is hinged:
        # a slide's first pass turns it by a few degrees (`slide_max_turn_deg`); a part whose
        # pinch track judges its slides (`slide_hand_ratio`) is left to the hand
        judged = hand_ref if config.slide_hand_ratio is not None else {}
        kept = []
        for c in candidates:
            turn = float(relative_turn_deg(T_a, c[0], c[1]).max())
            info[str(c[0])]["first_turn_deg"] = round(turn, 2)
            if turn <= config.slide_max_turn_deg or c[0] in judged:
                kept.append(c)
            else:
                info.setdefault("slide_candidates_turned", []).append(int(c[0]))
        candidates = kept
    hinge_out: set[int] = set()
    if config.slide_hand_ratio is not None and hand_ref:
        kept = []
        for k, nb, radius, dirs, mask, p in candidates:
            if k not in hand_ref:
                kept.append((k, nb, radius, dirs, mask, p))
                continue
            h, held, other, f, hinge_px = hand_ref[k]
            px = hand_slide_residual(T_a, cents, held, other, cents[held] + first.anchors.point[h], hands.T_cam_obj,
                                     hands.intrinsics, hands.pinch_uv[:, h], f, dirs)  # fmt: skip
            ok = px <= config.slide_hand_ratio * hinge_px + SLIDE_HAND_FLOOR_PX
            if config.slide_hand_best is not None and ok.sum() > config.slide_hand_best:
                # only the directions the pinch track fits best
                ok &= px <= np.sort(px[ok])[config.slide_hand_best - 1]
            info[str(k)]["slide_hand_px"] = np.round(px, 2).tolist()
            if ok.any() and hinge_px > config.slide_hand_ratio * float(px[ok].min()) + SLIDE_HAND_FLOOR_PX:
                # the converse: a slide fits the pinch track far better than the hinge, which the
                # first pass (the baseline) does not stand for: the best slide wins outright
                info[str(k)]["hinge_ruled_out_by_hand"] = True
                hinge_out.add(int(k))
            if ok.any():
                kept.append((k, nb, radius, dirs[ok], mask, p))
            else:
                info.setdefault("slide_candidates_ruled_out_by_hand", []).append(int(k))
        candidates = kept
    g = eqx.tree_at(lambda x: x.means, tm.gaussians, jnp.asarray(means, jnp.float32))
    piv = contact_pivots(means, ids, pairs, pw, cents, P, root_too=P == 2 and any(info[str(k)]["point"] is not None for k in slots))
    tm_b = eqx.tree_at(lambda m: (m.gaussians, m.arap_weight, m.part_pivots), tm,
                       (g, jnp.asarray(pw), jnp.asarray(use * piv, jnp.float32)))  # fmt: skip
    if hinges:
        tm_b = eqx.tree_at(lambda m: (m.hinge_parts, m.hinge_axes, m.hinge_lengths, m.hinge_weight), tm_b, (
            jnp.asarray([[k, nb] for k, nb, _, _ in hinges], jnp.int32), jnp.asarray([a for _, _, a, _ in hinges], jnp.float32),
            jnp.asarray([r for *_, r in hinges], jnp.float32), jnp.ones(len(hinges), jnp.float32)))  # fmt: skip
    info["hinges_ruled_out_by_hand"] = sorted(hinge_out)
    info["first_root_moved_mm"] = round(1e3 * root_moved, 3)
    return tm_b, info, key, candidates, first


def _hand_on(anchors, parts) -> int | None:
    """The first hand anchored on one of `parts`, or None."""
    for h, p in enumerate(anchors.part):
        if int(p) in parts:
            return h
    return None


def _slide_hypotheses(first, tm, candidates, config: TrackConfig, with_slide, run_pass, hinge_out=frozenset()):
    """The second pass with slide hypotheses (`TrackConfig.slides`): each candidate's slides are
    tracked (`_choose_slides`) against the baseline `TrackConfig.slide_baseline` names, the first
    pass ("first") or a pass on the joint point with the hypotheses' starts ("joint"); when no
    slide wins, the joint point is tracked with `velocity_hypothesis` (what a second pass without
    candidates does).

    Args:
        first: the joint discovery's first pass (a `_Pass`).
        tm: the second pass's model (joint points, hinge axes).
        candidates: as `_choose_slides` takes them.
        config: the tracking options.
        with_slide: as `_choose_slides` takes it.
        run_pass: `(tm, description, velocity hypothesis) -> _Pass`, one per-frame pass.
        hinge_out: as `_choose_slides` takes it.

    Returns:
        (the kept pass, its model, {part: winning axis}, the trials as `_choose_slides` gives
        them; their first entry, the baseline's, names its pass under "pass").
    """
    vh = config.velocity_hypothesis if config.slide_velocity is None else config.slide_velocity
    base = first if config.slide_baseline == "first" else run_pass(tm, "track", vh)
    best, tm_s, chosen, trials = _choose_slides(base, tm, candidates, config.slide_min_gain, with_slide,
                                                lambda tm_h, k: run_pass(tm_h, f"track (slide {k} hypothesis)", vh),
                                                hinge_out)  # fmt: skip
    trials[0]["pass"] = config.slide_baseline
    if chosen:
        return best, tm_s, chosen, trials
    if base is first or vh != config.velocity_hypothesis:
        base = run_pass(tm, "track", config.velocity_hypothesis)
    return base, tm, chosen, trials


def _choose_slides(best, tm, candidates, min_gain: float, with_slide, run_pass, hinge_out=frozenset()):
    """The slide hypotheses' choice (`TrackConfig.slides`).

    Each candidate part in turn (the other parts as chosen so far) is tracked on a slide along
    each of its axes; a hypothesis wins when its summed data loss is below the best so far by
    more than the fraction `min_gain`. A part's axes are alternatives: each is tried on the model
    as it was before the part's candidates (without an earlier winning axis of the same part),
    and compared with the best pass so far, that winner included.

    Args:
        best: the pass to beat (a `_Pass`; its `data_loss` is summed).
        tm: the model of that pass.
        candidates: `(k, nb, length, axes, pair_mask, slot_pair)` per candidate part.
        min_gain: `TrackConfig.slide_min_gain`.
        with_slide: `(tm, k, nb, axis, length, pair_mask, slot_pair) -> tm` (`_with_slide`).
        run_pass: `(tm, k) -> _Pass`, one per-frame pass on a hypothesis for part k.
        hinge_out: parts whose hinge the hand's pinch track ruled out (`slide_hand_ratio`): of
            their axes the one with the lowest data loss wins, whatever the pass to beat.

    Returns:
        (best pass, its model, {part: winning axis}, the trials: part, axis and data loss of the
        pass to beat and of each hypothesis, in order).
    """
    trials = [{"part": None, "axis": None, "data_loss": float(np.sum(best.data_loss))}]
    chosen: dict[int, list[float]] = {}
    for k, nb, length, axes, pair_mask, slot_pair in candidates:
        tm_k, own = tm, None  # own: the best slide of a part whose hinge the hand ruled out
        for a in axes:
            tm_h = with_slide(tm_k, k, nb, a, length, pair_mask, slot_pair)
            res = run_pass(tm_h, k)
            trials.append({"part": int(k), "axis": [float(v) for v in a], "data_loss": float(np.sum(res.data_loss))})
            if int(k) in hinge_out:
                if own is None or trials[-1]["data_loss"] < own[2]:
                    own = (res, tm_h, trials[-1]["data_loss"], trials[-1]["axis"])
            elif trials[-1]["data_loss"] < (1.0 - min_gain) * float(np.sum(best.data_loss)):
                best, tm = res, tm_h
                chosen[int(k)] = trials[-1]["axis"]
        if own is not None:
            best, tm, chosen[int(k)] = own[0], own[1], own[3]
    return best, tm, chosen, trials


def _held_root(w: Weights, num_parts: int, held: bool) -> Weights:
    """`w` with a step multiplier per part (`Weights.part_step`): 1 for every part, or 0 for the
    root when `held` (`TrackConfig.still_root`)."""
    step = jnp.ones(num_parts, jnp.float32)
    return eqx.tree_at(lambda v: v.part_step, w, step.at[0].set(0.0) if held else step, is_leaf=lambda x: x is None)


def _data_loss(w, aux) -> float:
    """The data terms of a frame's final loss (what hypotheses compare)."""
    return float(w.feature * aux["feature"] + w.rgb * aux["rgb"] + w.depth_rank * aux["rank"] + w.hand * aux["hand"]
                 + w.hand_depth * aux["hand_depth"])


def _with_slide(tm: TrackModel, k: int, nb: int, axis, length: float, pair_mask, slot_pair: int, use_pivots: bool) -> TrackModel:
    """`tm` with part k tied to `nb` by a slide joint along `axis` instead of its joint point or
    contact band (their ARAP pairs `pair_mask` and `slot_pair` weighted 0)."""
    pw = np.asarray(tm.arap_weight).copy()
    pw[pair_mask] = 0.0
    pw[slot_pair] = 0.0
    # pivots as `_discover_joints` sets them for these pair weights (k's: its centroid)
    slot_pairs = [q for _, _, q in joint_slots(tm).values()]
    P = tm.num_parts
    piv = contact_pivots(np.asarray(tm.gaussians.means, np.float64), np.asarray(tm.gaussians.part_ids), np.asarray(tm.arap_pairs),
                         pw, np.asarray(tm.part_centroids, np.float64), P, root_too=P == 2 and bool((pw[slot_pairs] > 0).any()))  # fmt: skip
    piv = piv if use_pivots else 0 * piv
    # a sliding part has no hinge axis in this hypothesis
    hw = np.where(np.asarray(tm.hinge_parts)[:, 0] == k, 0.0, np.asarray(tm.hinge_weight)).astype(np.float32)
    tm = eqx.tree_at(lambda m: m.hinge_weight, tm, jnp.asarray(hw))
    entry = (np.asarray([[k, nb]]), np.asarray([axis]), np.asarray([length]), np.ones(1))
    old = (np.asarray(tm.slide_parts), np.asarray(tm.slide_axes), np.asarray(tm.slide_lengths), np.asarray(tm.slide_weight))
    keep = old[3] > 0
    new = [np.concatenate([o[keep], e]) for o, e in zip(old, entry)]
    dts = (jnp.int32, jnp.float32, jnp.float32, jnp.float32)
    return eqx.tree_at(lambda m: (m.arap_weight, m.part_pivots, m.slide_parts, m.slide_axes, m.slide_lengths, m.slide_weight), tm,
                       (jnp.asarray(pw), jnp.asarray(piv, jnp.float32), *[jnp.asarray(x, dt) for x, dt in zip(new, dts)]))  # fmt: skip


def _support_plane(model, config: TrackConfig) -> list[float]:
    """The support term's plane: the config's, else the model's `meta["support_plane"]` (the
    build fits it to the scan's table when the scan has depth and masks). Called only with the
    term on: without a plane that is an error, not a silently inactive term."""
    plane = config.support_plane if config.support_plane is not None else model.meta.get("support_plane")
    if plane is None:
        raise ValueError("weights.support > 0 needs a support plane: TrackConfig.support_plane, or a model built "
                         "from a scan with depth and masks (meta['support_plane'])")
    plane = [float(v) for v in plane]
    if len(plane) != 4 or not np.all(np.isfinite(plane)) or abs(np.linalg.norm(plane[:3]) - 1) > 1e-3:
        raise ValueError(f"support_plane: expected (nx, ny, nz, d) with a unit normal, got {plane}")
    return plane


def _first_call_excess(times: list[float]) -> float:
    """Compilation estimate of a jitted function called repeatedly: its first call's time minus
    the median of the others (0 with fewer than two calls)."""
    if len(times) < 2:
        return 0.0
    return max(times[0] - float(np.median(times[1:])), 0.0)


def _config_dict(cfg) -> dict:
    out = {}
    for k in cfg.__dataclass_fields__:
        v = getattr(cfg, k)
        out[k] = _config_dict(v) if hasattr(v, "__dataclass_fields__") else v
    return out
