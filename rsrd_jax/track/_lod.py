"""Level of detail for tracking: merge a model's Gaussians per part on a voxel grid.

The tracker renders at its feature grid (a few millimetres per pixel), where a scan-resolution
model has tens of Gaussians per pixel; rendering cost grows with that count, not with the image
size. Merging the Gaussians of each voxel (per part, so no merged Gaussian straddles two parts)
into one moment-matched Gaussian keeps the rendered low-resolution image (colour, features,
coverage) while cutting the count several-fold.
"""

from __future__ import annotations

import numpy as np

from ..splat import Gaussians


def _quat_from_matrix(R: np.ndarray) -> np.ndarray:
    """N×3×3 rotation matrices -> N×4 wxyz (Shepperd's method, vectorised)."""
    m = R
    tr = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    cands = np.stack([tr, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], 1)
    k = np.argmax(cands, 1)
    q = np.zeros((len(R), 4))
    s = np.sqrt(np.maximum(1.0 + 2 * cands[np.arange(len(R)), k] - tr, 1e-12)) * 2  # 4·|q_k|
    i = k == 0
    q[i] = np.stack([0.25 * s[i], (m[i, 2, 1] - m[i, 1, 2]) / s[i], (m[i, 0, 2] - m[i, 2, 0]) / s[i], (m[i, 1, 0] - m[i, 0, 1]) / s[i]], 1)
    i = k == 1
    q[i] = np.stack([(m[i, 2, 1] - m[i, 1, 2]) / s[i], 0.25 * s[i], (m[i, 0, 1] + m[i, 1, 0]) / s[i], (m[i, 0, 2] + m[i, 2, 0]) / s[i]], 1)
    i = k == 2
    q[i] = np.stack([(m[i, 0, 2] - m[i, 2, 0]) / s[i], (m[i, 0, 1] + m[i, 1, 0]) / s[i], 0.25 * s[i], (m[i, 1, 2] + m[i, 2, 1]) / s[i]], 1)
    i = k == 3
    q[i] = np.stack([(m[i, 1, 0] - m[i, 0, 1]) / s[i], (m[i, 0, 2] + m[i, 2, 0]) / s[i], (m[i, 1, 2] + m[i, 2, 1]) / s[i], 0.25 * s[i]], 1)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def merge_gaussians(g: Gaussians, voxel_m: float) -> tuple[Gaussians, np.ndarray]:
    """Merges the Gaussians of each (part, voxel) cell into one.

    Weights are opacities. The merged mean is the weighted mean; the covariance is moment-matched
    (weighted mean of the covariances plus the spread of the means); colours and features are
    weighted means; the opacity is the largest in the cell (the members tile a surface rather
    than stack along the ray).

    Args:
        g: N Gaussians (object frame).
        voxel_m: voxel side, metres.

    Returns:
        (M merged Gaussians, N-vector mapping each input Gaussian to its merged index).
    """
    means = np.asarray(g.means, np.float64)
    n = len(means)
    pid = np.asarray(g.part_ids, np.int64)
    op = 1.0 / (1.0 + np.exp(-np.asarray(g.opacity_logits, np.float64)))
    cell = np.floor((means - means.min(0)) / voxel_m).astype(np.int64)
    key = np.concatenate([pid[:, None], cell], 1)
    _, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    m = int(inv.max()) + 1
    w = op + 1e-6
    W = np.bincount(inv, w, m)

    def wmean(x):
        x = x.reshape(n, -1)
        return np.stack([np.bincount(inv, w * x[:, j], m) for j in range(x.shape[1])], 1) / W[:, None]

    mu = wmean(means)
    q = np.asarray(g.unit_quats(), np.float64)
    s = np.exp(np.asarray(g.log_scales, np.float64))
    w_, x_, y_, z_ = q.T
    R = np.stack([
        np.stack([1 - 2 * (y_**2 + z_**2), 2 * (x_ * y_ - w_ * z_), 2 * (x_ * z_ + w_ * y_)], -1),
        np.stack([2 * (x_ * y_ + w_ * z_), 1 - 2 * (x_**2 + z_**2), 2 * (y_ * z_ - w_ * x_)], -1),
        np.stack([2 * (x_ * z_ - w_ * y_), 2 * (y_ * z_ + w_ * x_), 1 - 2 * (x_**2 + y_**2)], -1),
    ], 1)  # fmt: skip
    d = means - mu[inv]
    cov = np.einsum("nij,nj,nkj->nik", R, s**2, R) + d[:, :, None] * d[:, None, :]
    cov_m = wmean(cov).reshape(m, 3, 3)
    evals, evecs = np.linalg.eigh(cov_m)
    evecs[np.linalg.det(evecs) < 0, :, 0] *= -1  # proper rotations
    scales = np.sqrt(np.maximum(evals, 1e-10))
    op_m = np.zeros(m)
    np.maximum.at(op_m, inv, op)
    op_m = np.clip(op_m, 1e-4, 1 - 1e-4)
    part_m = np.zeros(m, np.int64)
    part_m[inv] = pid
    merged = Gaussians.create(
        mu,
        _quat_from_matrix(evecs),
        np.log(scales),
        np.log(op_m / (1 - op_m)),
        wmean(np.asarray(g.colours, np.float64)),
        wmean(np.asarray(g.features, np.float64)) if g.num_features else None,
        part_m,
    )
    return merged, inv
