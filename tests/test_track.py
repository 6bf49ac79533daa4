"""Tracking on a small studio object: compile-once per video, outputs, evaluation, bad inputs.

The GT-geometry model (`tests/_gt_model.py`) isolates tracking from 3DGS fitting.
"""

import dataclasses

import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from rsrd_jax.io import ArtefactError, load_trajectory, read_demo, read_demo_gt, save_trajectory
from rsrd_jax.splat import rest_part_poses
from rsrd_jax.studio import StudioConfig, make_object
from rsrd_jax.track import InitConfig, StudioDepthOracle, StudioHandMasks, TrackConfig, add_metrics, kabsch, track_video
from rsrd_jax.track import _dpm

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
    before = _dpm._trace_counts["frame"]
    traj = track_video(model, demo, TINY, TINY_INIT, StudioHandMasks(root / "demo"), StudioDepthOracle(root / "demo"),
                       extractor=ext, progress=False)  # fmt: skip
    assert _dpm._trace_counts["frame"] - before == 1, "the per-frame solve must compile once per video"
    assert traj.T_obj_part.shape == (4, 2, 7) and traj.T_cam_obj.shape == (4, 7)
    assert np.all(np.isfinite(traj.T_cam_world_part)) and np.all(traj.visible >= 0)
    assert "studio relative-depth ORACLE" in traj.meta["mono_depth"]
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
    with pytest.raises(ArtefactError, match="hand masks not found"):
        StudioHandMasks(tmp_path)
    with pytest.raises(ArtefactError, match="trajectory not found"):
        load_trajectory(tmp_path)
