"""Tracking evaluation against ground truth: ADD per part and per object, in millimetres."""

from __future__ import annotations

import numpy as np

from ..geometry import se3_from_wxyz_xyz


def _apply(T7: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """T7 (…×7 wxyz_xyz) applied to N×3 points -> …×N×3."""
    M = np.asarray(se3_from_wxyz_xyz(np.asarray(T7, np.float32)).as_matrix(), np.float64)
    return np.einsum("...ij,nj->...ni", M[..., :3, :3], pts) + M[..., None, :3, 3]


def kabsch(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """4×4 rigid transform minimising Σ‖A·src − dst‖² (Kabsch/Umeyama without scale)."""
    cs, cd = src.mean(0), dst.mean(0)
    H = (src - cs).T @ (dst - cd)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    A = np.eye(4)
    A[:3, :3] = R
    A[:3, 3] = cd - R @ cs
    return A


def add_metrics(
    T_cam_world_part_pred: np.ndarray,
    T_cam_world_part_gt: np.ndarray,
    part_points: list[np.ndarray],
) -> dict:
    """Average Distance of model points (ADD), mm.

    Args:
        T_cam_world_part_pred, T_cam_world_part_gt: T×P×7; each maps part k's points given in the
            scan's world frame into the demo camera frame.
        part_points: per part, N_k×3 points in the scan's world frame (the model's Gaussian centres).

    Returns:
        `add_mm` (per part, camera frame: includes the monocular global registration error),
        `add_obj_mm` (per part, after one rigid alignment of the whole object fitted on frame 0 —
        the object-frame evaluation: part motion errors, not the absolute depth of the object),
        their means, and per-frame curves.
    """
    pred = [_apply(T_cam_world_part_pred[:, k], p) for k, p in enumerate(part_points)]
    gt = [_apply(T_cam_world_part_gt[:, k], p) for k, p in enumerate(part_points)]
    A = kabsch(np.concatenate([p[0] for p in pred]), np.concatenate([g[0] for g in gt]))
    add, add_obj, curve = [], [], []
    for p, g in zip(pred, gt):
        add.append(float(np.linalg.norm(p - g, axis=-1).mean() * 1e3))
        pa = p @ A[:3, :3].T + A[:3, 3]
        per_t = np.linalg.norm(pa - g, axis=-1).mean(-1) * 1e3
        add_obj.append(float(per_t.mean()))
        curve.append(per_t)
    return {
        "add_mm": add,
        "add_obj_mm": add_obj,
        "mean_add_mm": float(np.mean(add)),
        "mean_add_obj_mm": float(np.mean(add_obj)),
        "add_obj_curve_mm": np.stack(curve, 1).tolist(),
    }
