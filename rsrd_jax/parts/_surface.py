"""Part surfaces as the scan saw them: the planner's collision and grasp geometry.

A Gaussian splat's centres are a poor surface: most lie inside the object, but a tail of them
lies outside it (on the studio led_light's robot-trial build the 95th percentile of the stand's
centres is 2.2 mm outside its true surface, low-opacity floaters up to 7.8 mm), and that tail
fattens a part exactly where a gripper's pads must pass (a 3 mm clearance). A scan with depth
maps (Polycam, Record3D, the studio) says where the surface is and where there is free space:
:func:`scan_surface_points` back-projects each view's depth inside each part's mask and keeps
the Gaussian centres that no view sees free space at (they fill what no view saw: undersides,
gaps between parts).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from jaxtyping import Float, Int

from ..io import ArtefactError, read_capture


def scan_surface_points(
    capture_dir: str | Path,
    means: Float[np.ndarray, "n 3"],
    part_ids: Int[np.ndarray, " n"],
    num_parts: int,
    views: Sequence[int] | None = None,
    carve_tolerance: float = 0.0015,
    voxel: float = 0.001,
    label_distance: float = 0.003,
) -> list[Float[np.ndarray, "_m 3"]]:
    """Each part's surface points (the scan's world frame, metres) from the scan's depth maps.

    Every view's depth is back-projected inside the part's mask: the capture's part masks
    (label k + 1 for part k), or without them the object pixels (every pixel of a scan without
    object masks) labelled by the nearest Gaussian centre within `label_distance` and dropped
    farther from every centre (the table, the background). The part's Gaussian centres are
    added where no view sees past them: a centre nearer to a view's camera than the depth that
    view measured at its pixel, by more than `carve_tolerance`, lies in free space and is
    dropped; the rest fill what no view saw (centres on a slanted face or at a silhouette are
    carved too, but the depth covers them).
    Each part's points are thinned to one per `voxel`-sized cell (their mean).

    Args:
        capture_dir: the scan (nerfstudio `transforms.json` with `depth_file_path` per frame).
        means: (N, 3) Gaussian centres (world frame); part_ids: (N,) their parts in [0, num_parts).
        views: the views to use (default: all).
        carve_tolerance: free-space margin (m): the depth maps' quantisation (1 mm) and the
            centres' fit error must not carve the surface itself.
        voxel: thinning cell (m); 0 keeps every point.
        label_distance: without part masks, the largest distance (m) from a depth point to the
            Gaussian centre whose part it takes.

    Returns:
        `num_parts` arrays (n_k × 3).

    Raises:
        ArtefactError: the capture has no depth maps, or a part would get no points.
    """
    cap = read_capture(capture_dir)
    if not cap.has_depth:
        raise ArtefactError(f"{cap.root / 'transforms.json'}: scan surface points need a depth_file_path on every frame")
    means = np.asarray(means, np.float64)
    part_ids = np.asarray(part_ids)
    if means.ndim != 2 or means.shape[1] != 3 or part_ids.shape != (len(means),):
        raise ValueError(f"means must be (N, 3) and part_ids (N,), got {means.shape} and {part_ids.shape}")
    views = range(len(cap)) if views is None else [int(v) for v in views]
    K = cap.intrinsics
    fx, fy, cx, cy = (float(x) for x in (K.fx, K.fy, K.cx, K.cy))
    T = cap.T_cam_world()
    keep = np.ones(len(means), bool)
    found: list[list[np.ndarray]] = [[] for _ in range(num_parts)]
    unlabelled: list[np.ndarray] = []
    for v in views:
        z = cap.depth(v)
        H, W = z.shape
        # free-space carving of the centres by this view
        pc = means @ T[v][:3, :3].T + T[v][:3, 3]
        front = pc[:, 2] > 1e-6
        u = np.full(len(means), -1)
        w = np.full(len(means), -1)
        u[front] = np.floor(pc[front, 0] / pc[front, 2] * fx + cx).astype(int)
        w[front] = np.floor(pc[front, 1] / pc[front, 2] * fy + cy).astype(int)
        inside = front & (u >= 0) & (u < W) & (w >= 0) & (w < H)
        z_seen = np.zeros(len(means))
        z_seen[inside] = z[w[inside], u[inside]]
        keep &= ~(inside & (z_seen > 0) & (pc[:, 2] < z_seen - carve_tolerance))
        # this view's surface points
        if cap.has_part_masks:
            labels = cap.part_mask(v).astype(int) - 1
        else:
            mask = cap.valid_mask(v) if cap.frames[v].mask_path is not None else np.ones((H, W), bool)
            labels = np.where(mask, num_parts, -1)  # object pixels, labelled below
        ok = (z > 0) & (labels >= 0)
        vv, uu = np.nonzero(ok)
        d = z[vv, uu]
        p_cam = np.stack([(uu + 0.5 - cx) / fx * d, (vv + 0.5 - cy) / fy * d, d], -1)
        Twc = np.linalg.inv(T[v])
        p = p_cam @ Twc[:3, :3].T + Twc[:3, 3]
        lab = labels[vv, uu]
        for k in range(num_parts):
            found[k].append(p[lab == k])
        unlabelled.append(p[lab == num_parts])
    if not cap.has_part_masks:
        from scipy.spatial import cKDTree

        rest = np.concatenate(unlabelled)
        if len(rest):
            dist, i = cKDTree(means).query(rest)
            near = dist <= label_distance
            for k in range(num_parts):
                found[k].append(rest[near & (part_ids[i] == k)])
    out = []
    for k in range(num_parts):
        pts = np.concatenate(found[k] + [means[keep & (part_ids == k)]])
        if not len(pts):
            raise ArtefactError(f"{cap.root}: part {k} has neither depth pixels nor Gaussian centres")
        out.append(_thin(pts, voxel))
    return out


def model_scan_surface(model, capture_dir: str | Path) -> list[Float[np.ndarray, "_m 3"]]:
    """`scan_surface_points` of an `ObjectModel` built from `capture_dir`: its Gaussian centres
    and parts, the views it was trained on (`meta["train_views"]`)."""
    return scan_surface_points(capture_dir, np.asarray(model.gaussians.means), np.asarray(model.gaussians.part_ids),
                               model.num_parts, views=model.meta.get("train_views"))  # fmt: skip


def _thin(points: np.ndarray, voxel: float) -> np.ndarray:
    """One point per occupied `voxel` cell: the mean of the cell's points."""
    if voxel <= 0:
        return points
    cells = np.floor(points / voxel).astype(np.int64)
    _, inv, counts = np.unique(cells, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    sums = np.zeros((len(counts), 3))
    np.add.at(sums, inv, points)
    return sums / counts[:, None]
