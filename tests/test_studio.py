"""The studio's ground truth checked against independent evidence (MuJoCo's own renders)."""

import hashlib
import json

import numpy as np
import pytest

from rsrd_jax.io import ArtefactError, read_capture, read_demo, read_demo_gt, read_depth_png, read_json, read_label_png
from rsrd_jax.studio import StudioConfig, get_object, list_objects, make_object

SMALL = StudioConfig(
    scan_views=6, scan_size=(160, 120), demo_frames=5, demo_size=(160, 120), robot_size=(320, 180), seed=3
)


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    root = tmp_path_factory.mktemp("studio")
    out = {}
    for name in ("red_box", "usb_plug", "frog"):
        out[name] = make_object(name, root / name, SMALL)
        out[name]["root"] = root / name
    return out


def _T(a7):
    import jaxlie

    return np.asarray(jaxlie.SE3(np.asarray(a7, np.float32)).as_matrix(), np.float64)


def _visible_projection(pts_cam, K, depth, tol=0.004):
    """Pixels hit by camera-frame points that are not hidden behind the rendered depth."""
    h, w = depth.shape
    z = pts_cam[:, 2]
    u = np.floor(K[0, 0] * pts_cam[:, 0] / z + K[0, 2]).astype(int)
    v = np.floor(K[1, 1] * pts_cam[:, 1] / z + K[1, 2]).astype(int)
    ok = (z > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    u, v, z = u[ok], v[ok], z[ok]
    vis = np.abs(depth[v, u] - z) < tol
    mask = np.zeros((h, w), bool)
    mask[v[vis], u[vis]] = True
    return mask


def _iou_after_dilation(pred, label_mask):
    """IoU of a (sparse) splat of projected GT points, closed to a silhouette, with a label mask;
    a 1-pixel tolerance at the silhouette edge."""
    import cv2

    k = np.ones((5, 5), np.uint8)
    pred = cv2.erode(cv2.dilate(pred.astype(np.uint8), k), np.ones((3, 3), np.uint8)) > 0
    edge = (cv2.dilate(label_mask.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0) & ~(
        cv2.erode(label_mask.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    )
    inter = (pred & label_mask) | (edge & (pred | label_mask))
    return inter.sum() / max((pred | label_mask).sum(), 1)


def test_catalogue_has_the_papers_objects():
    names = list_objects()
    for n in ["red_box", "nerf_gun", "scissors", "sunglasses", "bear", "stapler", "led_light",
              "wire_cutter", "usb_plug", "toy_drawer", "frog"]:  # fmt: skip
        assert n in names
    assert get_object("frog").num_parts >= 5
    assert get_object("usb_plug").separable and get_object("usb_plug").bimanual
    for n in names:
        obj = get_object(n)
        assert obj.keyframes, n
        for c in obj.contacts:
            assert 0 < c.width <= 0.05, f"{n}: contact width {c.width} is not graspable by the YuMi"
            assert c.part in obj.keyframes or obj.bimanual, f"{n}: single hand must touch the moved part"
    with pytest.raises(KeyError, match="known objects"):
        get_object("teapot")


def test_scan_loads_through_nerfstudio_reader(made):
    root = made["red_box"]["root"]
    cap = read_capture(root / "scan")
    assert len(cap) == SMALL.scan_views and cap.has_depth and cap.has_part_masks
    assert (cap.intrinsics.width, cap.intrinsics.height) == SMALL.scan_size
    fy = 0.5 * 120 / np.tan(np.deg2rad(SMALL.scan_fovy_deg) / 2)
    assert float(cap.intrinsics.fy) == pytest.approx(fy, rel=1e-5)
    with np.load(root / "scan/gt/scan_gt.npz") as z:
        np.testing.assert_allclose(cap.T_cam_world(), z["T_cam_world"], atol=2e-5)


@pytest.mark.parametrize("name", ["red_box", "usb_plug", "frog"])
def test_scan_gt_geometry_lands_on_part_masks_and_depth(made, name):
    root = made[name]["root"]
    cap = read_capture(root / "scan")
    with np.load(root / "scan/gt/scan_gt.npz") as z:
        T_wp = np.stack([_T(a) for a in z["T_world_part"]])
        pts, ids = z["part_points"], z["part_point_ids"]
    K = np.asarray(cap.intrinsics.K())
    ious = []
    for i in range(len(cap)):
        depth, labels = cap.depth(i), cap.part_mask(i)
        T_cw = cap.frames[i].T_cam_world
        for k in range(len(T_wp)):
            pk = pts[ids == k] @ T_wp[k, :3, :3].T + T_wp[k, :3, 3]
            pc = pk @ T_cw[:3, :3].T + T_cw[:3, 3]
            m = labels == k + 1
            if m.sum() < 30:
                continue
            ious.append(_iou_after_dilation(_visible_projection(pc, K, depth), m))
        # depth agrees with GT geometry: object pixels backproject onto the surface samples
        from scipy.spatial import cKDTree

        v, u = np.nonzero(labels > 0)
        d = depth[v, u]
        pc = np.stack([(u + 0.5 - K[0, 2]) / K[0, 0] * d, (v + 0.5 - K[1, 2]) / K[1, 1] * d, d], 1)
        pw = (pc - T_cw[:3, 3]) @ T_cw[:3, :3]
        allw = np.concatenate([pts[ids == k] @ T_wp[k, :3, :3].T + T_wp[k, :3, 3] for k in range(len(T_wp))])
        dist, _ = cKDTree(allw).query(pw)
        assert np.median(dist) < 0.003, f"view {i}: depth is off the GT surface by {np.median(dist):.4f} m"
    assert np.mean(ious) > 0.75 and min(ious) > 0.4, ious


def test_scan_gt_points_are_the_visible_hull(made):
    """frog's leg capsules end inside its body: their buried surface samples must not be in the GT
    (they would claim body Gaussians for the legs). Reference: MuJoCo's rendered scan depth."""
    from rsrd_jax.studio._scene import SceneOptions, build_scene, buried_points, part_surface_points

    root = made["frog"]["root"]
    cap = read_capture(root / "scan")
    with np.load(root / "scan/gt/scan_gt.npz") as z:
        T_wp = np.stack([_T(a) for a in z["T_world_part"]])
        gt_pts, gt_ids = z["part_points"], z["part_point_ids"]
    with build_scene(get_object("frog"), np.eye(4), SceneOptions(32, 32, 45.0, 0)) as sc:
        sc.set_configuration(0.0)
        T0 = sc.part_poses()
        raw = [part_surface_points(sc.model, b, 1500, SMALL.seed + k) for k, b in enumerate(sc.body_ids)]
        w0 = [p @ T0[k, :3, :3].T + T0[k, :3, 3] for k, p in enumerate(raw)]
        buried = np.concatenate([buried_points(sc.model, sc.data, w, sc.body_ids) for w in w0])
        deep = np.concatenate([buried_points(sc.model, sc.data, w, sc.body_ids, margin=0.002) for w in w0])
    world = np.concatenate([p @ T_wp[k, :3, :3].T + T_wp[k, :3, 3] for k, p in enumerate(raw)])
    K = np.asarray(cap.intrinsics.K())
    seen = np.zeros(len(world), bool)
    for i in range(len(cap)):
        T_cw = cap.frames[i].T_cam_world
        pc = world @ T_cw[:3, :3].T + T_cw[:3, 3]
        u = np.floor(K[0, 0] * pc[:, 0] / pc[:, 2] + K[0, 2]).astype(int)
        v = np.floor(K[1, 1] * pc[:, 1] / pc[:, 2] + K[1, 2]).astype(int)
        ok = (u >= 0) & (u < cap.intrinsics.width) & (v >= 0) & (v < cap.intrinsics.height)
        depth = cap.depth(i)[v.clip(0, cap.intrinsics.height - 1), u.clip(0, cap.intrinsics.width - 1)]
        seen |= ok & (np.abs(depth - pc[:, 2]) < 0.0015)
    assert buried.mean() > 0.03, buried.mean()
    # samples buried 2 mm deep are never in front of MuJoCo's depth (shallower ones sit within the
    # depth tolerance along the seams); most unburied samples are seen by some view
    assert deep.mean() > 0.03 and seen[deep].mean() < 0.01, (deep.mean(), seen[deep].mean())
    assert seen[~buried].mean() > 0.5, seen[~buried].mean()
    # the GT keeps exactly the unburied samples of every part
    gt_world = np.concatenate([gt_pts[gt_ids == k] @ T_wp[k, :3, :3].T + T_wp[k, :3, 3] for k in range(len(T_wp))])
    np.testing.assert_allclose(gt_world, world[~buried], atol=1e-5)


@pytest.mark.parametrize("name", ["red_box", "usb_plug", "frog"])
def test_demo_gt_poses_land_on_demo_part_masks(made, name):
    root = made[name]["root"]
    demo = read_demo(root / "demo" / "demo.mp4")
    gt = read_demo_gt(root / "demo")
    obj = get_object(name)
    assert demo.num_frames == SMALL.demo_frames
    assert gt["T_cam_world_part"].shape == (SMALL.demo_frames, obj.num_parts, 7)
    assert gt["keypoints_world"].shape == (SMALL.demo_frames, len(obj.contacts), 2, 3)
    with np.load(root / "scan/gt/scan_gt.npz") as z:
        T_wp_scan = np.stack([_T(a) for a in z["T_world_part"]])
        pts, ids = z["part_points"], z["part_point_ids"]
    K = np.asarray(demo.intrinsics.K())
    ious = []
    for t in range(demo.num_frames):
        depth = read_depth_png(root / f"demo/gt/depth/{t:05d}.png")
        labels = read_label_png(root / f"demo/gt/part_mask/{t:05d}.png")
        for k in range(obj.num_parts):
            # T_cam_world_part takes the part's points in the *scan's* world frame into the camera
            pw = pts[ids == k] @ T_wp_scan[k, :3, :3].T + T_wp_scan[k, :3, 3]
            T = _T(gt["T_cam_world_part"][t, k])
            pc = pw @ T[:3, :3].T + T[:3, 3]
            m = labels == k + 1
            if m.sum() >= 30:
                ious.append(_iou_after_dilation(_visible_projection(pc, K, depth), m))
        # the moved parts really move: the hand keypoints follow their contact parts
    assert np.mean(ious) > 0.75 and min(ious) > 0.4, ious
    moving = list(obj.keyframes)
    T0, T1 = gt["T_obj_part"][0, moving], gt["T_obj_part"][-1, moving]
    assert np.abs(T0 - T1).max() > 0.01
    static = [k for k in range(obj.num_parts) if k not in obj.keyframes and obj.parts[k].parent is None]
    np.testing.assert_allclose(gt["T_obj_part"][:, static], np.broadcast_to(gt["T_obj_part"][:1, static], gt["T_obj_part"][:, static].shape), atol=1e-6)
    # fingertips are within a finger radius + 1 cm of their contact part's surface
    for h, c in enumerate(obj.contacts):
        for t in range(demo.num_frames):
            Twp = _T(gt["T_world_part"][t, c.part])
            pw = pts[ids == c.part] @ Twp[:3, :3].T + Twp[:3, 3]
            d = np.linalg.norm(pw[None] - gt["keypoints_world"][t, h][:, None], axis=-1).min(1)
            assert d.max() < 0.02, (name, h, t, d)


def test_hand_masks_cover_visible_keypoints(made):
    root = made["red_box"]["root"]
    gt = read_demo_gt(root / "demo")
    hits = 0
    for t in range(SMALL.demo_frames):
        hand = read_label_png(root / f"demo/gt/hand_mask/{t:05d}.png") > 0
        assert hand.any(), "the proxy hand is visible in every frame"
        for (u, v), vis in zip(gt["keypoints_uv"][t].reshape(-1, 2), gt["keypoints_visible"][t].reshape(-1)):
            if vis:
                hits += hand[max(int(v) - 3, 0) : int(v) + 4, max(int(u) - 3, 0) : int(u) + 4].any()
    assert hits > 0


def test_robot_view_gt_projects_onto_object(made):
    root = made["frog"]["root"]
    cam = read_json(root / "robot_view/camera.json")
    gt = read_json(root / "robot_view/gt.json")
    depth = read_depth_png(root / "robot_view/depth.png")
    labels = read_label_png(root / "robot_view/part_mask.png")
    T_robot_world = np.asarray(gt["T_robot_world_matrix"])
    T_cam_robot = np.linalg.inv(np.asarray(cam["T_robot_cam_matrix"]))
    K = np.array([[cam["fl_x"], 0, cam["cx"]], [0, cam["fl_y"], cam["cy"]], [0, 0, 1]])
    with np.load(root / "scan/gt/scan_gt.npz") as z:
        T_wp = np.stack([_T(a) for a in z["T_world_part"]])
        pts, ids = z["part_points"], z["part_point_ids"]
    pw = np.concatenate([pts[ids == k] @ T_wp[k, :3, :3].T + T_wp[k, :3, 3] for k in range(len(T_wp))])
    pr = pw @ T_robot_world[:3, :3].T + T_robot_world[:3, 3]
    assert pr[:, 2].min() == pytest.approx(0.0, abs=2e-3), "object rests on the table top (z = 0)"
    pc = pr @ T_cam_robot[:3, :3].T + T_cam_robot[:3, 3]
    iou = _iou_after_dilation(_visible_projection(pc, K, depth, tol=0.006), labels > 0)
    assert iou > 0.75


def test_deterministic_for_a_seed_and_noise_option(tmp_path):
    cfg = StudioConfig(scan_views=2, scan_size=(64, 48), parts=("scan",), seed=5)
    make_object("stapler", tmp_path / "a", cfg)
    make_object("stapler", tmp_path / "b", cfg)
    h = lambda p: hashlib.sha256(p.read_bytes()).hexdigest()  # noqa: E731
    assert h(tmp_path / "a/scan/images/00001.png") == h(tmp_path / "b/scan/images/00001.png")
    assert json.loads((tmp_path / "a/scan/transforms.json").read_text()) == json.loads((tmp_path / "b/scan/transforms.json").read_text())
    noisy = StudioConfig(scan_views=8, scan_size=(64, 48), parts=("scan",), seed=5, pose_noise_deg=2.0, pose_noise_m=0.005)
    make_object("stapler", tmp_path / "n", noisy)
    cap = read_capture(tmp_path / "n/scan")
    with np.load(tmp_path / "n/scan/gt/scan_gt.npz") as z:
        T_true = z["T_cam_world"]
    ang = [np.rad2deg(np.arccos(np.clip((np.trace(a[:3, :3] @ b[:3, :3].T) - 1) / 2, -1, 1))) for a, b in zip(cap.T_cam_world(), T_true)]
    assert 0.5 < np.mean(ang) < 8.0


def test_bad_inputs(tmp_path):
    with pytest.raises(KeyError, match="teapot"):
        make_object("teapot", tmp_path / "x")
    (tmp_path / "exists").mkdir()
    (tmp_path / "exists" / "keep.txt").write_text("user data")
    with pytest.raises(FileExistsError, match="overwrite"):
        make_object("red_box", tmp_path / "exists")
    assert (tmp_path / "exists" / "keep.txt").read_text() == "user data"
    with pytest.raises(ValueError, match="unknown studio products"):
        make_object("red_box", tmp_path / "y", StudioConfig(parts=("scan", "movie")))
    with pytest.raises(ArtefactError, match="not found"):
        read_demo_gt(tmp_path)
