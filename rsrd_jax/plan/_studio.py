"""Planning inputs from a studio object's ground truth (stand-in for a tracked PartTrajectory).

Frames. The object frame is the scan's world frame. Part k's planning frame is its rest-centroid
frame: object axes, origin at the centroid c_k of its rest surface points. With
``T_world_part_rest`` (scan ground truth, scan world), the demo's ``T_world_part(t)`` (demo world)
and ``T_demo_scan`` (scan world -> demo world), a point x at rest in the scan world moves to
``T_demo_scan⁻¹ · T_world_part(t) · T_world_part_rest⁻¹ · x`` (in scan-world coordinates), so

    T_obj_part_k(t) = T_demo_scan⁻¹ · T_world_part_k(t) · T_world_part_rest_k⁻¹ · Tr(c_k).
"""

from __future__ import annotations

import json
from pathlib import Path

import equinox as eqx
import numpy as np


def _mat(x: np.ndarray) -> np.ndarray:
    """wxyz_xyz (..., 7) -> (..., 4, 4) (numpy, float64)."""
    x = np.asarray(x, np.float64)
    w, qx, qy, qz = (x[..., i] for i in range(4))
    n = np.sqrt(w * w + qx * qx + qy * qy + qz * qz)
    w, qx, qy, qz = w / n, qx / n, qy / n, qz / n
    R = np.stack([
        1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - w * qz), 2 * (qx * qz + w * qy),
        2 * (qx * qy + w * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - w * qx),
        2 * (qx * qz - w * qy), 2 * (qy * qz + w * qx), 1 - 2 * (qx * qx + qy * qy),
    ], -1).reshape(*x.shape[:-1], 3, 3)  # fmt: skip
    T = np.zeros((*x.shape[:-1], 4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = x[..., 4:]
    T[..., 3, 3] = 1
    return T


def _vec(T: np.ndarray) -> np.ndarray:
    """(..., 4, 4) -> wxyz_xyz (..., 7) (numpy)."""
    import jax.numpy as jnp
    import jaxlie

    R = jaxlie.SO3.from_matrix(jnp.asarray(T[..., :3, :3], jnp.float32))
    return np.concatenate([np.asarray(R.wxyz, np.float64), T[..., :3, 3]], -1)


class StudioPlanInputs(eqx.Module):
    """Planning inputs derived from studio ground truth (numpy)."""

    part_points: list
    """P arrays (n_k, 3): surface points in each part's rest-centroid frame (m)."""
    part_centroids: np.ndarray
    """(P, 3) rest centroids in the object (scan world) frame."""
    T_obj_part: np.ndarray
    """(T, P, 7) part poses in the object frame per demo frame (rest-centroid part frames)."""
    T_robot_obj: np.ndarray
    """(7,) object (scan world) pose in the robot base frame, from robot_view/gt.json."""
    hands: np.ndarray | None
    """(T, H, 2, 3) fingertip keypoints in the object frame (contact order), or None."""
    T_demo_scan: np.ndarray
    """(7,) scan world -> demo world."""
    free_parts: tuple[int, ...] | None = eqx.field(static=True, default=None)
    """Parts no joint holds (every part of a separable object, ``object.json``), or None: the
    planner's ``free_parts``."""


def read_robot_object_pose(path: str | Path) -> np.ndarray:
    """``T_robot_world`` (7,) from a studio ``robot_view/gt.json`` (or its directory)."""
    p = Path(path)
    if p.is_dir():
        p = p / "robot_view" / "gt.json" if (p / "robot_view").is_dir() else p / "gt.json"
    with open(p) as f:
        meta = json.load(f)
    if "T_robot_world" not in meta:
        raise ValueError(f"{p}: field T_robot_world missing")
    v = np.asarray(meta["T_robot_world"], float)
    if v.shape != (7,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{p}: T_robot_world must be 7 finite numbers, got {v}")
    return v


def studio_plan_inputs(studio_dir: str | Path, points_per_part: int | None = 2000, seed: int = 0) -> StudioPlanInputs:
    """Reads a studio object's scan/demo/robot-view ground truth as planning inputs.

    Args:
        studio_dir: output of ``rsrd_jax.studio.make_object`` (needs object.json, scan, demo, robot_view).
        points_per_part: subsample each part's surface points to at most this many (None: all).
        seed: subsampling seed.
    """
    from ..io import ArtefactError

    d = Path(studio_dir)
    need = (d / "scan" / "gt" / "scan_gt.npz", d / "demo" / "gt" / "part_poses.npz", d / "robot_view" / "gt.json",
            d / "object.json")
    missing = [str(p) for p in need if not p.is_file()]
    if missing:
        raise ArtefactError(f"{d}: not a complete studio object directory (object.json, scan, demo and robot_view "
                            f"ground truth); "
                            f"missing {', '.join(missing)} (make it with `rsrd-jax studio make NAME --out DIR`)")  # fmt: skip
    with np.load(d / "scan" / "gt" / "scan_gt.npz") as z:
        T_wr = _mat(z["T_world_part"])  # (P, 4, 4) rest, scan world
        pts, ids = np.asarray(z["part_points"], float), np.asarray(z["part_point_ids"])
    with np.load(d / "demo" / "gt" / "part_poses.npz") as z:
        T_wd = _mat(z["T_world_part"])  # (T, P, 4, 4) demo world
        T_ds = _mat(z["T_demo_scan"])
    P = T_wr.shape[0]
    rng = np.random.default_rng(seed)
    cents, local = [], []
    for k in range(P):
        pk = pts[ids == k]
        xw = pk @ T_wr[k, :3, :3].T + T_wr[k, :3, 3]
        c = xw.mean(0)
        cents.append(c)
        if points_per_part is not None and len(xw) > points_per_part:
            xw = xw[rng.choice(len(xw), points_per_part, replace=False)]
        local.append(xw - c)
    cents = np.stack(cents)
    Tc = np.tile(np.eye(4), (P, 1, 1))
    Tc[:, :3, 3] = cents
    T_op = np.linalg.inv(T_ds)[None, None] @ T_wd @ np.linalg.inv(T_wr)[None] @ Tc[None]
    hands = None
    hk = d / "demo" / "gt" / "hand_keypoints.npz"
    if hk.is_file():
        with np.load(hk) as z:
            kw = np.asarray(z["keypoints_world"], float)
        Ti = np.linalg.inv(T_ds)
        hands = kw @ Ti[:3, :3].T + Ti[:3, 3]
    from ..pipeline import studio_separable  # the one reader of the flag (tracking takes it too)

    free = tuple(range(P)) if studio_separable(d) else None
    return StudioPlanInputs(
        part_points=local, part_centroids=cents, T_obj_part=_vec(T_op),
        T_robot_obj=read_robot_object_pose(d / "robot_view" / "gt.json"), hands=hands, T_demo_scan=_vec(T_ds),
        free_parts=free,
    )
