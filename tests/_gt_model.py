"""A tracking test model built from a studio object's ground-truth geometry (no 3DGS fit).

Gaussians sit on the studio's true part surfaces with colours averaged from the scan views that
see them (depth-tested); the feature field (per-Gaussian features + decoder) is fitted to the scan
views' PCA features with the project's `fit_feature_field`. This isolates tracking from 3DGS
fitting in tests.
"""

from __future__ import annotations

import types

import cv2
import equinox as eqx
import jax.numpy as jnp
import jaxlie
import numpy as np
from scipy.spatial import cKDTree

from rsrd_jax.features import EfficientNetConfig, EfficientNetExtractor, fit_pca, mask_to_grid
from rsrd_jax.geometry import box_intrinsics, crop, roi_box
from rsrd_jax.io import read_capture
from rsrd_jax.parts import FieldConfig, fit_feature_field
from rsrd_jax.splat import Gaussians


def gt_object_model(studio_dir, pca_dim: int = 32, per_part: int = 1200, extractor=None, seed: int = 0, field_iters: int = 400,
                    crop_size: int | None = 96):  # fmt: skip
    """`crop_size`: features come from square object crops of this size (the build's default
    rule, `BuildConfig.feature_crop_size`); None: whole views."""
    cap = read_capture(studio_dir / "scan")
    with np.load(studio_dir / "scan/gt/scan_gt.npz") as z:
        T_wp = np.asarray(jaxlie.SE3(jnp.asarray(z["T_world_part"], jnp.float32)).as_matrix(), np.float64)
        pts, ids = z["part_points"], z["part_point_ids"]
    rng = np.random.default_rng(seed)
    means, pid = [], []
    for k in range(len(T_wp)):
        pk = pts[ids == k]
        pk = pk[rng.choice(len(pk), min(per_part, len(pk)), replace=False)]
        means.append(pk @ T_wp[k, :3, :3].T + T_wp[k, :3, 3])
        pid.append(np.full(len(pk), k))
    means, pid = np.concatenate(means), np.concatenate(pid)
    extractor = extractor or EfficientNetExtractor.pretrained(EfficientNetConfig())
    images = np.stack([cap.image(i) for i in range(len(cap))])
    masks = np.stack([cap.part_mask(i) > 0 for i in range(len(cap))])
    K = np.asarray(cap.intrinsics.K())
    Tcw = cap.T_cam_world()
    if crop_size:
        boxes = []
        for T in Tcw:
            pc = means @ T[:3, :3].T + T[:3, 3]
            boxes.append(roi_box((pc @ K.T)[:, :2] / pc[:, 2:3], cap.intrinsics.width, cap.intrinsics.height, 0.25))
        feat_images = np.stack([crop(im, b, crop_size) for im, b in zip(images, boxes)])
        feat_masks = np.stack([crop(m.astype(np.float32), b, crop_size, cv2.INTER_AREA) > 0.5 for m, b in zip(masks, boxes)])
    else:
        boxes = [(0.0, 0.0, None)] * len(Tcw)
        feat_images, feat_masks = images, masks
    fmaps = extractor(feat_images)
    F = np.asarray(fmaps.features)  # V×h×w×C
    V, h, w, C = F.shape
    cell = mask_to_grid(feat_masks, (h, w))
    view_K = [box_intrinsics(cap.intrinsics, b, h) for b in boxes] if crop_size else None
    pca = fit_pca(F[cell].reshape(-1, C), pca_dim)
    P = np.asarray(pca.project(jnp.asarray(F)))
    acc = np.zeros((len(means), pca_dim))
    col = np.zeros((len(means), 3))
    cnt = np.zeros(len(means))
    for i in range(V):
        T = cap.frames[i].T_cam_world
        pc = means @ T[:3, :3].T + T[:3, 3]
        u = K[0, 0] * pc[:, 0] / pc[:, 2] + K[0, 2]
        v = K[1, 1] * pc[:, 1] / pc[:, 2] + K[1, 2]
        ok = (pc[:, 2] > 0) & (u >= 0) & (u < cap.intrinsics.width) & (v >= 0) & (v < cap.intrinsics.height)
        d = cap.depth(i)
        ui, vi = np.clip(u.astype(int), 0, d.shape[1] - 1), np.clip(v.astype(int), 0, d.shape[0] - 1)
        ok &= np.abs(d[vi, ui] - pc[:, 2]) < 0.004
        if crop_size:  # grid cell of the crop box
            x0, y0, side = boxes[i]
            gi = np.clip(((v - y0) * h / side).astype(int), 0, h - 1)
            gj = np.clip(((u - x0) * w / side).astype(int), 0, w - 1)
        else:
            gi = np.clip((v * h / d.shape[0]).astype(int), 0, h - 1)
            gj = np.clip((u * w / d.shape[1]).astype(int), 0, w - 1)
        acc[ok] += P[i, gi[ok], gj[ok]]
        col[ok] += images[i, vi[ok], ui[ok]] / 255.0
        cnt[ok] += 1
    seen = cnt > 0
    acc[seen] /= cnt[seen, None]
    col[seen] /= cnt[seen, None]
    acc[~seen] = acc[seen].mean(0)
    col[~seen] = col[seen].mean(0)
    n = len(means)
    g = Gaussians.create(
        means, np.tile([1.0, 0, 0, 0], (n, 1)), np.full((n, 3), np.log(0.0025)), np.full(n, 3.0), col, acc, pid
    )
    if field_iters:
        g, decoder, _ = fit_feature_field(
            g, P, cell, cap.intrinsics, Tcw, FieldConfig(iterations=field_iters, feature_dim=16), view_intrinsics=view_K
        )
    else:
        decoder = eqx.nn.Identity()
    tree = cKDTree(means)
    pairs = np.array(sorted(tree.query_pairs(0.004)), np.int64).reshape(-1, 2)
    pairs = pairs[pid[pairs[:, 0]] != pid[pairs[:, 1]]]
    centroids = np.stack([means[pid == k].mean(0) for k in range(len(T_wp))])
    return types.SimpleNamespace(
        gaussians=g,
        decoder=decoder,
        pca=pca,
        part_centroids=jnp.asarray(centroids, jnp.float32),
        arap_pairs=jnp.asarray(pairs, jnp.int32),
        feature_backend={"name": "efficientnet"},
        part_names=tuple(f"part{k}" for k in range(len(T_wp))),
        meta={},
        num_parts=len(T_wp),
    ), extractor
