"""ObjectModel build pieces: 3DGS fit on a known scene, mask voting on a studio object, save/load,
bad captures, ARAP pairs and automatic grouping."""

import json
import shutil

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from rsrd_jax.features import fit_pca
from rsrd_jax.geometry import Camera, Intrinsics, look_at
from rsrd_jax.io import ArtefactError, read_capture, write_label_png
from rsrd_jax.parts import (
    BuildConfig,
    FeatureDecoder,
    FrozenDict,
    ObjectModel,
    arap_pairs,
    auto_group,
    build_object_model,
    decode_rendered,
    gt_part_accuracy,
    knn_cleanup,
    load_object_model,
    save_object_model,
    vote_part_labels,
)
from rsrd_jax.splat import Gaussians
from rsrd_jax.splat._fit import FitConfig, fit_gaussians
from rsrd_jax.splat._reference import render_reference


# --------------------------------------------------------------------------------------------
# 3DGS fit recovers a tiny known scene rendered by the dense reference renderer
# --------------------------------------------------------------------------------------------


def _tiny_scene():
    means = np.array([[0.0, 0.0, 0.0], [0.12, 0.05, 0.0], [-0.08, 0.1, 0.06], [0.02, -0.1, -0.05]])
    n = len(means)
    g = Gaussians.create(
        means,
        np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)),
        np.full((n, 3), np.log(0.03)),
        np.full(n, 2.0),
        np.array([[0.9, 0.1, 0.1], [0.1, 0.8, 0.2], [0.2, 0.2, 0.9], [0.8, 0.8, 0.1]]),
    )
    intr = Intrinsics.create(40.0, 40.0, 16.0, 16.0, 32, 32)
    Ts = []
    for i in range(8):
        a = 2 * np.pi * i / 8
        eye = 0.6 * np.array([np.cos(a), np.sin(a), 0.5 * np.sin(2 * a) + 0.3])
        Ts.append(np.asarray(look_at(eye, np.zeros(3)).as_matrix(), np.float64))
    return g, intr, np.stack(Ts)


def test_fit_recovers_tiny_scene():
    g, intr, T = _tiny_scene()
    imgs = []
    for Tv in T:
        cam = Camera(intr, jaxlie.SE3.from_matrix(jnp.asarray(Tv, jnp.float32)))
        rgb = np.asarray(render_reference(g, cam, jnp.zeros(3))["rgb"])
        imgs.append(np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8))
    imgs = np.stack(imgs)
    rng = np.random.default_rng(0)
    init = Gaussians.create(
        np.asarray(g.means) + rng.normal(0, 0.015, (4, 3)),
        np.tile([1.0, 0.0, 0.0, 0.0], (4, 1)),
        np.full((4, 3), np.log(0.04)),
        np.full(4, 2.0),  # opacity fixed at the truth: colour × opacity is otherwise ambiguous
        np.full((4, 3), 0.5),
    )
    cfg = FitConfig(iterations=300, block=100, max_gaussians=8, densify_from=10**9, prune_opacity=0.0,
                    lr_means=2e-3, lr_means_final=2e-4, lr_colours=2e-2, lr_opacity=0.0)  # fmt: skip
    res = fit_gaussians(init, imgs, intr, T, None, cfg)
    assert res.gaussians.num_gaussians == 4
    err_mu = np.linalg.norm(np.asarray(res.gaussians.means) - np.asarray(g.means), axis=1)
    assert err_mu.max() < 0.006, err_mu  # 6 mm on 3 cm Gaussians, initial error ~25 mm
    assert np.abs(np.asarray(res.gaussians.colours) - np.asarray(g.colours)).max() < 0.08
    s_fit = np.exp(np.asarray(res.gaussians.log_scales)).mean(1)
    assert np.all(np.abs(s_fit / 0.03 - 1) < 0.25), s_fit
    assert res.history["blocks"][-1]["loss"] < 0.25 * res.history["blocks"][0]["loss"]


def test_fit_render_budget_covers_crowded_tiles():
    """The fit's default render budget keeps every Gaussian of a crowded tile (as a dense
    reference renders them); a fixed small K truncates the far ones and visibly changes colours."""
    from rsrd_jax.splat import render
    from rsrd_jax.splat._fit import size_render_config

    rng = np.random.default_rng(1)
    n = 600  # translucent Gaussians stacked in depth in front of the camera
    means = np.stack([rng.normal(0, 0.01, n), rng.normal(0, 0.01, n), rng.uniform(-0.05, 0.05, n)], 1)
    g = Gaussians.create(means, np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)), np.full((n, 3), np.log(0.006)),
                         np.full(n, -3.0), rng.uniform(0, 1, (n, 3)))  # fmt: skip
    intr = Intrinsics.create(60.0, 60.0, 16.0, 16.0, 32, 32)
    T = np.asarray(look_at(np.array([0.0, 0.0, 0.3]), np.zeros(3)).as_matrix(), np.float64)[None]
    cam = Camera(intr, jaxlie.SE3.from_matrix(jnp.asarray(T[0], jnp.float32)))
    ref = np.asarray(render_reference(g, cam, jnp.zeros(3))["rgb"])
    cfg = size_render_config(g, intr, T, 8)
    assert cfg.capacity >= 512
    np.testing.assert_allclose(np.asarray(render(g, cam, cfg, jnp.zeros(3)).rgb), ref, atol=2e-3)
    small = size_render_config(g, intr, T, 8, capacity=64)
    assert np.abs(np.asarray(render(g, cam, small, jnp.zeros(3)).rgb) - ref).max() > 0.02


# --------------------------------------------------------------------------------------------
# Mask voting on a small studio object
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def studio_scan(tmp_path_factory):
    from rsrd_jax.studio import StudioConfig, make_object

    out = tmp_path_factory.mktemp("studio") / "red_box"
    make_object("red_box", out, StudioConfig(parts=("scan",), scan_views=10, scan_size=(128, 96)))
    return out / "scan"


def _gt_world(scan):
    z = np.load(scan / "gt" / "scan_gt.npz")
    T = jaxlie.SE3(jnp.asarray(z["T_world_part"], jnp.float32)[z["part_point_ids"]])
    return np.asarray(T @ jnp.asarray(z["part_points"], jnp.float32), np.float64), z["part_point_ids"]


def test_mask_voting_recovers_studio_labels(studio_scan):
    cap = read_capture(studio_scan)
    world, ids = _gt_world(studio_scan)
    pm = np.stack([cap.part_mask(i) for i in range(len(cap))])
    dep = np.stack([cap.depth(i) for i in range(len(cap))])
    votes = vote_part_labels(world, cap.intrinsics, cap.T_cam_world(), pm, dep, 2, tolerance=0.004)
    known = votes.sum(1) > 0
    assert known.mean() > 0.6  # many surface points are seen in front in some view
    raw = np.argmax(votes, 1)
    assert np.mean(raw[known] == ids[known]) > 0.97
    labels = knn_cleanup(world, raw, known, k=10)
    acc = gt_part_accuracy(world, labels, world, ids)
    assert acc >= 0.98, acc
    # an occluder 3 cm in front of every surface hides the points: only the few surface points
    # that happen to lie 3 cm in front of another surface still vote
    occluded = np.where(dep > 0, dep - 0.03, 0.0)
    none = vote_part_labels(world, cap.intrinsics, cap.T_cam_world(), pm, occluded, 2, tolerance=0.004)
    assert none.sum() < 0.03 * votes.sum()


# --------------------------------------------------------------------------------------------
# Save / load
# --------------------------------------------------------------------------------------------


def _random_model(seed=0, n=50, f=8, d=6, p=3):
    rng = np.random.default_rng(seed)
    g = Gaussians.create(
        rng.normal(size=(n, 3)), rng.normal(size=(n, 4)), rng.normal(size=(n, 3)), rng.normal(size=n),
        rng.uniform(size=(n, 3)), rng.normal(size=(n, f)), rng.integers(0, p, n),
    )  # fmt: skip
    pca = fit_pca(rng.normal(size=(200, 10)).astype(np.float32), dim=d)
    dec = FeatureDecoder.create(f, d, 16, 3, jax.random.key(seed))
    return ObjectModel(
        gaussians=g, decoder=dec, pca=pca,
        part_centroids=jnp.asarray(rng.normal(size=(p, 3)), jnp.float32),
        arap_pairs=jnp.asarray([[0, 1], [2, 5], [7, 49]], jnp.int32),
        feature_backend=FrozenDict(name="efficientnet_lite0", config={"strides": [8, 16]}, stride=[8.0, 8.0]),
        part_names=("a", "b", "c"), meta=FrozenDict(scale_m=0.05, metrics={"x": 1.5}),
    )  # fmt: skip


def test_save_load_roundtrip_exact(tmp_path):
    m = _random_model()
    save_object_model(m, tmp_path / "model")
    m2 = load_object_model(tmp_path / "model")
    la, ta = jax.tree_util.tree_flatten(m)
    lb, tb = jax.tree_util.tree_flatten(m2)
    assert ta == tb
    for a, b in zip(la, lb):
        assert a.dtype == b.dtype and np.array_equal(np.asarray(a), np.asarray(b))
    assert m2.part_names == ("a", "b", "c") and m2.meta["metrics"]["x"] == 1.5
    assert m2.num_parts == 3
    ids = np.asarray(m.gaussians.part_ids)
    assert np.array_equal(m2.part_points(1), np.asarray(m.gaussians.means)[ids == 1])
    # static dicts are hashable, so the model can pass through jit
    out = jax.jit(lambda mm: decode_rendered(mm.decoder, mm.gaussians.features, jnp.ones(50)))(m2)
    assert out.shape == (50, 6)


def test_part_extent_points_lie_on_each_gaussians_sigma_ellipsoid_and_thicken_a_sheet():
    """Every extent point is one standard deviation from its Gaussian's centre in that
    Gaussian's own metric (Mahalanobis distance 1, covariance from jaxlie's rotation of the
    quaternion); a plate whose Gaussian centres lie on its mid-plane gets no antipodal grasp
    from its centres (a sheet) and grasps across its thickness from its extent points."""
    from rsrd_jax.grasp import build_part_mesh, sample_antipodal_grasps

    rng = np.random.default_rng(3)
    gx, gy = np.meshgrid(np.arange(-0.03, 0.0301, 0.0015), np.arange(-0.01, 0.0101, 0.0015))
    n = gx.size
    means = np.stack([gx.ravel(), gy.ravel(), rng.normal(0, 2e-4, n)], 1)
    yaw = rng.uniform(0, np.pi, n)
    quats = np.stack([np.cos(yaw / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)], 1)  # about z: the thin axis stays z
    scales = np.tile([0.002, 0.0015, 0.0016], (n, 1))
    g = Gaussians.create(means, quats, np.log(scales), np.zeros(n), np.full((n, 3), 0.5), np.zeros((n, 4)), np.zeros(n, int))
    m = eqx.tree_at(lambda x: (x.gaussians, x.part_centroids), _random_model(p=1), (g, jnp.zeros((1, 3))))
    ext = m.part_extent_points(0)
    assert ext.shape == (7 * n, 3)
    R = np.asarray(jaxlie.SO3(jnp.asarray(quats, jnp.float32)).as_matrix(), np.float64)
    s = np.minimum(scales, np.percentile(scales, 90))
    cov_inv = np.einsum("nij,nj,nkj->nik", R, 1 / s**2, R)
    d = ext[n:].reshape(2, n, 3, 3) - means[None, :, None]  # (±, gaussian, axis, xyz)
    maha = np.einsum("anbi,nij,anbj->anb", d, cov_inv, d)
    np.testing.assert_allclose(maha, 1.0, rtol=1e-4)
    key = jax.random.key(0)
    flat = sample_antipodal_grasps(build_part_mesh(np.asarray(m.part_points(0))), key)
    thick = sample_antipodal_grasps(build_part_mesh(ext), key)
    assert not np.asarray(flat.valid).any()
    w = np.asarray(thick.width)[np.asarray(thick.valid)]
    assert len(w) and np.median(w) == pytest.approx(2 * 0.0016, abs=1e-3)


def test_load_errors_name_file_and_field(tmp_path):
    d = tmp_path / "model"
    save_object_model(_random_model(), d)
    meta = json.loads((d / "model.json").read_text())
    bad = dict(meta, format="other/9")
    (d / "model.json").write_text(json.dumps(bad))
    with pytest.raises(ArtefactError, match=r"model\.json: format"):
        load_object_model(d)
    (d / "model.json").write_text(json.dumps(dict(meta, num_parts=2, part_names=["a", "b"])))
    with pytest.raises(ArtefactError, match=r"part_centroids|part_ids"):
        load_object_model(d)
    (d / "model.safetensors").unlink()
    with pytest.raises(ArtefactError, match=r"model\.safetensors: not found"):
        load_object_model(d)


# --------------------------------------------------------------------------------------------
# Bad captures
# --------------------------------------------------------------------------------------------


def _copy(scan, tmp_path):
    dst = tmp_path / "scan"
    shutil.copytree(scan, dst)
    return dst


def test_bad_capture_missing_image(studio_scan, tmp_path):
    d = _copy(studio_scan, tmp_path)
    (d / "images" / "00003.png").unlink()
    with pytest.raises(ArtefactError, match=r"frames\[3\]\.file_path: file not found"):
        build_object_model(d, progress=False)


def test_bad_capture_mismatched_size(studio_scan, tmp_path):
    import cv2

    d = _copy(studio_scan, tmp_path)
    cv2.imwrite(str(d / "images" / "00002.png"), np.zeros((50, 60, 3), np.uint8))
    with pytest.raises(ArtefactError, match=r"00002\.png: image is 60×50"):
        build_object_model(d, progress=False)


def test_bad_capture_nonfinite_pose(studio_scan, tmp_path):
    d = _copy(studio_scan, tmp_path)
    meta = json.loads((d / "transforms.json").read_text())
    meta["frames"][1]["transform_matrix"][0][3] = float("nan")
    (d / "transforms.json").write_text(json.dumps(meta))
    with pytest.raises(ArtefactError, match=r"frames\[1\]\.transform_matrix"):
        build_object_model(d, progress=False)


def test_bad_capture_unknown_part_label(studio_scan, tmp_path):
    d = _copy(studio_scan, tmp_path)
    pm = read_capture(d).part_mask(4).copy()
    pm[:5, :5] = 7
    write_label_png(d / "part_masks" / "00004.png", pm)
    with pytest.raises(ArtefactError, match=r"00004\.png: part label 7 but the model has 2 parts"):
        build_object_model(d, BuildConfig(num_parts=2), progress=False)
    with pytest.raises(ArtefactError, match=r"labels \[3, 4, 5, 6\] never appear"):
        build_object_model(d, progress=False)


# --------------------------------------------------------------------------------------------
# Part-level helpers
# --------------------------------------------------------------------------------------------


def test_arap_pairs_match_brute_force(rng):
    pts = rng.uniform(0, 0.05, (300, 3))
    lab = (pts[:, 0] > 0.025).astype(int)
    r = 0.006
    got = {tuple(p) for p in arap_pairs(pts, lab, r).tolist()}
    d = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
    want = {(i, j) for i in range(300) for j in range(i + 1, 300) if d[i, j] < r and lab[i] != lab[j]}
    assert got == want and len(want) > 10


def test_auto_group_separates_blobs_by_size(rng):
    a = rng.normal([0, 0, 0], 0.01, (600, 3))
    b = rng.normal([0.1, 0, 0], 0.01, (300, 3))
    pts = np.concatenate([a, b])
    feats = np.concatenate([np.tile([1.0, 0.0], (600, 1)), np.tile([0.0, 1.0], (300, 1))])
    lab = auto_group(pts, feats + rng.normal(0, 0.05, feats.shape))
    assert np.mean(lab[:600] == 0) > 0.99 and np.mean(lab[600:] == 1) > 0.99


def test_auto_group_splits_studio_objects_at_their_joints():
    """Geometry alone (no features) on the studio's visible surface samples: the spectral grouping
    finds red_box's lid and the stapler's arm (independent reference: the MuJoCo part bodies)."""
    from sklearn.metrics import adjusted_rand_score

    from rsrd_jax.studio import get_object
    from rsrd_jax.studio._scene import SceneOptions, build_scene

    for name, min_ari in (("red_box", 0.9), ("stapler", 0.85)):
        with build_scene(get_object(name), np.eye(4), SceneOptions(32, 32, 45.0, 0)) as sc:
            sc.set_configuration(0.0)
            T = sc.part_poses()
            pts = sc.exterior_part_points(1500, 0)
        world = np.concatenate([p @ T[k, :3, :3].T + T[k, :3, 3] for k, p in enumerate(pts)])
        ids = np.concatenate([np.full(len(p), k) for k, p in enumerate(pts)])
        lab = auto_group(world, np.zeros((len(world), 1)), feature_weight=0.0)
        assert lab.max() + 1 == 2, (name, lab.max() + 1)
        assert adjusted_rand_score(ids, lab) > min_ari, (name, adjusted_rand_score(ids, lab))


def test_support_plane_is_the_table_under_the_scanned_object(studio_scan):
    """Fitted to the scan's background depth (object pixels masked out), the plane is the table
    the ground-truth object rests on: normal up within 0.1°, height at its lowest point."""
    from rsrd_jax.io import read_capture
    from rsrd_jax.parts import support_plane

    cap = read_capture(studio_scan)
    depths = np.stack([cap.depth(i) for i in range(len(cap))])
    masks = np.stack([cap.valid_mask(i) for i in range(len(cap))])
    world, _ = _gt_world(studio_scan)
    c = world.mean(0)
    plane = support_plane(cap.intrinsics, cap.T_cam_world(), depths, masks, c, 3 * np.linalg.norm(world - c, axis=1).max())
    assert np.degrees(np.arccos(plane[2])) < 0.1
    assert plane[3] == pytest.approx(world[:, 2].min(), abs=5e-4)
    # without background depth there is no plane
    assert support_plane(cap.intrinsics, cap.T_cam_world(), depths, np.ones_like(masks), c, 1.0) is None


@pytest.mark.slow
def test_build_small_studio_object(studio_scan, tmp_path):
    from rsrd_jax.parts import FieldConfig

    cfg = BuildConfig(fit=FitConfig(iterations=200), field=FieldConfig(iterations=200), holdout_every=0)
    m = build_object_model(studio_scan, cfg, progress=False, rrd_path=tmp_path / "b.rrd")
    assert m.num_parts == 2 and (tmp_path / "b.rrd").is_file()
    assert m.meta["metrics"]["part_label_accuracy"] >= 0.97
    # the table fitted to the scan's background depth: the plane the ground-truth object rests on
    n, d = np.asarray(m.meta["support_plane"][:3]), m.meta["support_plane"][3]
    assert np.degrees(np.arccos(n[2])) < 0.1
    assert d == pytest.approx(_gt_world(studio_scan)[0][:, 2].min(), abs=5e-4)
    save_object_model(m, tmp_path / "m")
    assert load_object_model(tmp_path / "m").gaussians.num_gaussians == m.gaussians.num_gaussians


def test_pose_refinement_reduces_pose_error():
    """With the true Gaussians frozen, per-view se(3) corrections pull noisy poses to the truth."""
    g, intr, T = _tiny_scene()
    imgs = []
    for Tv in T:
        cam = Camera(intr, jaxlie.SE3.from_matrix(jnp.asarray(Tv, jnp.float32)))
        rgb = np.asarray(render_reference(g, cam, jnp.zeros(3))["rgb"])
        imgs.append(np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8))
    rng = np.random.default_rng(1)
    noise = np.concatenate([rng.normal(0, 0.01, (8, 3)), rng.normal(0, np.deg2rad(1.5), (8, 3))], 1)
    T_noisy = np.stack([np.asarray((jaxlie.SE3.exp(jnp.asarray(n, jnp.float32))
                                    @ jaxlie.SE3.from_matrix(jnp.asarray(t, jnp.float32))).as_matrix())
                        for n, t in zip(noise, T)])  # fmt: skip
    cfg = FitConfig(iterations=300, block=100, max_gaussians=8, densify_from=10**9, prune_opacity=0.0,
                    lr_means=0.0, lr_means_final=0.0, lr_colours=0.0, lr_opacity=0.0, lr_scales=0.0, lr_quats=0.0,
                    refine_poses=True, lr_pose=1e-3)  # fmt: skip
    res = fit_gaussians(g, np.stack(imgs), intr, T_noisy, None, cfg)
    T_ref = np.asarray(jaxlie.SE3(res.T_cam_world).as_matrix())

    def reproj(A):  # mean reprojection error (px) of a cube of points around the scene
        pts = jnp.asarray(np.stack(np.meshgrid(*[[-0.1, 0.1]] * 3), -1).reshape(-1, 3), jnp.float32)
        err = []
        for a, b in zip(A, T):
            ua = Camera(intr, jaxlie.SE3.from_matrix(jnp.asarray(a, jnp.float32))).project(pts)[0]
            ub = Camera(intr, jaxlie.SE3.from_matrix(jnp.asarray(b, jnp.float32))).project(pts)[0]
            err.append(np.linalg.norm(np.asarray(ua - ub), axis=-1).mean())
        return float(np.mean(err))

    # (camera position and rotation trade off for a small far scene; the image error is what is
    # determined, so compare reprojections)
    assert reproj(T_ref) < 0.3 * reproj(T_noisy), (reproj(T_ref), reproj(T_noisy))


def test_feature_backend_record_rebuilds_extractor():
    from rsrd_jax.features import EfficientNetConfig, EfficientNetExtractor
    from rsrd_jax.parts import feature_backend_record, make_extractor

    ext = EfficientNetExtractor.pretrained(EfficientNetConfig(strides=(8,), input_scale=2.0))
    rec = feature_backend_record(ext, (96, 128))
    assert rec["stride"] == [4.0, 4.0] and rec["feature_dim"] == ext.feature_dim
    again = make_extractor(json.loads(json.dumps(rec)))  # survives model.json
    assert again.config == ext.config
    assert np.array_equal(np.asarray(again.net.stem_w), np.asarray(ext.net.stem_w))
    with pytest.raises(ValueError, match="unknown"):
        make_extractor({"name": "clip"})


def _without(scan, tmp_path, key):
    """A copy of the capture's transforms.json (same files) without `key` on every frame."""
    meta = json.loads((scan / "transforms.json").read_text())
    for f in meta["frames"]:
        f.pop(key, None)
        for k in ("file_path", "depth_file_path", "mask_path", "part_mask_path"):
            if k in f:
                f[k] = str((scan / f[k]).resolve())
    d = tmp_path / f"{scan.name}_no_{key}"
    d.mkdir(exist_ok=True)
    (d / "transforms.json").write_text(json.dumps(meta))
    return d


def _red_box_sdf(scan, points, k):
    """Signed distance (m) of world points to the studio red_box's part k (a union of boxes)."""
    from rsrd_jax.studio import get_object

    z = np.load(scan / "gt" / "scan_gt.npz")
    T = np.asarray(jaxlie.SE3(jnp.asarray(z["T_world_part"][k], jnp.float32)).inverse().as_matrix(), np.float64)
    p = points @ T[:3, :3].T + T[:3, 3]
    out = np.full(len(p), np.inf)
    for g in get_object("red_box").parts[k].geoms:
        assert g.type == "box" and not any(g.euler)
        q = np.abs(p - np.asarray(g.pos)) - np.asarray(g.size)
        out = np.minimum(out, np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(1), 0.0))
    return out


def test_scan_surface_points_lie_on_the_surface_and_carve_what_the_views_see_through(studio_scan, tmp_path):
    """Centres = the true surface samples plus floaters 5 mm outside it. The scan's depth maps
    back-projected inside each part's mask lie on that part's true surface (the analytic boxes of
    the studio red_box; the depth's 1 mm quantisation), the floaters a view sees through are
    carved, the centres no view sees (the box's underside) are kept; without part masks the depth pixels take the nearest
    centre's part; a capture without depth is refused."""
    from scipy.spatial import cKDTree

    from rsrd_jax.parts import scan_surface_points

    world, ids = _gt_world(studio_scan)
    rng = np.random.default_rng(0)
    pick = rng.choice(np.flatnonzero(world[:, 2] > 0.01), 400, replace=False)  # above the table
    centre = np.stack([world[ids == k].mean(0) for k in range(2)])
    out_dir = world[pick] - centre[ids[pick]]
    out_dir /= np.linalg.norm(out_dir, axis=1, keepdims=True)
    floaters = world[pick] + 0.005 * out_dir
    means = np.concatenate([world, floaters])
    part_ids = np.concatenate([ids, ids[pick]])

    def check(pts, label_accuracy, tol=1.0e-3):
        for k in range(2):
            own, other = np.abs(_red_box_sdf(studio_scan, pts[k], k)), np.abs(_red_box_sdf(studio_scan, pts[k], 1 - k))
            assert np.percentile(own, 99) < tol, (k, np.percentile(own, 99))
            assert np.mean(own <= other) > label_accuracy, (k, np.mean(own <= other))

    # on-surface centres only: every returned point lies on its part's surface
    pts = scan_surface_points(studio_scan, world, ids, 2, voxel=0.0)
    check(pts, 0.98)
    thin = scan_surface_points(studio_scan, world, ids, 2)  # one point per millimetre cell
    assert all(len(t) < len(p) for t, p in zip(thin, pts))
    check(thin, 0.98)
    # without part masks: labelled by the nearest centre; without any mask the table's pixels
    # beyond `label_distance` (3 mm) of every centre are dropped (those nearer, at the box's
    # foot, stay)
    check(scan_surface_points(_without(studio_scan, tmp_path, "part_mask_path"), world, ids, 2), 0.95)
    check(scan_surface_points(_without(_without(studio_scan, tmp_path, "part_mask_path"), tmp_path, "mask_path"),
                              world, ids, 2), 0.95, tol=3e-3)  # fmt: skip
    # with floaters: those a view sees through are carved, the surface centres kept
    kept = cKDTree(np.concatenate(scan_surface_points(studio_scan, means, part_ids, 2, voxel=0.0)))
    floaters_kept = np.mean(kept.query(floaters)[0] < 1e-9)
    bottom = world[(ids == 0) & (world[:, 2] < 5e-4)]  # the box's underside, on the table: no view sees it
    bottom_kept = np.mean(kept.query(bottom)[0] < 1e-9)
    assert floaters_kept < 0.2, floaters_kept
    assert len(bottom) > 50 and bottom_kept > 0.9, (len(bottom), bottom_kept)
    with pytest.raises(ArtefactError, match="depth"):
        scan_surface_points(_without(studio_scan, tmp_path, "depth_file_path"), means, part_ids, 2)
