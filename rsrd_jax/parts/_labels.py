"""Part labels of Gaussians: multi-view mask voting with visibility, kNN cleanup, automatic
grouping without masks, and the part-level quantities (centroids, ARAP boundary pairs)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..geometry import Intrinsics


def vote_part_labels(
    means: np.ndarray,
    intrinsics: Intrinsics,
    T_cam_world: np.ndarray,
    part_masks: np.ndarray,
    depths: np.ndarray,
    num_parts: int,
    tolerance: float = 0.004,
) -> np.ndarray:
    """Per-Gaussian vote counts for each part from per-view label masks.

    A Gaussian votes in a view only if its centre projects inside the image at positive depth
    and in front: |z − depth(pixel)| ≤ `tolerance` (metres), `depth` being the scan's or the
    model's rendered z-depth (0 = unknown: no vote). It votes for the pixel's label k ≥ 1 (part
    k − 1); background pixels cast no vote.

    Args:
        means: N×3 world centres. T_cam_world: V×4×4. part_masks: V×H×W ints. depths: V×H×W metres.

    Returns:
        N×P vote counts.
    """
    n = len(means)
    H, W = part_masks.shape[1:]
    fx, fy, cx, cy = (float(x) for x in (intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy))
    votes = np.zeros((n, num_parts), np.int64)
    for v in range(len(part_masks)):
        pc = means @ T_cam_world[v, :3, :3].T + T_cam_world[v, :3, 3]
        z = pc[:, 2]
        zs = np.where(z > 1e-6, z, 1.0)
        u = np.floor(fx * pc[:, 0] / zs + cx).astype(np.int64)
        w = np.floor(fy * pc[:, 1] / zs + cy).astype(np.int64)
        ok = (z > 1e-6) & (u >= 0) & (u < W) & (w >= 0) & (w < H)
        ui, wi = np.clip(u, 0, W - 1), np.clip(w, 0, H - 1)
        d = depths[v][wi, ui]
        ok &= (d > 0) & (np.abs(z - d) <= tolerance)
        lab = part_masks[v][wi, ui].astype(np.int64)
        ok &= lab > 0
        np.add.at(votes, (np.nonzero(ok)[0], lab[ok] - 1), 1)
    return votes


def knn_cleanup(means: np.ndarray, labels: np.ndarray, known: np.ndarray, k: int = 10, rounds: int = 2) -> np.ndarray:
    """Fills unknown labels from the nearest known Gaussians, then smooths by kNN majority.

    Args:
        means: N×3. labels: N ints. known: N bool (labels with votes).
        k: neighbours; rounds: majority-vote passes (each Gaussian takes its k-neighbourhood's
            most common label, itself included).
    """
    labels = labels.copy()
    if not known.any():
        return np.zeros_like(labels)
    if (~known).any():
        _, j = cKDTree(means[known]).query(means[~known], k=1)
        labels[~known] = labels[known][j]
    k = min(k, len(means))
    _, nb = cKDTree(means).query(means, k=k)
    nb = np.asarray(nb).reshape(len(means), k)
    P = int(labels.max()) + 1
    for _ in range(rounds):
        counts = np.zeros((len(means), P), np.int64)
        for j in range(k):
            np.add.at(counts, (np.arange(len(means)), labels[nb[:, j]]), 1)
        labels = np.argmax(counts, axis=1)
    return labels


def auto_group(means: np.ndarray, features: np.ndarray, scale: float = 1.0, feature_weight: float = 1.0,
               max_points: int = 3000, seed: int = 0) -> np.ndarray:
    """Automatic part grouping without masks (GARField-like, one `scale` knob).

    Positions are divided by the object's RMS radius, features (decoded PCA vectors) by their RMS
    norm and multiplied by `feature_weight`; HDBSCAN runs on a random subset with
    `cluster_selection_epsilon = 0.25·scale` (larger scale → fewer, bigger groups) and
    `min_cluster_size` 3 % of the subset; noise and the rest go to the nearest clustered point.
    Labels are ordered by size, largest first.
    """
    from sklearn.cluster import HDBSCAN

    rng = np.random.default_rng(seed)
    c = means - means.mean(0)
    r = np.sqrt(np.mean(np.sum(c**2, 1))) + 1e-12
    f = features / (np.sqrt(np.mean(np.sum(features**2, 1))) + 1e-12)
    X = np.concatenate([c / r, feature_weight * f], 1)
    idx = rng.choice(len(X), min(len(X), max_points), replace=False)
    hd = HDBSCAN(min_cluster_size=max(5, int(0.03 * len(idx))), cluster_selection_epsilon=0.25 * scale,
                 allow_single_cluster=True, copy=True)  # fmt: skip
    lab = hd.fit_predict(X[idx])
    if (lab < 0).all():
        return np.zeros(len(means), np.int64)
    good = lab >= 0
    _, j = cKDTree(X[idx][good]).query(X, k=1)
    full = lab[good][j]
    uniq, counts = np.unique(full, return_counts=True)
    order = uniq[np.argsort(-counts, kind="stable")]
    remap = {int(o): i for i, o in enumerate(order)}
    return np.asarray([remap[int(x)] for x in full], np.int64)


def part_centroids(means: np.ndarray, labels: np.ndarray, num_parts: int) -> np.ndarray:
    """Mean centre of each part's Gaussians (P×3); raises if a part is empty."""
    out = np.zeros((num_parts, 3))
    for k in range(num_parts):
        sel = labels == k
        if not sel.any():
            raise ValueError(f"part {k} received no Gaussians")
        out[k] = means[sel].mean(0)
    return out


def arap_pairs(means: np.ndarray, labels: np.ndarray, radius: float, max_pairs: int = 50000, seed: int = 0) -> np.ndarray:
    """Cross-part Gaussian pairs (i < j) closer than `radius` metres (M×2, at most `max_pairs`)."""
    pairs = cKDTree(means).query_pairs(radius, output_type="ndarray")
    if len(pairs) == 0:
        return np.zeros((0, 2), np.int32)
    pairs = pairs[labels[pairs[:, 0]] != labels[pairs[:, 1]]]
    if len(pairs) > max_pairs:
        pairs = pairs[np.random.default_rng(seed).choice(len(pairs), max_pairs, replace=False)]
    pairs = np.sort(pairs, axis=1)
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))].astype(np.int32)


def gt_part_accuracy(means: np.ndarray, labels: np.ndarray, gt_points_world: np.ndarray, gt_ids: np.ndarray) -> float:
    """Fraction of Gaussians whose label equals the part of the nearest ground-truth surface point."""
    _, j = cKDTree(gt_points_world).query(means, k=1)
    return float(np.mean(labels == gt_ids[j]))
