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
               max_points: int = 3000, max_parts: int = 8, knn: int = 20, seed: int = 0) -> np.ndarray:
    """Automatic part grouping without masks: spectral clustering of the Gaussians' kNN graph.

    Parts of an articulated object meet at narrow or creased junctions (a leg's root, a lid's
    seam), which a normalised cut of the surface's neighbour graph finds; edges are weighted by
    decoded-feature similarity, exp(−feature_weight·‖f_i − f_j‖² / median), so an appearance
    boundary also weakens them. The number of parts k is chosen by the eigengap of the normalised
    Laplacian: the gaps λ_k / λ_{k−1} (k = 2…max_parts) are compared with a threshold
    1 + (largest gap − 1) / `scale`, and the smallest k that reaches it wins: scale 1 takes the
    largest gap; larger scales accept weaker gaps earlier (fewer, bigger parts), smaller ones only
    the largest (scale < 1 behaves as 1). One part when no gap exceeds 1.5. Runs on a random
    subset of `max_points`; the rest take their nearest subset point's label. Labels are ordered by
    size, largest first.

    Measured on studio builds (48 views): red_box → 2 parts, frog → 6 (see issue 4's note).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components, laplacian
    from scipy.sparse.linalg import eigsh
    from sklearn.cluster import KMeans

    rng = np.random.default_rng(seed)
    n = len(means)
    idx = rng.choice(n, min(n, max_points), replace=False)
    x = np.asarray(means, np.float64)[idx]
    f = np.asarray(features, np.float64)[idx]
    m = len(x)
    if m < 3 * max_parts:
        return np.zeros(n, np.int64)
    kk = min(knn, m - 1)
    _, nb = cKDTree(x).query(x, k=kk + 1)
    rows = np.repeat(np.arange(m), kk)
    cols = nb[:, 1:].reshape(-1)
    df = np.sum((f[rows] - f[cols]) ** 2, axis=1)
    w = np.exp(-feature_weight * df / max(float(np.median(df)), 1e-12))
    A = coo_matrix((w, (rows, cols)), shape=(m, m)).tocsr()
    A = 0.5 * (A + A.T)
    _, comp = connected_components(A, directed=False)
    size = np.bincount(comp)
    keep = size[comp] >= max(3, 0.01 * m)  # separate pieces stay (each is a zero eigenvalue), specks go
    if not keep.all():  # specks take their nearest kept point's label below
        x, A = x[keep], A[keep][:, keep]
        m = len(x)
    L = laplacian(A, normed=True)
    nev = min(max_parts + 1, m - 1)
    vals, vecs = eigsh(L, k=nev, sigma=-1e-3, which="LM")
    order = np.argsort(vals)
    vals, vecs = np.maximum(vals[order], 0.0), vecs[:, order]
    gaps = vals[2:] / np.maximum(vals[1:-1], 1e-12)  # gaps[j] = λ_{j+2} / λ_{j+1}: k = j + 2 parts
    if len(gaps) == 0 or gaps.max() < 1.5:
        return np.zeros(n, np.int64)
    thr = 1.0 + (gaps.max() - 1.0) / max(scale, 1.0)
    k = int(np.nonzero(gaps >= thr - 1e-12)[0][0]) + 2
    U = vecs[:, :k]
    U = U / np.maximum(np.linalg.norm(U, axis=1, keepdims=True), 1e-12)
    lab = KMeans(k, n_init=10, random_state=seed).fit_predict(U)
    _, j = cKDTree(x).query(np.asarray(means, np.float64), k=1)
    full = lab[j]
    uniq, counts = np.unique(full, return_counts=True)
    remap = np.zeros(int(uniq.max()) + 1, np.int64)
    remap[uniq[np.argsort(-counts, kind="stable")]] = np.arange(len(uniq))
    return remap[full]


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
