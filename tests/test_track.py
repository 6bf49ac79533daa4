"""Tracking on a small studio object: compile-once per video, outputs, evaluation, bad inputs.

The GT-geometry model (`tests/_gt_model.py`) isolates tracking from 3DGS fitting.
"""

import dataclasses
from pathlib import Path

import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from rsrd_jax.io import ArtefactError, load_trajectory, read_demo, read_demo_gt, save_trajectory
from rsrd_jax.splat import rest_part_poses
from rsrd_jax.studio import StudioConfig, make_object
from rsrd_jax.track import InitConfig, StudioDepthOracle, StudioHandMasks, TrackConfig, add_metrics, initialize_demo, kabsch, track_video
from rsrd_jax.track import _dpm, _init

from ._gt_model import gt_object_model

TINY = TrackConfig(roi_size=96, steps_per_frame=8, smooth_iters=2, smooth_batch=2, rank_pairs=256, max_gaussians=1500)
TINY_INIT = InitConfig(yaw_seeds=8, altitudes_deg=(35.0,), iters=8, refine_iters=4, match_gaussians=500)


@pytest.fixture(scope="module")
def studio(tmp_path_factory):
    root = tmp_path_factory.mktemp("trk") / "nerf_gun"
    make_object("nerf_gun", root, StudioConfig(scan_views=6, scan_size=(96, 72), demo_frames=4, demo_size=(128, 96), parts=("scan", "demo")))
    model, ext = gt_object_model(root, pca_dim=16, per_part=300, field_iters=30)
    return root, model, ext


def test_track_compiles_once_and_writes_a_valid_trajectory(studio, tmp_path):
    root, model, ext = studio
    demo = read_demo(root / "demo" / "demo.mp4")
    before, seeds_before = _dpm._trace_counts["frame"], _init._trace_counts["seeds"]
    traj = track_video(model, demo, TINY, TINY_INIT, StudioHandMasks(root / "demo"), StudioDepthOracle(root / "demo"),
                       extractor=ext, progress=False)  # fmt: skip
    # once per video (plus once per widening of the render budgets, `render_headroom`)
    growths = len(traj.meta["render_budget_growths"])
    assert _dpm._trace_counts["frame"] - before == 1 + growths, "the per-frame solve must compile once per video"
    # the initialiser's stages (seeds, survivors, ROI refinement) share one compiled optimiser; a
    # second compile only when the ROI crop at the best pose needs a larger render budget than the
    # seeds' ROI crops measured beforehand (at this tiny size it may: a 3×3-tile grid; at pipeline
    # sizes it did not on five demos since the crop's need is compared without the margins)
    widened = traj.meta["init"]["render_config_widened_for_roi"]
    assert _init._trace_counts["seeds"] - seeds_before == 1 + int(widened)
    assert len(traj.meta["init"]["refined_losses"]) == TINY_INIT.keep_seeds
    assert traj.T_obj_part.shape == (4, 2, 7) and traj.T_cam_obj.shape == (4, 7)
    assert np.all(np.isfinite(traj.T_cam_world_part)) and np.all(traj.visible >= 0)
    assert "studio relative-depth ORACLE" in traj.meta["mono_depth"]
    # the initialisation alone (`initialize_demo`, for evaluating it) gives the pose tracking started from
    T_init, info = initialize_demo(model, demo, TINY, TINY_INIT, StudioHandMasks(root / "demo"),
                                   StudioDepthOracle(root / "demo"), extractor=ext)  # fmt: skip
    np.testing.assert_allclose(np.asarray(T_init.wxyz_xyz), traj.T_cam_obj[0], atol=1e-5)
    assert info["init_s"] > 0 and info["best_seed"] == traj.meta["init"]["best_seed"]
    # compilation is reported apart from the tracking rate (the first solve compiles)
    ts = traj.meta["timings_s"]
    assert ts["frame_compile_s"] > 0.5 * ts["frames_s"] > 0
    assert traj.meta["frames_per_second"] > traj.meta["frames_per_second_with_compile"]
    save_trajectory(traj, tmp_path / "t")
    back = load_trajectory(tmp_path / "t")
    np.testing.assert_allclose(back.T_obj_part, traj.T_obj_part)
    # the evaluation interface: T_cam_world_part = T_cam_obj · T_obj_part · rest⁻¹
    rest = rest_part_poses(model.part_centroids)
    T = jaxlie.SE3(jnp.asarray(traj.T_cam_obj[:, None], jnp.float32)) @ jaxlie.SE3(jnp.asarray(traj.T_obj_part, jnp.float32)) @ rest.inverse()
    np.testing.assert_allclose(np.asarray(T.as_matrix()), np.asarray(jaxlie.SE3(jnp.asarray(traj.T_cam_world_part, jnp.float32)).as_matrix()), atol=1e-4)


def test_add_is_zero_for_ground_truth_and_kabsch_recovers_transform(studio, rng):
    root, model, _ = studio
    gt = read_demo_gt(root / "demo")
    pts = [model.part_points(k) if hasattr(model, "part_points") else np.asarray(model.gaussians.means)[np.asarray(model.gaussians.part_ids) == k] for k in range(model.num_parts)]
    m = add_metrics(gt["T_cam_world_part"], gt["T_cam_world_part"], pts)
    assert m["mean_add_mm"] == pytest.approx(0.0, abs=1e-3) and m["mean_add_obj_mm"] == pytest.approx(0.0, abs=1e-3)
    # a global offset of the whole object is an ADD error in the camera frame but not in the object frame
    shifted = gt["T_cam_world_part"].copy()
    shifted[..., 6] += 0.01
    m = add_metrics(shifted, gt["T_cam_world_part"], pts)
    assert m["mean_add_mm"] == pytest.approx(10.0, abs=0.05) and m["mean_add_obj_mm"] < 0.05
    A = np.asarray(jaxlie.SE3.exp(jnp.array([0.1, -0.2, 0.05, 0.3, 0.1, -0.2])).as_matrix(), np.float64)
    src = rng.normal(size=(50, 3))
    np.testing.assert_allclose(kabsch(src, src @ A[:3, :3].T + A[:3, 3]), A, atol=1e-6)


def test_bad_inputs(studio, tmp_path):
    root, model, ext = studio
    demo = read_demo(root / "demo" / "demo.mp4")
    wrong = dataclasses.replace(model) if dataclasses.is_dataclass(model) else model
    with pytest.raises(ArtefactError, match="feature backend mismatch"):
        from rsrd_jax.features import EfficientNetConfig, EfficientNetExtractor

        track_video(wrong, demo, TINY, TINY_INIT, extractor=EfficientNetExtractor.pretrained(EfficientNetConfig(strides=(8,))), progress=False)
    empty = dataclasses.replace(demo, frames=demo.frames[:0])
    with pytest.raises(ArtefactError, match="no frames"):
        track_video(model, empty, TINY, TINY_INIT, extractor=ext, progress=False)
    for bad in (0.0, 90.0, float("nan")):  # an option out of range, refused before any work
        with pytest.raises(ValueError, match="hinge_refine_deg"):
            track_video(model, demo, dataclasses.replace(TINY, hinge_refine_deg=bad), TINY_INIT, extractor=ext, progress=False)
    with pytest.raises(ArtefactError, match="hand masks not found"):
        StudioHandMasks(tmp_path)
    with pytest.raises(ArtefactError, match="trajectory not found"):
        load_trajectory(tmp_path)


# ------------------------------------------------------------------ known motions, init, bad inputs
def _render_demo(model, T_cwp: np.ndarray, K, bg=(0.55, 0.5, 0.45)) -> np.ndarray:
    """Frames of the model's Gaussians with part k at `T_cwp[t, k]` (scan world -> camera)."""
    from rsrd_jax.geometry import Camera
    from rsrd_jax.splat import apply_part_poses, choose_config, render

    g = model.gaussians
    rest = rest_part_poses(model.part_centroids)
    cam = Camera(K, jaxlie.SE3.identity())
    posed = [apply_part_poses(g, jaxlie.SE3(jnp.asarray(T, jnp.float32)) @ rest, model.part_centroids) for T in T_cwp]
    cfg = choose_config(posed[0], cam, headroom=2.0)
    frames = [np.asarray(render(p, cam, cfg, jnp.asarray(bg, jnp.float32)).rgb) for p in posed]
    return (np.clip(np.stack(frames), 0, 1) * 255).astype(np.uint8)


def _object_motion(T0: np.ndarray, centre_cam: np.ndarray, n: int, yaw: float, shift: np.ndarray) -> np.ndarray:
    """n frames of a rigid motion of the whole object: rotation about the camera's y axis through
    the object centre, up to `yaw` rad, plus a translation up to `shift` (camera frame, m)."""
    out = []
    for t in range(n):
        s = t / max(n - 1, 1)
        M = jaxlie.SE3.from_translation(jnp.asarray(centre_cam + s * shift, jnp.float32)) @ jaxlie.SE3.from_rotation(
            jaxlie.SO3.from_y_radians(s * yaw)) @ jaxlie.SE3.from_translation(jnp.asarray(-centre_cam, jnp.float32))  # fmt: skip
        out.append(np.asarray((M @ jaxlie.SE3(jnp.asarray(T0, jnp.float32))).wxyz_xyz))
    return np.stack(out)


def _track_synthetic(model, ext, T_cwp, K, cfg, known_init: bool):
    from rsrd_jax.io import Demo

    frames = _render_demo(model, T_cwp, K)
    demo = Demo(Path("synthetic.mp4"), frames, 30.0, K)
    T0 = jaxlie.SE3(jnp.asarray(T_cwp[0, 0], jnp.float32)) if known_init else None
    traj = track_video(model, demo, cfg, TINY_INIT, extractor=ext, progress=False, T_cam_obj_init=T0)
    pts = [np.asarray(model.gaussians.means)[np.asarray(model.gaussians.part_ids) == k] for k in range(model.num_parts)]
    return add_metrics(traj.T_cam_world_part, T_cwp, pts), traj


RIGID_TOL_MM = 4.0
"""ADD (object-frame alignment on frame 0) tolerance of the synthetic known-motion tests."""


def test_velocity_hypothesis_keeps_the_lower_loss(studio):
    """With a second start per frame (full constant velocity), frames 0–1 are tracked as without
    it (same observations and pair samples), and frame 2's loss, the first frame with two starts,
    is the lower of the two: never above the single start's."""
    root, model, ext = studio
    demo = read_demo(root / "demo" / "demo.mp4")
    cfg = dataclasses.replace(TINY, smooth_iters=0)
    run = lambda c: track_video(model, demo, c, TINY_INIT, StudioHandMasks(root / "demo"), StudioDepthOracle(root / "demo"),  # noqa: E731
                                extractor=ext, progress=False)  # fmt: skip
    one = run(cfg)
    two = run(dataclasses.replace(cfg, velocity_hypothesis=1.0))
    np.testing.assert_allclose(two.loss[:2], one.loss[:2], rtol=1e-5)
    assert two.loss[2] <= one.loss[2] * (1 + 1e-6), (one.loss, two.loss)
    assert 0 <= two.meta["velocity_hypothesis_frames"] <= demo.num_frames - 2
    assert one.meta["velocity_hypothesis_frames"] == 0
    # the two starts solved one after the other instead of at once: the same trajectory
    seq = run(dataclasses.replace(cfg, velocity_hypothesis=1.0, parallel_starts=False))
    np.testing.assert_allclose(seq.T_obj_part, two.T_obj_part, atol=1e-6)
    np.testing.assert_allclose(seq.loss, two.loss, rtol=1e-6)


def test_rebinning_every_few_steps_tracks_as_binning_every_step(studio):
    """`TrackConfig.rebin_every`: the steps between two binnings render on stale per-tile lists;
    the tracked points end within a fraction of a video pixel's footprint at the object (what
    the observations resolve) of where binning every step puts them, and the frames' final
    losses (binned afresh) agree. Measured: the parts moved 2.86 mm; 5 against 1 ended 0.65 mm
    apart at most on session 44's machine (2 cores; another machine's XLA code gave < 0.29 mm),
    where moving the initial pose by 0.1 mm moves the solved points by 0.07 mm."""
    root, model, ext = studio
    demo = read_demo(root / "demo" / "demo.mp4")
    T0 = jaxlie.SE3(jnp.asarray(read_demo_gt(root / "demo")["T_cam_world_part"][0, 0], jnp.float32))
    # 15 steps: a solve no other test of this module compiles (several assert their own compile)
    cfg = dataclasses.replace(TINY, smooth_iters=0, steps_per_frame=15, joints=False)
    run = lambda c: track_video(model, demo, c, TINY_INIT, StudioHandMasks(root / "demo"), StudioDepthOracle(root / "demo"),  # noqa: E731
                                extractor=ext, progress=False, T_cam_obj_init=T0)  # fmt: skip
    every, fifth = run(dataclasses.replace(cfg, rebin_every=1)), run(dataclasses.replace(cfg, rebin_every=5))
    means = np.asarray(model.gaussians.means)
    pts = lambda tr: np.stack([np.asarray(jaxlie.SE3(jnp.asarray(T, jnp.float32)).apply(jnp.asarray(means)))  # noqa: E731
                               for T in tr.T_cam_world_part.reshape(-1, 7)])  # fmt: skip
    moved = np.linalg.norm(pts(every) - np.tile(pts(every)[: model.num_parts], (demo.num_frames, 1, 1)), axis=-1).max()
    apart = np.linalg.norm(pts(fifth) - pts(every), axis=-1).max()
    pixel = float(T0.translation()[2]) / demo.intrinsics.fy  # a video pixel's footprint at the object (m)
    assert moved > 2e-3 and apart < 0.25 * pixel, (moved, apart, pixel)
    np.testing.assert_allclose(fifth.loss, every.loss, rtol=0.02)
    for bad in (0, -1):
        with pytest.raises(ValueError, match="rebin_every"):
            run(dataclasses.replace(cfg, rebin_every=bad))


def test_render_budgets_too_small_for_a_frame_are_widened_and_the_frame_solved_again(studio, monkeypatch):
    """Frame 0's render budgets deliberately far too small (every tile truncated): the render says
    so, the tracker widens the budgets at the frame's solved pose and solves it again, and the
    trajectory is the one tracked with generous budgets throughout."""
    from rsrd_jax.splat import RenderConfig
    from rsrd_jax.track import _track

    root, model, ext = studio
    demo = read_demo(root / "demo" / "demo.mp4")
    cfg = dataclasses.replace(TINY, smooth_iters=0)
    T0 = jaxlie.SE3(jnp.asarray(read_demo_gt(root / "demo")["T_cam_world_part"][0, 0], jnp.float32))
    run = lambda c: track_video(model, demo, c, TINY_INIT, StudioHandMasks(root / "demo"), StudioDepthOracle(root / "demo"),  # noqa: E731
                                extractor=ext, progress=False, T_cam_obj_init=T0)  # fmt: skip
    generous = run(dataclasses.replace(cfg, render_headroom=3.0))
    assert generous.meta["render_budget_growths"] == []
    chosen = _track.choose_config
    calls = []

    def tiny_first(*a, **k):  # the first choice (frame 0's budgets) too small; later ones as usual
        calls.append(1)
        return RenderConfig(capacity=32, max_chunks=8, max_pairs=1024) if len(calls) == 1 else chosen(*a, **k)

    monkeypatch.setattr(_track, "choose_config", tiny_first)
    grown = run(cfg)
    growths = grown.meta["render_budget_growths"]
    assert [g["frame"] for g in growths] == [0] and not growths[0]["still_truncated"], growths
    assert growths[0]["capacity"][0] == 32 < growths[0]["capacity"][1] and growths[0]["max_chunks"][0] == 8 < growths[0]["max_chunks"][1]
    np.testing.assert_allclose(grown.T_obj_part, generous.T_obj_part, atol=2e-4)
    np.testing.assert_allclose(grown.loss, generous.loss, rtol=1e-3)
    with pytest.raises(ValueError, match="render_headroom"):
        run(dataclasses.replace(cfg, render_headroom=0.9))


@pytest.mark.xfail(strict=True, reason="KNOWN FAILURE (issue 5): at this tiny size (12×12 ROI grid, 1500 Gaussians, "
                   "30-iteration field) tracking a synthetic 2.3°+3 mm/frame motion ends 12.5/8.7 mm off, worse than "
                   "standing still (10.4 mm); strict: remove this marker when it passes")
def test_track_recovers_a_known_rigid_motion(studio):
    root, model, ext = studio
    gt = read_demo_gt(root / "demo")
    demo = read_demo(root / "demo" / "demo.mp4")
    T0 = gt["T_cam_world_part"][0, 0]
    c = np.asarray(jaxlie.SE3(jnp.asarray(T0, jnp.float32)) @ jnp.asarray(np.asarray(model.gaussians.means).mean(0)))
    T = _object_motion(T0, c, 7, yaw=0.24, shift=np.array([0.018, 0.0, 0.0]))
    T_cwp = np.repeat(T[:, None], model.num_parts, axis=1)
    cfg = dataclasses.replace(TINY, steps_per_frame=40, smooth_iters=0)
    m, _ = _track_synthetic(model, ext, T_cwp, demo.intrinsics, cfg, known_init=True)
    # 2.3° and 3 mm per frame; not following at all would give this much error:
    still = add_metrics(np.repeat(T_cwp[:1], len(T_cwp), 0), T_cwp, [np.asarray(model.gaussians.means)])["mean_add_obj_mm"]
    assert max(m["add_obj_mm"]) < RIGID_TOL_MM < still / 2, (m["add_obj_mm"], still)


@pytest.mark.slow
def test_track_recovers_a_known_hinge_motion(tmp_path):
    """The red box's lid closes about its hinge (studio ground truth, 1.1 rad over 12 frames)."""
    root = tmp_path / "red_box"
    make_object("red_box", root, StudioConfig(scan_views=8, scan_size=(128, 96), demo_frames=40, demo_size=(160, 120), parts=("scan", "demo")))
    model, ext = gt_object_model(root, pca_dim=16, per_part=600, field_iters=60)
    gt = read_demo_gt(root / "demo")
    demo = read_demo(root / "demo" / "demo.mp4")
    T_cwp = gt["T_cam_world_part"][6:30:2]
    rel = jaxlie.SE3(jnp.asarray(T_cwp[:, 0], jnp.float32)).inverse() @ jaxlie.SE3(jnp.asarray(T_cwp[:, 1], jnp.float32))
    angle = np.linalg.norm(np.asarray(rel.rotation().log()), axis=-1)
    assert angle.max() - angle.min() > 0.8  # the lid really turns
    cfg = dataclasses.replace(TINY, steps_per_frame=40, smooth_iters=0, roi_size=128)
    m, _ = _track_synthetic(model, ext, T_cwp, demo.intrinsics, cfg, known_init=True)
    lid_still = add_metrics(np.repeat(T_cwp[:1, 1:], len(T_cwp), 0), T_cwp[:, 1:], [np.asarray(model.gaussians.means)[np.asarray(model.gaussians.part_ids) == 1]])
    assert lid_still["mean_add_obj_mm"] > 15.0
    assert max(m["add_obj_mm"]) < 2 * RIGID_TOL_MM, m["add_obj_mm"]
    print("hinge ADD per part (mm):", m["add_obj_mm"], "lid still:", lid_still["mean_add_obj_mm"])


@pytest.mark.parametrize("seed", [0, pytest.param(3, marks=pytest.mark.slow),
                                  pytest.param(5, marks=pytest.mark.slow)])  # fmt: skip
def test_init_recovers_a_yaw_from_each_seed_basin(studio, seed):
    """The object turned by a seed's yaw + 20° (inside that seed's basin, away from the others'
    optimum at the true pose only if the optimisation works): init finds it within 15°, where the
    neighbouring seeds' basins lie 45° apart (a pose from another basin is ≥ 25° off). At this
    tiny size the optimum is coarse and moves with the CPU's float rounding: 12.3° for seed 0 on
    session 49's machine (the same code gave < 12° before)."""
    from rsrd_jax.track import initialize_pose
    from rsrd_jax.track._dpm import TrackModel
    from rsrd_jax.track._observe import Observer, full_frame_box
    from rsrd_jax.track._track import _roi_for

    root, model, ext = studio
    gt = read_demo_gt(root / "demo")
    K = read_demo(root / "demo" / "demo.mp4").intrinsics
    tm = TrackModel.from_object_model(model, 1500)
    T0 = jaxlie.SE3(jnp.asarray(gt["T_cam_world_part"][0, 0], jnp.float32))
    c = tm.gaussians.means.mean(0)
    yaw = seed * 2 * np.pi / TINY_INIT.yaw_seeds + np.deg2rad(20.0)
    # turn the object about its own vertical (object z) axis through its centroid
    Rz = jaxlie.SE3.from_translation(c) @ jaxlie.SE3.from_rotation(jaxlie.SO3.from_z_radians(yaw)) @ jaxlie.SE3.from_translation(-c)
    T_true = T0 @ Rz
    frame = _render_demo(model, np.repeat(np.asarray(T_true.wxyz_xyz)[None, None], model.num_parts, 1), K)[0]
    obsr = Observer(ext, model.pca, K, TINY.roi_size)
    rest = rest_part_poses(tm.part_centroids)
    cfg = dataclasses.replace(TINY_INIT, iters=40, refine_iters=10, altitudes_deg=(30.0, 55.0))
    res, info = initialize_pose(tm, lambda b: obsr.observe(0, frame, b), frame, K, cfg, full_frame_box(K.width, K.height),
                                lambda T: _roi_for(tm, rest, T, K, TINY.roi_margin))  # fmt: skip
    err = np.rad2deg(float(jnp.linalg.norm((T_true.rotation().inverse() @ res.T_cam_obj.rotation()).log())))
    assert err < 15.0, (err, info)


def test_seed_batches_on_two_threads_give_the_batches_results_in_order():
    """`_init.in_lanes(parallel=True)`: the batches after the first run on two threads; the
    outputs are those of the batches run one after the other, in seed order (the last batch
    padded and cut)."""
    import jax

    run = jax.jit(lambda T: (T.log() * 2.0, jnp.sum(T.wxyz_xyz, -1)))
    rng = np.random.default_rng(0)
    seeds = np.asarray(jaxlie.SE3.exp(jnp.asarray(rng.normal(size=(11, 6)) * 0.3, jnp.float32)).wxyz_xyz)
    one = _init.in_lanes(run, seeds, 4, parallel=False)
    two = _init.in_lanes(run, seeds, 4, parallel=True)
    assert [x.shape for x in two] == [(11, 6), (11,)]
    for a, b in zip(one, two):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(two[1], seeds.sum(-1), rtol=1e-6)


def test_bad_demo_files_give_clear_errors(studio, tmp_path):
    import shutil

    root, _, _ = studio
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "demo.mp4").write_bytes(b"not a video")
    shutil.copy(root / "demo" / "camera.json", bad / "camera.json")
    with pytest.raises(ArtefactError, match="demo.mp4"):
        read_demo(bad / "demo.mp4")
    nocam = tmp_path / "nocam"
    nocam.mkdir()
    shutil.copy(root / "demo" / "demo.mp4", nocam / "demo.mp4")
    with pytest.raises(ArtefactError, match="camera.json"):
        read_demo(nocam / "demo.mp4")
    import json

    cam = json.loads((root / "demo" / "camera.json").read_text())
    cam["w"], cam["cx"] = cam["w"] * 2, cam["cx"] * 2
    (nocam / "camera.json").write_text(json.dumps(cam))
    with pytest.raises(ArtefactError, match="camera is"):
        read_demo(nocam / "demo.mp4")


def test_silhouette_areas_of_a_sphere_and_a_plate(rng):
    from rsrd_jax.track._init import seed_rotations, silhouette_areas

    p = rng.normal(size=(20000, 3))
    p = 0.03 * p / np.linalg.norm(p, axis=1, keepdims=True) + np.array([0.1, -0.2, 0.05])
    a = silhouette_areas(p, np.asarray(seed_rotations(4, (30.0, 60.0))))
    np.testing.assert_allclose(a / (np.pi * 0.03**2), 1.0, atol=0.06)
    # a flat 40×10 mm plate in the object's xy plane: seen from elevation e its silhouette is
    # foreshortened to A·sin(e)
    xy = rng.uniform([-0.02, -0.005], [0.02, 0.005], size=(20000, 2))
    plate = np.concatenate([xy, np.zeros((len(xy), 1))], 1)
    for e, tol in ((90.0, 0.1), (30.0, 0.25)):  # a 5 mm-thin silhouette gains ≈ a grid cell each side
        a = silhouette_areas(plate, np.asarray(seed_rotations(4, (e,))))
        np.testing.assert_allclose(a / (4e-4 * np.sin(np.deg2rad(e))), 1.0, atol=tol)


def test_support_height_finds_what_stands_on_the_table():
    """A pinhole camera 0.4 m above a table, looking down at 40°; a 60 × 60 × 6 mm block on it
    where the optical axis meets the table. True depth per cell by ray casting, seen through a
    monotone transform the fit does not list (1.3·Z^1.3) with 0.1 % noise: the table's cells lie
    within ±3 units of the fitted plane, every cell of the block's top face > 5 units in front."""
    from rsrd_jax.track._init import support_height

    rng = np.random.default_rng(0)
    g, f, H, e = 28, 60.0, 0.4, np.deg2rad(40.0)  # cells, focal length (cells), height (m), elevation
    up = np.array([0.0, -np.cos(e), -np.sin(e)])  # the table's normal in camera axes (x right, y down)
    u, v = np.meshgrid(np.arange(g) + 0.5 - g / 2, np.arange(g) + 0.5 - g / 2)
    rays = np.stack([u / f, v / f, np.ones_like(u)], -1)
    t_table = -H / (rays @ up)  # the table: up·X = −H
    t_top = -(H - 0.006) / (rays @ up)  # the block's top face, 6 mm higher
    centre = np.array([0.0, 0.0, 1.0]) * (-H / up[2])  # where the optical axis meets the table
    a1, a2 = np.array([1.0, 0.0, 0.0]), np.cross(up, [1.0, 0.0, 0.0])  # in-plane axes
    d = rays * t_top[..., None] - centre
    on_top = (np.abs(d @ a1) < 0.03) & (np.abs(d @ a2) < 0.03)
    Z = np.where(on_top, t_top, t_table)
    assert np.all(t_table > 0) and on_top.sum() >= 12
    mono = 1.3 * Z**1.3 * np.exp(rng.normal(0, 1e-3, Z.shape))
    valid = np.ones((g, g), bool)
    z = support_height(mono, valid)
    assert np.all(z[on_top] > 5.0), z[on_top]
    assert np.percentile(np.abs(z[~on_top]), 95) < 3.0
    assert support_height(np.zeros((g, g)), valid) is None  # no mono-depth source


@pytest.mark.parametrize("shift", [(-30, -18), (32, 16)])
def test_locate_object_finds_the_object_and_its_distance(studio, shift):
    """On the demo's first frame shifted in the image (the object off-centre; the table
    reflected in), the contrast region's centre lies near the projected true centroid, and the
    distance its area implies for the true view's silhouette is within 30 % of the truth (each
    seed starts at the distance of its own view; a hand covers part of the object)."""
    import cv2
    import jax

    from rsrd_jax.geometry import crop
    from rsrd_jax.track._dpm import TrackModel
    from rsrd_jax.track._init import locate_object, region_centre_and_area, silhouette_areas
    from rsrd_jax.track._observe import Observer, OccluderSource, full_frame_box

    root, model, ext = studio
    demo = read_demo(root / "demo" / "demo.mp4")
    K = demo.intrinsics
    M = np.array([[1.0, 0.0, shift[0]], [0.0, 1.0, shift[1]]])
    frame = cv2.warpAffine(np.asarray(demo.frames[0]), M, (K.width, K.height), borderMode=cv2.BORDER_REFLECT)
    hands = StudioHandMasks(root / "demo")

    class ShiftedHands(OccluderSource):
        def __call__(self, t, frame):
            return cv2.warpAffine(hands(t, frame).astype(np.uint8), M, (K.width, K.height), flags=cv2.INTER_NEAREST) > 0

    gt = read_demo_gt(root / "demo")
    tm = TrackModel.from_object_model(model, 1500)
    T0 = jaxlie.SE3(jnp.asarray(gt["T_cam_world_part"][0, 0], jnp.float32))
    means = np.asarray(model.gaussians.means)
    pc = np.asarray(T0 @ jnp.asarray(means.mean(0), jnp.float32))
    uv_true = np.array([K.fx * pc[0] / pc[2] + K.cx, K.fy * pc[1] / pc[2] + K.cy]) + np.asarray(shift)
    box = full_frame_box(K.width, K.height)
    obs = Observer(ext, model.pca, K, 192, ShiftedHands()).observe(0, frame, box)
    g = obs.features.shape[0]
    inside = crop(np.ones(frame.shape[:2], np.float32), box, g, cv2.INTER_AREA) > 0.99
    gf = np.asarray(jax.vmap(tm.decoder)(tm.gaussians.features[:, : tm.num_features]))
    score, region = locate_object(np.asarray(obs.features), inside, inside & (np.asarray(obs.weight) <= 0), gf)
    uv, area = region_centre_and_area(score, region, box)
    assert np.linalg.norm(uv - uv_true) < 0.06 * K.width, (uv, uv_true)
    R_true = np.asarray(T0.rotation().as_matrix())
    d = K.fx * np.sqrt(silhouette_areas(means, R_true[None])[0] / area)
    assert abs(d / np.linalg.norm(pc) - 1.0) < 0.3, (d, np.linalg.norm(pc))


def test_locate_object_finds_the_toy_drawer_under_the_hand(tmp_path):
    """On the studio toy_drawer's first frame at the pipeline's size (320×240 demo, 224 px ROI:
    a 28-cell grid over the letterboxed frame) the hand covers the knob and half the drawer. The
    decoded object features resemble the near table's coarser texture at the frame's bottom as
    much as the drawer's (cosine 0.5–0.6 for both on a pipeline-size build), so on features alone
    those cells, unlike the far table that makes up most of the background, win the contrast: the
    located centre lay 100 px from the drawer and the initialisation missed the object
    (`experiments/init_table.py`: 542 mm). With the relative depth the table plane is fitted
    (`support_height`) and cells on it can neither hold the peak nor join the region."""
    import cv2
    import jax

    from rsrd_jax.geometry import crop
    from rsrd_jax.track._dpm import TrackModel
    from rsrd_jax.track._init import locate_object, region_centre_and_area
    from rsrd_jax.track._observe import Observer, full_frame_box

    root = tmp_path / "toy_drawer"
    make_object("toy_drawer", root, StudioConfig(scan_views=6, scan_size=(96, 72), demo_frames=2, demo_size=(320, 240),
                                                 parts=("scan", "demo")))  # fmt: skip
    model, ext = gt_object_model(root, pca_dim=16, per_part=300, field_iters=30)
    demo = read_demo(root / "demo" / "demo.mp4")
    K = demo.intrinsics
    T0 = jaxlie.SE3(jnp.asarray(read_demo_gt(root / "demo")["T_cam_world_part"][0, 0], jnp.float32))
    pc = np.asarray(T0 @ jnp.asarray(np.asarray(model.gaussians.means).mean(0), jnp.float32))
    uv_true = np.array([K.fx * pc[0] / pc[2] + K.cx, K.fy * pc[1] / pc[2] + K.cy])
    box = full_frame_box(K.width, K.height)
    obs = Observer(ext, model.pca, K, 224, StudioHandMasks(root / "demo"),
                   StudioDepthOracle(root / "demo")).observe(0, demo.frames[0], box)  # fmt: skip
    g = obs.features.shape[0]
    inside = crop(np.ones((K.height, K.width), np.float32), box, g, cv2.INTER_AREA) > 0.99
    tm = TrackModel.from_object_model(model, 1500)
    gf = np.asarray(jax.vmap(tm.decoder)(tm.gaussians.features[:, : tm.num_features]))
    score, region = locate_object(np.asarray(obs.features), inside, inside & (np.asarray(obs.weight) <= 0), gf,
                                  mono=np.asarray(obs.mono))  # fmt: skip
    uv, _ = region_centre_and_area(score, region, box)
    assert np.linalg.norm(uv - uv_true) < 0.08 * K.width, (uv, uv_true)


@pytest.mark.slow
def test_slide_hypothesis_follows_the_nerf_gun_slide(tmp_path):
    """The nerf gun's slide is pulled 40 mm along the gun (studio demo, MuJoCo frames, hand masks,
    depth oracle, true initial pose). Every moving part is made a slide candidate
    (`slide_point_ratio=0`; the candidate rule is `test_slide_candidates_and_axes`); the slide
    along the gun's length has the lowest data loss of the hypotheses and follows the slide far
    better than without slide hypotheses (a turn about the fitted joint point)."""
    root = tmp_path / "nerf_gun"
    make_object("nerf_gun", root, StudioConfig(scan_views=8, scan_size=(128, 96), demo_frames=30, demo_size=(160, 120), parts=("scan", "demo")))
    model, ext = gt_object_model(root, pca_dim=16, per_part=600, field_iters=60)
    gt = read_demo_gt(root / "demo")
    demo = read_demo(root / "demo" / "demo.mp4")
    T_cwp = gt["T_cam_world_part"]
    T0 = jaxlie.SE3(jnp.asarray(T_cwp[0, 0], jnp.float32))
    cfg = dataclasses.replace(TINY, steps_per_frame=40, smooth_iters=0, roi_size=128, joints=True, lr_start=0.01, max_gaussians=3000,
                              slide_point_ratio=0.0)  # fmt: skip
    pts = [np.asarray(model.gaussians.means)[np.asarray(model.gaussians.part_ids) == k] for k in range(model.num_parts)]
    run = lambda c: track_video(model, demo, c, TINY_INIT, StudioHandMasks(root / "demo"), StudioDepthOracle(root / "demo"),  # noqa: E731
                                extractor=ext, progress=False, T_cam_obj_init=T0)  # fmt: skip
    with_slides = run(cfg)
    without = run(dataclasses.replace(cfg, slides=False))
    m1 = add_metrics(with_slides.T_cam_world_part, T_cwp, pts)["add_obj_mm"]
    m0 = add_metrics(without.T_cam_world_part, T_cwp, pts)["add_obj_mm"]
    print("ADD per part (mm) with / without slide hypotheses:", m1, m0, with_slides.meta["joints"])
    slide = 1  # parts: body, slide
    axis = with_slides.meta["joints"][str(slide)].get("slide_axis")
    assert axis is not None and abs(axis[0]) > 0.9, with_slides.meta["joints"]  # the gun's length is the model's x
    # a slide left at its first pose would be this far off (mean over the frames; 40 mm at the end)
    still = add_metrics(np.repeat(T_cwp[:1], len(T_cwp), 0), T_cwp, pts)["add_obj_mm"][slide]
    assert m1[slide] < 0.5 * m0[slide] and m1[slide] < 0.75 * still, (m1, m0, still)  # measured 11.5 / 26.4 mm


def test_studio_fingertips_give_each_hands_pinch_point_on_the_roi_grid(studio, tmp_path):
    """The oracle's pinch point is the midpoint of the thumb and index tips of the studio's
    keypoints, moved onto the ROI grid as the crop moves pixels (brute force); its noise has the
    requested spread; missing or malformed keypoints and a negative noise are clear errors."""
    from rsrd_jax.track import StudioFingertips
    from rsrd_jax.track._observe import Observer

    root, model, ext = studio
    demo = read_demo(root / "demo" / "demo.mp4")
    with np.load(root / "demo" / "gt" / "hand_keypoints.npz") as z:
        uv = z["keypoints_uv"]
    src = StudioFingertips(root / "demo")
    assert src.num_hands == uv.shape[1] and "oracle" in src.name
    obsr = Observer(ext, model.pca, demo.intrinsics, 96, fingertips=src)
    box = (10.0, -5.0, 80.0)
    obs = obsr.observe(2, demo.frames[2], box)
    g = obsr.grid_size
    want = (uv[2].mean(1) - [box[0], box[1]]) * g / box[2]
    inside = ((uv[2] >= 0) & (uv[2] < [demo.intrinsics.width, demo.intrinsics.height])).all(-1).all(-1)
    np.testing.assert_array_equal(np.asarray(obs.hand_seen) > 0, inside)
    np.testing.assert_allclose(np.asarray(obs.hand_uv)[inside], want[inside], atol=1e-3)
    assert float(jnp.sum(obs.hand_weight)) == 0.0  # no anchors until the tracker sets them
    noisy = StudioFingertips(root / "demo", noise_px=2.0, seed=1)
    d = (noisy.uv - uv).reshape(-1)
    assert 0.9 < float(np.std(d)) < 3.2 and "2 px noise" in noisy.name  # 16 samples of σ = 2
    with pytest.raises(ArtefactError, match="hand keypoints not found"):
        StudioFingertips(tmp_path)
    with pytest.raises(ValueError, match="noise_px"):
        StudioFingertips(root / "demo", noise_px=-1.0)
    (tmp_path / "gt").mkdir()
    np.savez(tmp_path / "gt" / "hand_keypoints.npz", keypoints_uv=np.zeros((3, 1, 2)))
    with pytest.raises(ArtefactError, match="T×H×2×2"):
        StudioFingertips(tmp_path)


def _gt_model_demo(tmp_path, name: str):
    """A studio object's demo at its own frame count, a ground-truth-geometry model of its small
    scan, the true poses, the true first pose and each part's Gaussian centres."""
    root = tmp_path / name
    make_object(name, root, StudioConfig(scan_views=12, scan_size=(160, 120), parts=("scan", "demo")))
    model, ext = gt_object_model(root, pca_dim=32, per_part=2000, field_iters=200)
    T_cwp = read_demo_gt(root / "demo")["T_cam_world_part"]
    T0 = jaxlie.SE3(jnp.asarray(T_cwp[0, 0], jnp.float32))
    pts = [np.asarray(model.gaussians.means)[np.asarray(model.gaussians.part_ids) == k] for k in range(model.num_parts)]
    return root, model, ext, read_demo(root / "demo" / "demo.mp4"), T_cwp, T0, pts


@pytest.mark.slow
def test_hand_term_follows_the_pinched_lid_under_the_hand(tmp_path):
    """The red box's lid closes 97° while the demonstrator's hand pinches its lip and hides it
    (studio demo at its own 90 frames, 320×240, MuJoCo frames, hand masks, depth oracle, true
    initial pose, ground-truth-geometry model, the pipeline's joint discovery with hinge axes).
    With the hand term (the studio's 2D fingertips, anchored to the lid) the lid is followed
    better and the box is not pulled off (measured: box / lid 5.05 / 2.80 mm with, 6.49 / 4.17 mm
    without). Without joint discovery the term no longer helps the lid at this size (session 33:
    10.85 / 13.30 against 11.99 / 12.32 mm; the commit that wrote this test gives the same today,
    though it measured 9.9 / 10.6 against 16.0 / 15.1 then: the environment changed, not the
    code; likely MuJoCo, which renders the demo, 4.0.0 → 4.0.1)."""
    from rsrd_jax.track import LossWeights, StudioFingertips

    root, model, ext, demo, T_cwp, T0, pts = _gt_model_demo(tmp_path, "red_box")
    cfg = TrackConfig(steps_per_frame=30, smooth_iters=0, lr_start=0.01, rank_pairs=1024, max_gaussians=4000, joints=True,
                      hinge_axes=True)  # fmt: skip
    run = lambda c, tips: track_video(model, demo, c, TINY_INIT, StudioHandMasks(root / "demo"), StudioDepthOracle(root / "demo"),  # noqa: E731
                                      extractor=ext, progress=False, T_cam_obj_init=T0, fingertips=tips)  # fmt: skip
    with_hands = run(cfg, StudioFingertips(root / "demo"))
    without = run(dataclasses.replace(cfg, weights=LossWeights(hand=0.0)), StudioFingertips(root / "demo"))
    m1 = add_metrics(with_hands.T_cam_world_part, T_cwp, pts)["add_obj_mm"]
    m0 = add_metrics(without.T_cam_world_part, T_cwp, pts)["add_obj_mm"]
    print("ADD per part (mm) with / without the hand term:", m1, m0, with_hands.meta["hand_anchors"])
    lid = 1
    assert [a["part"] for a in with_hands.meta["hand_anchors"]] == [lid] and without.meta["hand_anchors"] == []
    assert "oracle" in with_hands.meta["fingertips"]
    assert m1[lid] < 0.8 * m0[lid] and m1[0] < m0[0] + 2.0, (m1, m0)


@pytest.mark.slow
def test_hand_depth_term_follows_the_plug_lifted_towards_the_camera(tmp_path):
    """usb_plug's plug is pulled out of its brick and lifted towards the camera under the hand
    (studio demo at its own 90 frames, MuJoCo frames, hand masks, depth oracle, true initial
    pose, ground-truth-geometry model, the table at z = 0 of the object frame). The 2D hand term
    alone leaves the plug free along its viewing ray; the hand depth term, which reads the
    hand's depth off the table with the depth oracle's order, follows it (measured: plug 15.1 mm
    with, 50.1 mm without; at this size the base drifts in both runs, 41.6 / 65.0 mm; robot
    trials' build with the pipeline's tracking: plug 34.6 -> 9.9 mm)."""
    from rsrd_jax.track import LossWeights, StudioFingertips

    root, model, ext, demo, T_cwp, T0, pts = _gt_model_demo(tmp_path, "usb_plug")
    cfg = TrackConfig(steps_per_frame=30, smooth_iters=0, lr_start=0.01, rank_pairs=1024, max_gaussians=4000,
                      support_plane=(0.0, 0.0, 1.0, 0.0), weights=LossWeights(hand_depth=0.2))  # fmt: skip
    run = lambda c: track_video(model, demo, c, TINY_INIT, StudioHandMasks(root / "demo"), StudioDepthOracle(root / "demo"),  # noqa: E731
                                separable=True, extractor=ext, progress=False, T_cam_obj_init=T0,
                                fingertips=StudioFingertips(root / "demo"))  # fmt: skip
    with_depth = run(cfg)
    without = run(dataclasses.replace(cfg, weights=LossWeights(hand_depth=0.0)))
    m1 = add_metrics(with_depth.T_cam_world_part, T_cwp, pts)["add_obj_mm"]
    m0 = add_metrics(without.T_cam_world_part, T_cwp, pts)["add_obj_mm"]
    print("ADD per part (mm) with / without the hand depth term:", m1, m0)
    assert with_depth.meta["hand_depth_table"] and not without.meta["hand_depth_table"]
    plug = 1
    assert m1[plug] < 0.6 * m0[plug] and m1[0] < m0[0] + 3.0, (m1, m0)


def test_track_with_hands_anchors_the_pinched_part_and_pulls_it_to_the_fingertips(studio):
    """Tracking the studio nerf gun (its slide pulled 40 mm in 4 frames) with its 2D fingertips:
    the hand is anchored to the slide it pinches (the studio's contact part), the per-frame solve
    still compiles once, the trajectory names the oracle, and the anchored point, projected at the
    tracked poses (`viz.hand_anchor_pixels`, checked against a numpy projection), stays closer to
    the pinch point than the same point does when tracked without the hand term. (At this size
    ARAP holds the slide against the default weight's pull, so the weight is raised to 2.0: this
    tests the mechanism; the default is measured on the full-size demos.)"""
    from rsrd_jax.track import LossWeights, StudioFingertips
    from rsrd_jax.viz._track import hand_anchor_pixels

    root, model, ext = studio
    demo = read_demo(root / "demo" / "demo.mp4")
    gt = read_demo_gt(root / "demo")
    T0 = jaxlie.SE3(jnp.asarray(gt["T_cam_world_part"][0, 0], jnp.float32))
    cfg = dataclasses.replace(TINY, steps_per_frame=20, smooth_iters=0, weights=LossWeights(hand=2.0))
    run = lambda c: track_video(model, demo, c, TINY_INIT, StudioHandMasks(root / "demo"), StudioDepthOracle(root / "demo"),  # noqa: E731
                                extractor=ext, progress=False, T_cam_obj_init=T0, fingertips=StudioFingertips(root / "demo"))  # fmt: skip
    before = _dpm._trace_counts["frame"]
    traj = run(cfg)
    assert _dpm._trace_counts["frame"] - before == 1
    assert "oracle" in traj.meta["fingertips"]
    anchors = traj.meta["hand_anchors"]
    assert [a["part"] for a in anchors] == gt["contact_parts"].tolist() and anchors[0]["frame"] == 0
    px = hand_anchor_pixels(traj, demo.intrinsics)
    a = anchors[0]
    K = demo.intrinsics

    def project(tr):
        M = np.asarray((jaxlie.SE3(jnp.asarray(tr.T_cam_obj, jnp.float32)) @ jaxlie.SE3(jnp.asarray(tr.T_obj_part[:, a["part"]], jnp.float32))).as_matrix())
        pc = M[:, :3, :3] @ (np.asarray(a["point_mm"]) * 1e-3) + M[:, :3, 3]
        return np.stack([float(K.fx) * pc[:, 0] / pc[:, 2] + float(K.cx), float(K.fy) * pc[:, 1] / pc[:, 2] + float(K.cy)], 1)

    np.testing.assert_allclose(px[:, 0], project(traj), atol=1e-2)
    without = run(dataclasses.replace(cfg, weights=LossWeights(hand=0.0)))
    assert without.meta["hand_anchors"] == []
    pinch = gt["keypoints_uv"][:, 0].mean(1)
    r1 = np.linalg.norm(project(traj) - pinch, axis=1)
    r0 = np.linalg.norm(project(without) - pinch, axis=1)
    print("pinch residual (px) with / without the hand term:", r1, r0)
    assert r1[1:].mean() < 0.7 * r0[1:].mean(), (r1, r0)


def test_slide_hypotheses_only_for_parts_a_hand_held(tmp_path):
    """Joint discovery with the studio fingertips on the bear (one hand waves its right arm):
    with every jointed part made a slide candidate (`slide_point_ratio=0`, `slide_min_m=0`, no
    `slide_max_turn_deg`), only
    the held arm gets slide hypotheses; the parts no hand held are reported as dropped candidates
    (`TrackConfig.slide_held_only`)."""
    from rsrd_jax.track import StudioFingertips

    root = tmp_path / "bear"
    make_object("bear", root, StudioConfig(scan_views=6, scan_size=(96, 72), demo_frames=4, demo_size=(128, 96), parts=("scan", "demo")))
    model, ext = gt_object_model(root, pca_dim=16, per_part=200, field_iters=30)
    demo = read_demo(root / "demo" / "demo.mp4")
    gt = read_demo_gt(root / "demo")
    T0 = jaxlie.SE3(jnp.asarray(gt["T_cam_world_part"][0, 0], jnp.float32))
    cfg = dataclasses.replace(TINY, steps_per_frame=4, smooth_iters=0, joints=True, joint_first_steps=4,
                              slide_point_ratio=0.0, slide_min_m=0.0, slide_max_turn_deg=None)  # fmt: skip
    traj = track_video(model, demo, cfg, TINY_INIT, StudioHandMasks(root / "demo"), StudioDepthOracle(root / "demo"),
                       extractor=ext, progress=False, T_cam_obj_init=T0, fingertips=StudioFingertips(root / "demo"))  # fmt: skip
    held = [a["part"] for a in traj.meta["hand_anchors"]]
    assert held == gt["contact_parts"].tolist() == [2]
    j = traj.meta["joints"]
    tried = {h["part"] for h in j["slide_hypotheses"] if h["part"] is not None}
    assert tried == {2}, j
    assert len(j["slide_candidates_not_held"]) >= 2 and 2 not in j["slide_candidates_not_held"], j


def test_motion_prior_holds_each_frame_at_its_extrapolated_guess(studio):
    """With `velocity_factor=0` every frame starts at the previous frame's poses; a strong motion
    prior keeps the parts there (the slide, pulled 40 mm over the video, barely moves relative to
    the body), while without it the per-frame solve follows the video. Object-frame poses only:
    the camera pose is fixed at the ground truth."""
    from rsrd_jax.track import LossWeights

    root, model, ext = studio
    demo = read_demo(root / "demo" / "demo.mp4")
    gt = read_demo_gt(root / "demo")
    T0 = jaxlie.SE3(jnp.asarray(gt["T_cam_world_part"][0, 0], jnp.float32))
    cfg = dataclasses.replace(TINY, steps_per_frame=20, smooth_iters=0, velocity_factor=0.0)
    run = lambda w: track_video(model, demo, dataclasses.replace(cfg, weights=LossWeights(motion=w)), TINY_INIT,  # noqa: E731
                                StudioHandMasks(root / "demo"), StudioDepthOracle(root / "demo"), extractor=ext,
                                progress=False, T_cam_obj_init=T0)  # fmt: skip

    def steps(traj):  # per-frame motion of each part (object frame): translation m, rotation rad
        T = jaxlie.SE3(jnp.asarray(traj.T_obj_part, jnp.float32))
        d = (jaxlie.SE3(T.wxyz_xyz[:-1]).inverse() @ jaxlie.SE3(T.wxyz_xyz[1:])).log()
        return np.linalg.norm(np.asarray(d[..., :3]), axis=-1), np.linalg.norm(np.asarray(d[..., 3:]), axis=-1)

    t_free, r_free = steps(run(0.0))
    t_held, r_held = steps(run(1e4))
    print("per-frame translation (mm) free / held:", 1e3 * t_free, 1e3 * t_held)
    assert t_free.max() > 1e-3  # the free solve moves a part by over a millimetre in a frame
    assert t_held.max() < 0.2 * t_free.max() and r_held.max() < 0.2 * max(r_free.max(), 1e-3), (t_held, r_held)


def test_a_still_root_stays_at_its_first_frame_pose_while_the_others_follow(studio):
    """`TrackConfig.still_root`: the root (the nerf gun's body, which the studio never moves) keeps
    the pose frame 0's solve gave it on every later frame and through the smoothing, while the
    slide is still solved on every frame (its pose changes); without it the root's pose changes
    from frame to frame (by 1.9 mm here: this 4-frame demo pulls the slide 40 mm, which the tiny
    solve does not follow; what the option does to accuracy is measured in the tracking table)."""
    root, model, ext = studio
    demo = read_demo(root / "demo" / "demo.mp4")
    gt = read_demo_gt(root / "demo")
    T0 = jaxlie.SE3(jnp.asarray(gt["T_cam_world_part"][0, 0], jnp.float32))
    cfg = dataclasses.replace(TINY, steps_per_frame=20, smooth_iters=2)
    run = lambda still: track_video(model, demo, dataclasses.replace(cfg, still_root=still), TINY_INIT,  # noqa: E731
                                    StudioHandMasks(root / "demo"), StudioDepthOracle(root / "demo"), extractor=ext,
                                    progress=False, T_cam_obj_init=T0)  # fmt: skip

    def moves(T_obj_part, k):  # largest change of part k's pose over the frames: translation m, rotation rad
        T = jaxlie.SE3(jnp.asarray(T_obj_part[:, k], jnp.float32))
        d = (jaxlie.SE3(T.wxyz_xyz[:1]).inverse() @ T).log()
        return float(np.linalg.norm(np.asarray(d[:, :3]), axis=-1).max()), float(np.linalg.norm(np.asarray(d[:, 3:]), axis=-1).max())

    held, free = run(True), run(False)
    assert moves(held.T_obj_part, 0) == pytest.approx((0.0, 0.0), abs=1e-6)
    assert moves(free.T_obj_part, 0)[0] > 1e-5
    assert moves(held.T_obj_part, 1)[1] > 1e-3  # the slide is still solved (it turns by 0.8° here)
    assert held.meta["config"]["still_root"] is True


@pytest.mark.parametrize("first", [False, True])
def test_a_still_root_is_tracked_freely_in_the_joint_pass_unless_asked(studio, first):
    """`TrackConfig.still_root_first`: with joint discovery, the first pass (which the joint points
    and axes are fitted from) tracks the root freely by default, so that a drift common to all
    parts is not read as a joint's motion (`joints["first_root_moved_mm"]` > 0; the studio's
    led_light: the panel's joint point 17.3 mm off its hinge line when the first pass held the
    root, 1.5 mm when free), and holds it with `still_root_first` (0 mm); the final trajectory
    holds the root at its frame-0 pose either way; with the free first pass as the slides'
    baseline (`slide_baseline="first"`) it refuses to track."""
    root, model, ext = studio
    demo = read_demo(root / "demo" / "demo.mp4")
    gt = read_demo_gt(root / "demo")
    T0 = jaxlie.SE3(jnp.asarray(gt["T_cam_world_part"][0, 0], jnp.float32))
    cfg = dataclasses.replace(TINY, steps_per_frame=8, smooth_iters=2, joints=True, joint_first_steps=8, still_root=True,
                              still_root_first=first, slide_baseline="joint")  # fmt: skip
    traj = track_video(model, demo, cfg, TINY_INIT, StudioHandMasks(root / "demo"), StudioDepthOracle(root / "demo"),
                       extractor=ext, progress=False, T_cam_obj_init=T0)  # fmt: skip
    if not first:  # the first pass, free, is no baseline for hypotheses that hold the root
        with pytest.raises(ValueError, match="slide_baseline='joint'"):
            track_video(model, demo, dataclasses.replace(cfg, slide_baseline="first"), TINY_INIT, progress=False)
    moved = traj.meta["joints"]["first_root_moved_mm"]
    assert moved == 0.0 if first else moved > 1e-3, moved
    T = jaxlie.SE3(jnp.asarray(traj.T_obj_part[:, 0], jnp.float32))
    d = (jaxlie.SE3(T.wxyz_xyz[:1]).inverse() @ T).log()
    assert float(jnp.abs(d).max()) < 1e-6  # the final root: frame 0's pose on every frame
