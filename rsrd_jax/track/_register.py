"""Robot-view registration: the object's pose in the robot base frame from one RGB + metric-depth
view with known extrinsics (the paper's ZED stereo camera; the studio's `robot_view/`).

It reuses the tracking initialiser's vmapped multi-seed optimisation in its metric-depth mode
(feature loss + metric depth loss, `track._init`). Metric depth and known extrinsics make the
seeds better than on a monocular frame: the object is the blob standing above the table plane,
and the seeds stand the model upright on the table (its +z is "up", as for studio scans and
gravity-aligned phone scans) at yaws covering 360°.
"""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import equinox as eqx
import jaxlie
import jax.numpy as jnp
import jax
import numpy as np

from ..geometry import Camera, Intrinsics, backproject_depth, project_points
from ..io import ArtefactError, read_camera_json, read_depth_png, read_image_rgb, read_json, require
from ._config import InitConfig
from ._dpm import TrackModel
from ._dpm import lr_schedule, render_posed
from ._init import adam_about_centroid, in_lanes, padded_schedule, widest
from ._losses import feature_loss
from ._observe import model_extractor, Observer, crop, roi_box
from ..splat import apply_part_poses, choose_config, rest_part_poses

_trace_counts = {"optimise": 0}


class RobotView(eqx.Module):
    """One calibrated RGB-D view of the workspace (host numpy)."""

    rgb: np.ndarray
    """(H, W, 3) uint8 image."""
    depth: np.ndarray
    """(H, W) metric depth along the optical axis (m; 0 = unknown)."""
    intrinsics: Intrinsics
    """Camera intrinsics (OpenCV axes, pixel centres at +0.5)."""
    T_robot_cam: np.ndarray
    """(7,) wxyz_xyz camera pose in the robot base frame."""


def read_robot_view(path: str | Path) -> RobotView:
    """Reads a robot view directory: `rgb.png`, `depth.png` (16-bit mm) and `camera.json` with
    `T_robot_cam` (wxyz_xyz), as the studio writes it (or a studio object directory holding
    `robot_view/`).

    Raises:
        ArtefactError: naming the missing file or the bad field.
    """
    d = Path(path)
    if (d / "robot_view").is_dir():
        d = d / "robot_view"
    if not d.is_dir():
        raise ArtefactError(f"{d}: robot view directory not found (expected rgb.png, depth.png, camera.json)")
    for name in ("rgb.png", "depth.png", "camera.json"):
        if not (d / name).is_file():
            raise ArtefactError(f"{d / name}: missing (a robot view needs rgb.png, depth.png and camera.json)")
    K = read_camera_json(d / "camera.json")
    meta = read_json(d / "camera.json", "camera.json")
    require("T_robot_cam" in meta, d / "camera.json", "T_robot_cam", "the camera pose in the robot frame (wxyz_xyz)")
    T = np.asarray(meta["T_robot_cam"], np.float64)
    require(T.shape == (7,) and np.all(np.isfinite(T)), d / "camera.json", "T_robot_cam", "7 finite numbers (wxyz_xyz)")
    rgb = read_image_rgb(d / "rgb.png")
    depth = read_depth_png(d / "depth.png")
    for name, arr in (("rgb.png", rgb), ("depth.png", depth)):
        if arr.shape[:2] != (K.height, K.width):
            raise ArtefactError(f"{d / name}: size {arr.shape[1]}×{arr.shape[0]} differs from camera.json {K.width}×{K.height}")
    return RobotView(rgb=rgb, depth=depth.astype(np.float32), intrinsics=K, T_robot_cam=T)


class RegistrationStatus(eqx.Enumeration):
    """Outcome of `register_object`, judged without ground truth."""

    ok = "the posed model explains the observed object points (residual ≤ max_residual_mm)"
    poor_fit = "the observed object points lie far from the posed model: a wrong basin or a bad model"


class Registration(eqx.Module):
    """Result of `register_object` (host numpy)."""

    status: RegistrationStatus
    """`ok` or `poor_fit` (from `residual_mm`)."""

    T_robot_obj: np.ndarray
    """(7,) object (model/scan frame) pose in the robot base frame, wxyz_xyz."""
    T_cam_obj: np.ndarray
    """(7,) object pose in the camera frame, wxyz_xyz."""
    loss: float
    """Final objective (feature + metric depth) of the refined pose."""
    residual_mm: float
    """Median distance from the observed object points (the blob's metric depth) to the nearest
    posed model Gaussian centre (mm): a self-check that needs no ground truth."""
    info: dict = eqx.field(static=True)
    """Diagnostics: seed losses, chosen seed, blob size, ICP statistics, timings."""

    @property
    def status_name(self) -> str:
        """``"ok"`` or ``"poor_fit"``."""
        return "ok" if bool(self.status == RegistrationStatus.ok) else "poor_fit"


def _segment_object(view: RobotView, table_z: float, min_height: float, workspace, join_m: float = 0.03) -> np.ndarray:
    """H×W bool mask of the object: pixels standing above the table plane (robot frame
    z > table_z + min_height) inside the workspace box, as the largest connected blob plus the
    blobs within `join_m` (m) of it."""
    K = view.intrinsics
    pc = np.asarray(backproject_depth(K, jnp.asarray(view.depth)), np.float64).reshape(-1, 3)
    T = np.asarray(jaxlie.SE3(jnp.asarray(view.T_robot_cam, jnp.float32)).as_matrix(), np.float64)
    pr = pc @ T[:3, :3].T + T[:3, 3]
    (x0, x1), (y0, y1), z1 = workspace
    ok = (view.depth.reshape(-1) > 0) & (pr[:, 2] > table_z + min_height) & (pr[:, 2] < z1)
    ok &= (pr[:, 0] > x0) & (pr[:, 0] < x1) & (pr[:, 1] > y0) & (pr[:, 1] < y1)
    mask = ok.reshape(K.height, K.width).astype(np.uint8)
    # close 1-pixel gaps (thin parts), drop isolated speckle
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    n, lab, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    big = [i for i in range(1, n) if stats[i, cv2.CC_STAT_AREA] >= 4]
    if not big:
        raise RegistrationError(
            "robot view: no object found standing above the table (no depth pixels more than "
            f"{min_height * 1e3:.0f} mm above z = {table_z} m inside the workspace)"
        )
    # the object: the largest blob plus every blob whose points come within `join_m` of it (thin
    # objects such as scissors break into pieces at the height threshold)
    k = max(big, key=lambda i: stats[i, cv2.CC_STAT_AREA])
    pts = pr.reshape(K.height, K.width, 3)
    from scipy.spatial import cKDTree

    tree = cKDTree(pts[lab == k][::4])
    keep = lab == k
    for i in big:
        if i != k and np.min(tree.query(pts[lab == i][::2])[0]) < join_m:
            keep |= lab == i
    return keep


class RegWeights(eqx.Module):
    """Weights of the registration objective (all terms are means over the ROI grid)."""

    feature: float = 1.0
    """Feature distance (as in tracking)."""
    depth: float = 4.0
    """|rendered − measured| depth where render and measurement both see the object, clipped at
    `depth_clip`, / clip."""
    silhouette: float = 4.0
    """Squared difference of rendered alpha and the above-table blob mask."""
    below_table: float = 100.0
    """Mean depth (m) of Gaussian centres below the table plane."""
    depth_clip: float = 0.05
    """Clip of the depth residual (m)."""


def _reg_objective(tm, T_cam_obj, obs, rcfg, md, blob, T_robot_cam, table_z, w: RegWeights):
    r = render_posed(tm, rest_part_poses(tm.part_centroids), T_cam_obj, obs.intrinsics, obs.bg_feature, rcfg)
    loss = w.feature * feature_loss(r.features, obs.features, obs.weight)
    # depth only where both the render and the measurement see the object: at the silhouette's
    # blurred rim the measurement is the table, which the silhouette term already covers
    m = (r.alpha > 0.5) * (md > 0) * (blob > 0.5)
    err = jnp.clip(jnp.abs(r.depth - md), 0.0, w.depth_clip) / w.depth_clip
    loss = loss + w.depth * jnp.sum(m * err) / jnp.maximum(jnp.sum(m), 1.0)
    loss = loss + w.silhouette * jnp.mean((r.alpha - blob) ** 2)
    z = (T_robot_cam @ T_cam_obj).apply(r.means)[:, 2]
    return loss + w.below_table * jnp.mean(jax.nn.relu(table_z - z))


@eqx.filter_jit
def _optimise(tm, T_seeds: jaxlie.SE3, c, scale, obs, lrs, steps, rcfg, md, blob, T_robot_cam, table_z, w: RegWeights):
    """Vmapped Adam over seeds on tangent updates about the object centroid `c` (the first
    `steps`, traced, of the learning rates `lrs`); the translation part is in units of the
    object's diameter (2 · `scale`), so a step of lr moves the object by that fraction of its
    size, whatever its size (rotation: lr radians)."""
    _trace_counts["optimise"] += 1
    units = jnp.concatenate([jnp.full(3, 2.0 * scale), jnp.ones(3)])

    def one(T_seed):
        loss_at = lambda T: _reg_objective(tm, T, obs, rcfg, md, blob, T_robot_cam, table_z, w)  # noqa: E731
        T = adam_about_centroid(loss_at, T_seed, c, lrs, units, steps=steps)
        feat = _reg_objective(tm, T, obs, rcfg, md, blob, T_robot_cam, table_z, RegWeights(1.0, 0.0, 0.0, 0.0, w.depth_clip))
        return T.wxyz_xyz, loss_at(T), feat

    return jax.vmap(one)(T_seeds)


def icp_refine(
    T_init: np.ndarray, model_points: np.ndarray, observed: np.ndarray, iters: int = 30, trim_m: float = 0.015
) -> tuple[np.ndarray, dict]:
    """Trimmed point-to-point ICP from observed points to the model (host numpy, float64).

    Every observed point lies on a visible model surface, so correspondences go observed → nearest
    model point (robust to the model's self-occluded far side); pairs farther than `trim_m` are
    dropped (floaters, the table's rim). Rigid updates by Kabsch.

    Args:
        T_init: 4×4 initial `T_frame_obj`.
        model_points: (N, 3) model points (object frame).
        observed: (M, 3) observed points in the same frame as `T_init` maps into.
        iters: iterations.
        trim_m: largest correspondence distance kept (m).

    Returns:
        (4×4 refined pose, {"rms_mm", "inliers", "iterations"}).
    """
    from scipy.spatial import cKDTree

    tree = cKDTree(model_points)
    T = np.array(T_init, np.float64)
    rms, n_in, it = float("nan"), 0, 0
    for it in range(1, iters + 1):
        # observed -> object frame
        q = (observed - T[:3, 3]) @ T[:3, :3]
        d, idx = tree.query(q)
        keep = d < trim_m
        n_in = int(keep.sum())
        if n_in < 10:
            break
        rms = float(np.sqrt(np.mean(d[keep] ** 2)) * 1e3)
        A = model_points[idx[keep]]  # object frame
        B = observed[keep]  # target frame
        ca, cb = A.mean(0), B.mean(0)
        U, _, Vt = np.linalg.svd((A - ca).T @ (B - cb))
        D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
        Rn = Vt.T @ D @ U.T
        Tn = np.eye(4)
        Tn[:3, :3], Tn[:3, 3] = Rn, cb - Rn @ ca
        step = np.linalg.norm(Tn[:3, 3] - T[:3, 3])
        T = Tn
        if step < 1e-5:
            break
    return T, {"rms_mm": rms, "inliers": n_in, "iterations": it}


def select_seed(losses, feature_losses, window: float = 0.05) -> int:
    """The registration's seed: among the seeds whose total loss is within `window` (a fraction of
    the lowest's magnitude) of the lowest, the one of lowest feature loss.

    Why: the depth and silhouette terms barely tell a 90° or 180° turn of a near-symmetric outline
    from the right pose, the features do; on the robot trials' 11 objects × 10 orientations the
    lowest total made 3 such flips, this rule (5 %) none and changed no other registration
    (`experiments/results/registration_seeds_s44.md`).
    """
    L, F = np.asarray(losses, np.float64), np.asarray(feature_losses, np.float64)
    if L.shape != F.shape or L.ndim != 1 or L.size == 0:
        raise ValueError(f"seed losses: expected two equal-length 1-D arrays, got {L.shape} and {F.shape}")
    if not window >= 0.0:
        raise ValueError(f"feature_window: expected a fraction >= 0, got {window}")
    near = np.flatnonzero(L <= L.min() + window * abs(L.min()))
    return int(near[np.argmin(F[near])])


class RegistrationError(ArtefactError):
    """The robot view does not show an object to register."""


def register_object(
    model,
    view: RobotView,
    init: InitConfig = InitConfig(yaw_seeds=16, iters=50, refine_iters=0, lr_start=2e-2, lr_end=2e-3),
    weights: RegWeights = RegWeights(),
    roi_size: int = 224,
    max_gaussians: int = 4000,
    table_z: float = 0.0,
    min_height: float = 0.003,
    workspace: tuple = ((0.1, 0.9), (-0.5, 0.5), 0.5),
    icp_iters: int = 30,
    icp_trim_m: float = 0.015,
    max_residual_mm: float = 6.0,
    extractor=None,
    seed: int = 0,
    feature_window: float = 0.05,
) -> Registration:
    """Estimates the object's pose in the robot frame from one calibrated RGB-D view.

    Seeds: the object's pixels are the largest blob standing above the table plane (metric depth
    + extrinsics); each of `init.yaw_seeds` yaws about the robot's z puts the model upright
    (object +z = robot +z) with its lowest points on the table and its centroid under the blob's
    centroid. All seeds are then optimised in parallel (vmapped Adam on feature distance, metric
    depth, silhouette against the blob and a below-the-table penalty, `RegWeights`) on a crop
    around the blob; the best is refined on an ROI around it, then by trimmed ICP of the blob's
    metric points onto the model (feature-grid cells are ≈ 1 cm; ICP is not bound to them).

    Args:
        model: the `ObjectModel` (rsrd_jax.parts) built from the scan (its +z is up).
        view: the robot camera's RGB, metric depth, intrinsics and `T_robot_cam`.
        init: seed count, iterations and learning rates (`yaw_seeds`, `iters`, `lr_start`,
            `lr_end`; `refine_iters` > 0 adds an ROI refinement of the best seed before ICP).
        weights: weights of the registration objective.
        roi_size: crop side (pixels) given to the feature extractor.
        max_gaussians: Gaussians used for rendering.
        table_z: table top height in the robot frame (m).
        min_height: pixels higher than this above the table count as object (m).
        workspace: ((x0, x1), (y0, y1), z_max) box in the robot frame where the object may be.
        icp_iters: iterations of the final ICP refinement (0: off), see `icp_refine`.
        icp_trim_m: ICP correspondence trim distance (m).
        max_residual_mm: `status` is `poor_fit` above this residual.
        extractor: feature extractor (default rebuilt from the model's backend).
        seed: Gaussian subsampling seed.
        feature_window: seed selection, see `select_seed` (0: the lowest total loss).

    Returns:
        `Registration`.

    Raises:
        ArtefactError: bad depth, extractor/model mismatch, or nothing above the table.
    """
    K = view.intrinsics
    if not feature_window >= 0.0:
        raise ValueError(f"feature_window: expected a fraction >= 0, got {feature_window}")
    if not np.any(view.depth > 0) or not np.all(np.isfinite(view.depth)):
        raise ArtefactError("robot view depth: expected finite metric depth with some valid (> 0) pixels")
    extractor = model_extractor(model, extractor)
    t0 = time.perf_counter()
    tick = [t0]
    timings: dict[str, float] = {}

    def lap(name: str) -> None:
        now = time.perf_counter()
        timings[name] = round(now - tick[0], 3)
        tick[0] = now

    blob = _segment_object(view, table_z, min_height, workspace)
    tm = TrackModel.from_object_model(model, max_gaussians, seed)
    obsr = Observer(extractor, model.pca, K, roi_size)
    rest = rest_part_poses(tm.part_centroids)
    posed = apply_part_poses(tm.gaussians, rest, tm.part_centroids)
    means = np.asarray(posed.means, np.float64)
    c = means.mean(0)
    radius = float(np.percentile(np.linalg.norm(means - c, axis=1), 90))
    T_robot_cam = jaxlie.SE3(jnp.asarray(view.T_robot_cam, jnp.float32))
    Rrc = np.asarray(T_robot_cam.rotation().as_matrix(), np.float64)
    # blob centroid on the table, pushed away from the camera by a fraction of the object's radius
    # (the camera sees only the near side)
    pc = np.asarray(backproject_depth(K, jnp.asarray(view.depth)), np.float64)[blob]
    pr = pc @ Rrc.T + np.asarray(T_robot_cam.translation(), np.float64)
    centre = pr.mean(0)
    away = centre[:2] - np.asarray(T_robot_cam.translation(), np.float64)[:2]
    centre_xy = centre[:2] + 0.3 * radius * away / max(np.linalg.norm(away), 1e-6)
    yaws = np.arange(init.yaw_seeds) * 2 * np.pi / init.yaw_seeds
    z_floor = float(np.percentile(means[:, 2], 1))
    seeds = []
    for yaw in yaws:
        Rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
        rc = Rz @ c
        t = np.array([centre_xy[0] - rc[0], centre_xy[1] - rc[1], table_z - z_floor])
        T_ro = jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.from_matrix(jnp.asarray(Rz, jnp.float32)), jnp.asarray(t, jnp.float32))
        seeds.append((T_robot_cam.inverse() @ T_ro).wxyz_xyz)
    T_seeds = jaxlie.SE3(jnp.stack(seeds))
    # crop around the blob, grown so every yaw of the object fits
    ys, xs = np.nonzero(blob)
    uv = np.stack([xs + 0.5, ys + 0.5], -1)
    box = roi_box(uv, K.width, K.height, 0.35)
    lap("prepare")
    obs = obsr.observe(0, view.rgb, box)
    g = obs.features.shape[0]
    md = jnp.asarray(crop(view.depth, box, g, cv2.INTER_NEAREST))
    lap("observe")
    def roi_of(T: jaxlie.SE3):  # the refinement's crop: the posed model's projection, grown by 20 %
        uv, z = project_points(K, T @ posed.means)
        return roi_box(np.asarray(uv)[np.asarray(z) > 0], K.width, K.height, 0.2)

    # render budgets for the seed crop and for the ROI crop of the refinement (framed alike at any
    # pose), so that one render config serves both stages
    cams = []
    for i in range(0, len(yaws), max(1, len(yaws) // 4)):
        Ti = jaxlie.SE3(T_seeds.wxyz_xyz[i])
        cams += [Camera(obs.intrinsics, Ti), Camera(obsr.grid_intrinsics(roi_of(Ti)), Ti)]
    rcfg = choose_config(posed, cams, headroom=1.5)
    cj = jnp.asarray(c, jnp.float32)
    lap("choose_config")
    blob_g = jnp.asarray(crop(blob.astype(np.float32), box, g, cv2.INTER_AREA))
    tz = jnp.float32(table_z)
    # the seeds and the ROI refinement run one compiled function: `lanes` seeds per call, the
    # schedules padded to one length, one render config (`_init.in_lanes`)
    lanes = max(1, min(init.keep_seeds, len(yaws)))
    L = max(init.iters, init.refine_iters)

    def optimise(T, obs_, schedule, md_, blob_, rcfg_):
        lr, steps = padded_schedule(schedule, L)
        return in_lanes(lambda Tb: _optimise(tm, Tb, cj, jnp.float32(radius), obs_, lr, steps, rcfg_, md_, blob_,
                                             T_robot_cam, tz, weights), T, lanes, init.parallel)  # fmt: skip

    Ts, losses, feats = optimise(T_seeds.wxyz_xyz, obs, lr_schedule(init.lr_start, init.lr_end, init.iters), md, blob_g, rcfg)
    best = select_seed(losses, feats, feature_window)
    order = np.array([best] + [int(i) for i in np.argsort(losses) if i != best])
    T_best = jaxlie.SE3(jnp.asarray(Ts[best]))
    T_cam_obj, final_loss = T_best, float(losses[best])
    refined = None
    lap("optimise_seeds")
    if init.refine_iters > 0:  # refine the best seeds (one batch) on an ROI around the best pose
        box2 = roi_of(T_best)
        obs2 = obsr.observe(0, view.rgb, box2)
        md2 = jnp.asarray(crop(view.depth, box2, g, cv2.INTER_NEAREST))
        rcfg2 = widest(rcfg, choose_config(posed, Camera(obs2.intrinsics, T_best), headroom=1.5))
        lrs2 = lr_schedule(init.lr_end, init.lr_end * 0.5, init.refine_iters)
        blob2 = jnp.asarray(crop(blob.astype(np.float32), box2, g, cv2.INTER_AREA))
        top = order[:lanes]
        Ts2, losses2, _ = optimise(Ts[top], obs2, lrs2, md2, blob2, rcfg2)
        k2 = int(np.argmin(losses2))
        best = int(top[k2])
        T_cam_obj, final_loss = jaxlie.SE3(jnp.asarray(Ts2[k2])), float(losses2[k2])
        refined = {"seeds": [int(i) for i in top], "losses": np.asarray(losses2).tolist()}
    # metric refinement: ICP of the blob's points (camera frame) onto the model's Gaussian centres
    icp_info = {}
    if icp_iters > 0:
        T_icp, icp_info = icp_refine(np.asarray(T_cam_obj.as_matrix(), np.float64), means, pc, icp_iters, icp_trim_m)
        T_cam_obj = jaxlie.SE3.from_matrix(jnp.asarray(T_icp, jnp.float32))
    lap("icp")
    # self-check without ground truth: distance of the observed object points to the posed model
    from scipy.spatial import cKDTree

    T_np = np.asarray(T_cam_obj.as_matrix(), np.float64)
    d_obs, _ = cKDTree(means).query((pc - T_np[:3, 3]) @ T_np[:3, :3])
    resid = float(np.median(d_obs) * 1e3)
    T_robot_obj = T_robot_cam @ T_cam_obj
    lap("self_check")
    info = {
        "seed_losses": np.asarray(losses).tolist(), "seed_feature_losses": np.asarray(feats).tolist(), "best_seed": best, "best_yaw_deg": float(np.rad2deg(yaws[best])),
        "seed_poses_robot": np.asarray((T_robot_cam @ jaxlie.SE3(jnp.asarray(Ts))).wxyz_xyz).tolist(),
        "final_loss": final_loss, "refined": refined, "blob_pixels": int(blob.sum()),
        "icp": icp_info, "time_s": time.perf_counter() - t0, "timings_s": timings,
    }  # fmt: skip
    status = RegistrationStatus.ok if resid <= max_residual_mm else RegistrationStatus.poor_fit
    return Registration(
        status=status,
        T_robot_obj=np.asarray(T_robot_obj.wxyz_xyz, np.float64),
        T_cam_obj=np.asarray(T_cam_obj.wxyz_xyz, np.float64),
        loss=final_loss,
        residual_mm=resid,
        info=info,
    )


def registration_error(T_est: np.ndarray, T_gt: np.ndarray, points: np.ndarray) -> dict:
    """Pose error of an estimate against ground truth.

    Args:
        T_est, T_gt: (7,) wxyz_xyz poses of the same frame (e.g. `T_robot_obj`).
        points: (N, 3) object points (model frame) for the ADD error.

    Returns:
        {"translation_mm", "rotation_deg", "add_mm"}: displacement of the points' centroid,
        geodesic rotation error and mean point distance (ADD).
    """
    A = jaxlie.SE3(jnp.asarray(T_est, jnp.float32))
    B = jaxlie.SE3(jnp.asarray(T_gt, jnp.float32))
    d = B.inverse() @ A
    rot = float(np.rad2deg(np.linalg.norm(np.asarray(d.rotation().log()))))
    p = jnp.asarray(points, jnp.float32)
    add = float(np.mean(np.linalg.norm(np.asarray(_apply(A, p) - _apply(B, p)), axis=1)) * 1e3)
    c = p.mean(0)
    trans = float(np.linalg.norm(np.asarray(A @ c - B @ c)) * 1e3)
    return {"translation_mm": trans, "rotation_deg": rot, "add_mm": add}


def _apply(T: jaxlie.SE3, p):
    return p @ T.rotation().as_matrix().T + T.translation()
