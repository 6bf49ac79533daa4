"""`build_object_model`: capture directory → ObjectModel (3DGS fit, feature field, parts, metrics)."""

from __future__ import annotations

import time
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from ..features import EfficientNetConfig, EfficientNetExtractor, FeatureExtractor, fit_pca, mask_to_grid
from ..geometry import Camera, box_intrinsics, crop, project_points, roi_box
from ..io import ArtefactError, read_capture
from ..splat import render
from ..splat._fit import (
    FitConfig,
    fit_gaussians,
    init_from_points,
    points_from_depth,
    points_in_frustums,
    psnr,
    size_render_config,
    ssim,
)
from ._field import FieldConfig, fit_feature_field, render_decoded
from ._labels import arap_pairs, auto_group, gt_part_accuracy, knn_cleanup, part_centroids, vote_part_labels
from ._model import FrozenDict, ObjectModel, feature_backend_record


class BuildConfig(eqx.Module):
    """Options of `build_object_model`."""

    fit: FitConfig = FitConfig()
    """3DGS fitting options."""
    field: FieldConfig = FieldConfig()
    """Feature-field options."""
    extractor: EfficientNetConfig = EfficientNetConfig()
    """Embedded EfficientNet-Lite0 extractor options (ignored when `onnx_path` is set)."""
    onnx_path: str | None = None
    """A ViT ONNX file (DINOv2) to use instead of EfficientNet (`OnnxConfig` defaults)."""
    pca_dim: int = 64
    """D: PCA dimension of the extractor features."""
    feature_crop_size: int | None = 224
    """Features are extracted from a square crop around the object in each view (tracking's ROI
    rule: the projected Gaussians' 1–99 % extent grown by `feature_crop_margin` per side),
    resampled to this many pixels, and the field is fitted on those grids. This puts the object
    at the scale tracking and registration observe it (their ROI crops default to 224) and gives
    the field ≈ 10× more supervised cells than whole 160×120 views. None: whole images."""
    feature_crop_margin: float = 0.25
    """Margin of the feature crops, as a fraction of the object's extent (tracking's default)."""
    init_gaussians: int = 4000
    """Initial Gaussians (from depth, else random in the frustum intersection)."""
    holdout_every: int = 8
    """Every k-th view (0, k, 2k, …) is held out of all fitting and used for metrics; 0 = none."""
    num_parts: int | None = None
    """Known part count; mask labels above it are an error (None: the largest label seen)."""
    part_names: tuple[str, ...] | None = None
    """Part names (default part0, part1, …)."""
    visibility_tolerance: float = 0.004
    """Depth agreement (metres) for a Gaussian to vote in a view."""
    knn_cleanup: int = 10
    """Neighbours of the label cleanup."""
    group_scale: float = 1.0
    """Automatic grouping granularity when there are no part masks (larger: fewer parts)."""
    arap_radius: float | None = None
    """Cross-part pair radius in metres; None: max(2.5 mm, 2.5 × the median nearest-neighbour
    spacing of the Gaussians). Studio objects are 10–15 cm, like the paper's, so 2.5 mm is kept."""
    crop_box: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    """World box isolating the object when the capture has no masks."""
    use_masks: bool = True
    """Isolate the object by the capture's masks when present."""


def _load(cap, idx, name, fn):
    out = []
    for i in idx:
        out.append(fn(i))
    return np.stack(out)


def _check_part_masks(cap, idx, pm: np.ndarray, num_parts: int | None) -> int:
    top = int(pm.max())
    if num_parts is not None:
        if top > num_parts:
            bad = next(i for i, m in zip(idx, pm) if m.max() > num_parts)
            raise ArtefactError(
                f"{cap.frames[bad].part_mask_path}: part label {int(pm[list(idx).index(bad)].max())} "
                f"but the model has {num_parts} parts (labels 0..{num_parts})"
            )
        return num_parts
    if top == 0:
        raise ArtefactError(f"{cap.root / 'transforms.json'}: part masks contain no part labels (all 0)")
    seen = set(np.unique(pm).tolist()) - {0}
    missing = sorted(set(range(1, top + 1)) - seen)
    if missing:
        raise ArtefactError(
            f"{cap.root / 'transforms.json'}: part masks use labels up to {top} but labels {missing} never appear"
        )
    return top


def _extract(extractor: FeatureExtractor, images: np.ndarray, batch: int = 8) -> np.ndarray:
    outs = []
    for s in range(0, len(images), batch):
        outs.append(np.asarray(extractor(images[s : s + batch]).features))
    return np.concatenate(outs)


def support_plane(intrinsics, T_cam_world: np.ndarray, depths: np.ndarray, masks: np.ndarray, centre: np.ndarray,
                  radius: float, inlier_m: float = 0.002, iterations: int = 5) -> list[float] | None:  # fmt: skip
    """The table the scanned object rests on, (n, d) with n·x = d (world frame, unit n towards
    the cameras), from the scan's depth maps: the background pixels (outside the object masks)
    within `radius` of the object's `centre`, back-projected, fitted with a plane by least
    squares, refitted `iterations` times on the points within max(`inlier_m`, 3 × the median
    absolute residual) of it. None without enough background depth (fewer than 100 points)."""
    fx, fy, cx, cy = (float(x) for x in (intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy))
    H, W = depths.shape[1:]
    uu, vv = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    pts, eyes = [], []
    for v in range(len(depths)):
        ok = (depths[v] > 0) & ~masks[v]
        z = depths[v][ok]
        pc = np.stack([(uu[ok] - cx) / fx * z, (vv[ok] - cy) / fy * z, z], -1)
        Twc = np.linalg.inv(T_cam_world[v])
        pts.append(pc @ Twc[:3, :3].T + Twc[:3, 3])
        eyes.append(Twc[:3, 3])
    pts = np.concatenate(pts)
    pts = pts[np.linalg.norm(pts - centre, axis=1) <= radius]
    if len(pts) < 100:
        return None
    keep = np.ones(len(pts), bool)
    for _ in range(iterations):
        q = pts[keep]
        m = q.mean(0)
        n = np.linalg.svd(q - m, full_matrices=False)[2][-1]
        r = np.abs((pts - m) @ n)
        keep = r <= max(inlier_m, 3.0 * float(np.median(r[keep])))
        if keep.sum() < 100:
            return None
    if (np.mean(eyes, 0) - m) @ n < 0:
        n = -n
    return [float(v) for v in n] + [float(m @ n)]


def build_object_model(
    capture_dir: str | Path,
    config: BuildConfig = BuildConfig(),
    progress: bool = True,
    rrd_path: str | Path | None = None,
) -> ObjectModel:
    """Builds the ObjectModel of the object in a scan capture (see the `parts` docstring).

    Stages: load → init (depth back-projection, or random in the frustum intersection) → 3DGS
    fit → feature extraction + PCA → feature field → part labels (mask voting with visibility +
    kNN cleanup, or automatic grouping) → centroids, ARAP pairs → held-out metrics. Times of each
    stage and the metrics are in `model.meta`.

    Raises:
        ArtefactError: bad capture (missing files, mismatched sizes, non-finite poses, unknown labels).
    """
    times: dict[str, float] = {}
    t = time.perf_counter()
    cap = read_capture(capture_dir)
    V = len(cap)
    idx = np.arange(V)
    if config.holdout_every and V >= 2 * config.holdout_every:
        test = idx[idx % config.holdout_every == 0]
    else:
        test = idx[:0]
    train = np.setdiff1d(idx, test)
    images = _load(cap, idx, "image", cap.image)
    use_masks = config.use_masks and all(f.mask_path is not None for f in cap.frames)
    masks = _load(cap, idx, "mask", cap.valid_mask) if use_masks else None
    depths = _load(cap, idx, "depth", cap.depth) if cap.has_depth else None
    part_masks = _load(cap, idx, "part mask", cap.part_mask) if cap.has_part_masks else None
    num_parts = None
    if part_masks is not None:
        num_parts = _check_part_masks(cap, idx, part_masks, config.num_parts)
        if masks is None and config.use_masks:
            masks = part_masks > 0
    T = cap.T_cam_world()
    intr = cap.intrinsics
    times["load_s"] = time.perf_counter() - t

    # 3DGS
    t = time.perf_counter()
    if depths is not None:
        pts, cols = points_from_depth(intr, T[train], images[train], depths[train],
                                      None if masks is None else masks[train], 20 * config.init_gaussians)  # fmt: skip
    else:
        pts = points_in_frustums(intr, T[train], 5 * config.init_gaussians, masks=None if masks is None else masks[train])
        cols = np.full((len(pts), 3), 0.5)
    g0 = init_from_points(pts, cols, config.init_gaussians, seed=config.fit.seed)
    fit = fit_gaussians(g0, images[train], intr, T[train], None if masks is None else masks[train], config.fit,
                        crop_box=config.crop_box, progress=progress)  # fmt: skip
    g = fit.gaussians
    T_train = np.asarray(jaxlie.SE3(fit.T_cam_world).as_matrix(), np.float64)
    times["fit_s"] = time.perf_counter() - t

    # features
    t = time.perf_counter()
    if config.onnx_path is not None:
        from ..features import OnnxConfig, OnnxFeatureExtractor

        extractor: FeatureExtractor = OnnxFeatureExtractor(OnnxConfig(path=config.onnx_path))
    else:
        extractor = EfficientNetExtractor.pretrained(config.extractor)
    obj_mask = masks if masks is not None else np.ones(images.shape[:3], bool)
    T_all = np.array(T, np.float64)
    T_all[train] = T_train
    view_K = None
    if config.feature_crop_size:
        feat_images, feat_masks, view_K = _object_crops(g, intr, T_all, images, obj_mask,
                                                        config.feature_crop_size, config.feature_crop_margin)  # fmt: skip
    else:
        feat_images, feat_masks = images, obj_mask
    fmaps = _extract(extractor, feat_images)
    gh, gw = fmaps.shape[1:3]
    grid_valid = mask_to_grid(feat_masks, (gh, gw))
    if view_K is not None:
        view_K = [box_intrinsics(intr, box, gh) for box in view_K]
    pca = fit_pca([fmaps[i] for i in train], masks=[grid_valid[i] for i in train], dim=config.pca_dim)
    targets = np.asarray(pca.project(jnp.asarray(fmaps)))
    times["features_s"] = time.perf_counter() - t

    t = time.perf_counter()
    g, decoder, field_hist = fit_feature_field(g, targets[train], grid_valid[train], intr, T_train, config.field, progress,
                                               view_intrinsics=None if view_K is None else [view_K[i] for i in train])  # fmt: skip
    times["field_s"] = time.perf_counter() - t

    # parts
    t = time.perf_counter()
    means = np.asarray(g.means, np.float64)
    if part_masks is not None:
        if depths is not None:
            dep = depths[train]
        else:
            dep = _render_depths(g, intr, T_train)
        votes = vote_part_labels(means, intr, T_train, part_masks[train], dep, num_parts, config.visibility_tolerance)
        known = votes.sum(1) > 0
        labels = knn_cleanup(means, np.argmax(votes, 1), known, config.knn_cleanup)
        grouping = "mask_voting"
    else:
        dec = np.asarray(decoder(g.features))
        labels = auto_group(means, dec, config.group_scale, seed=config.fit.seed)
        num_parts = int(labels.max()) + 1
        known = np.ones(len(means), bool)
        grouping = "auto_hdbscan"
    # every part must own Gaussians
    present = np.unique(labels)
    if len(present) != num_parts:
        missing = sorted(set(range(num_parts)) - set(present.tolist()))
        raise ValueError(f"part grouping: parts {missing} received no Gaussians (too few views of them?)")
    cents = part_centroids(means, labels, num_parts)
    radius_obj = float(np.sqrt(np.mean(np.sum((means - means.mean(0)) ** 2, 1))))
    if config.arap_radius is None:
        from scipy.spatial import cKDTree

        d, _ = cKDTree(means).query(means, k=2)
        arap_r = max(0.0025, 2.5 * float(np.median(d[:, 1])))
    else:
        arap_r = float(config.arap_radius)
    pairs = arap_pairs(means, labels, arap_r)
    g = eqx.tree_at(lambda x: x.part_ids, g, jnp.asarray(labels, jnp.int32))
    times["parts_s"] = time.perf_counter() - t

    # metrics
    t = time.perf_counter()
    metrics: dict = {"num_gaussians": int(g.num_gaussians), "labelled_by_votes": float(known.mean()),
                     "arap_pairs": int(len(pairs)), "fit_final_loss": fit.history["blocks"][-1]["loss"],
                     "field_final_mse": field_hist["blocks"][-1]["mse"]}  # fmt: skip
    if len(test):
        metrics.update(_heldout_metrics(g, decoder, intr, T[test], images[test],
                                        None if masks is None else masks[test], targets[test], grid_valid[test],
                                        None if view_K is None else [view_K[i] for i in test]))  # fmt: skip
    gt = Path(cap.root) / "gt" / "scan_gt.npz"
    if gt.is_file():
        with np.load(gt) as z:
            Twp = jaxlie.SE3(jnp.asarray(z["T_world_part"], jnp.float32))
            pp, ids = z["part_points"], z["part_point_ids"]
            world = np.asarray(jax.vmap(lambda T_, p: T_ @ p)(jaxlie.SE3(Twp.wxyz_xyz[ids]), jnp.asarray(pp, jnp.float32)))
        if part_masks is not None:
            metrics["part_label_accuracy"] = gt_part_accuracy(means, labels, world, ids)
        metrics["gt_chamfer_mm"] = _chamfer_mm(means, world)
    times["metrics_s"] = time.perf_counter() - t
    times["total_s"] = float(sum(times.values()))

    names = config.part_names or tuple(f"part{k}" for k in range(num_parts))
    if len(names) != num_parts:
        raise ValueError(f"part_names has {len(names)} names for {num_parts} parts")
    meta = FrozenDict(
        scale_m=radius_obj, arap_radius_m=arap_r, grouping=grouping, capture=str(Path(cap.root).resolve()),
        train_views=[int(i) for i in train], heldout_views=[int(i) for i in test],
        fit_config={k: v for k, v in vars(config.fit).items()}, field_config=dict(vars(config.field)),
        pca_dim=config.pca_dim, stage_times_s=times, metrics=metrics, versions={"jax": jax.__version__},
        grid_hw=[int(gh), int(gw)], feature_crop_size=config.feature_crop_size,
        support_plane=None if depths is None or masks is None else support_plane(
            intr, T[train], depths[train], masks[train], means.mean(0), 3.0 * float(np.max(np.linalg.norm(means - means.mean(0), axis=1)))),
    )  # fmt: skip
    model = ObjectModel(
        gaussians=g,
        decoder=decoder,
        pca=pca,
        part_centroids=jnp.asarray(cents, jnp.float32),
        arap_pairs=jnp.asarray(pairs, jnp.int32).reshape(-1, 2),
        feature_backend=feature_backend_record(extractor, images.shape[1:3]),
        part_names=tuple(names),
        meta=meta,
    )
    if rrd_path is not None:
        log_object_model(model, rrd_path)
    return model


def _render_depths(g, intr, T) -> np.ndarray:
    rcfg = size_render_config(g, intr, T[: min(len(T), 6)], 8)
    out = []
    for Tv in T:
        cam = Camera(intr, jaxlie.SE3.from_matrix(jnp.asarray(Tv, jnp.float32)))
        o = render(g, cam, rcfg)
        out.append(np.where(np.asarray(o.alpha) > 0.5, np.asarray(o.depth), 0.0))
    return np.stack(out)


def _chamfer_mm(a: np.ndarray, b: np.ndarray) -> float:
    from scipy.spatial import cKDTree

    da, _ = cKDTree(b).query(a)
    db, _ = cKDTree(a).query(b)
    return float(1000 * 0.5 * (np.median(da) + np.median(db)))


def _object_crops(g, intr, T, images, obj_mask, size: int, margin: float):
    """Square object crops of every view (`roi_box` of the projected Gaussian centres) resampled to
    `size`: (crops V×size×size×3, crop masks V×size×size, boxes)."""
    import cv2

    crops, cmasks, boxes = [], [], []
    for v in range(len(T)):
        uv, z = project_points(intr, jaxlie.SE3.from_matrix(jnp.asarray(T[v], jnp.float32)) @ g.means)
        box = roi_box(np.asarray(uv)[np.asarray(z) > 1e-3], intr.width, intr.height, margin)
        boxes.append(box)
        crops.append(crop(images[v], box, size))
        cmasks.append(crop(obj_mask[v].astype(np.float32), box, size, cv2.INTER_AREA) > 0.5)
    return np.stack(crops), np.stack(cmasks), boxes


def _heldout_metrics(g, decoder, intr, T, images, masks, targets, grid_valid, view_K=None) -> dict:
    """PSNR/SSIM (object on black where masks exist; all pixels and object pixels only) and
    decoded-feature cosine similarity on object grid cells of held-out views."""
    rcfg = size_render_config(g, intr, T, 8)
    ps, ps_obj, ss = [], [], []
    for v in range(len(T)):
        cam = Camera(intr, jaxlie.SE3.from_matrix(jnp.asarray(T[v], jnp.float32)))
        out = render(g, cam, rcfg, jnp.zeros(3))
        tgt = images[v].astype(np.float32) / 255.0
        if masks is not None:
            tgt = np.where(masks[v][..., None], tgt, 0.0)
        rgb = np.clip(np.asarray(out.rgb), 0, 1)
        ps.append(psnr(rgb, tgt))
        ss.append(float(ssim(jnp.asarray(rgb), jnp.asarray(tgt))))
        if masks is not None:
            m = masks[v]
            ps_obj.append(psnr(rgb[m], tgt[m]))
    dec, alpha = render_decoded(g, decoder, intr, T, targets.shape[1:3], view_K)
    a = dec[grid_valid]
    b = targets[grid_valid]
    cos = np.sum(a * b, -1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1) + 1e-12)
    out = {"heldout_psnr": float(np.mean(ps)), "heldout_ssim": float(np.mean(ss)),
           "heldout_feature_cosine": float(np.mean(cos)), "heldout_views": int(len(T))}  # fmt: skip
    if ps_obj:
        out["heldout_psnr_object_pixels"] = float(np.mean(ps_obj))
    return out


def log_object_model(model: ObjectModel, rrd_path: str | Path) -> Path:
    """Writes a rerun recording: Gaussian centres coloured by RGB, by PCA features (first three
    decoded components) and by part, plus part centroids."""
    import rerun as rr

    rrd_path = Path(rrd_path)
    rrd_path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream("rsrd_jax_build")
    g = model.gaussians
    pts = np.asarray(g.means)
    radii = np.exp(np.asarray(g.log_scales)).mean(1)
    rgb = (np.clip(np.asarray(g.colours), 0, 1) * 255).astype(np.uint8)
    dec = np.asarray(model.decoder(g.features))[:, :3]
    lo, hi = np.percentile(dec, 2, 0), np.percentile(dec, 98, 0)
    pca_rgb = (np.clip((dec - lo) / np.maximum(hi - lo, 1e-9), 0, 1) * 255).astype(np.uint8)
    palette = np.array([[230, 25, 75], [60, 180, 75], [0, 130, 200], [245, 130, 48], [145, 30, 180],
                        [70, 240, 240], [240, 50, 230], [210, 245, 60]], np.uint8)  # fmt: skip
    part_rgb = palette[np.asarray(g.part_ids) % len(palette)]
    rec.log("object/gaussians_rgb", rr.Points3D(pts, colors=rgb, radii=radii), static=True)
    rec.log("object/gaussians_features", rr.Points3D(pts, colors=pca_rgb, radii=radii), static=True)
    rec.log("object/gaussians_parts", rr.Points3D(pts, colors=part_rgb, radii=radii), static=True)
    rec.log("object/part_centroids", rr.Points3D(np.asarray(model.part_centroids), radii=0.003,
                                                 labels=list(model.part_names)), static=True)  # fmt: skip
    rec.save(str(rrd_path))
    return rrd_path
