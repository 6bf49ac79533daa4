"""PartTrajectory artefact: `trajectory.npz` + `trajectory.json`.

Arrays (T frames, P parts, poses wxyz_xyz):
    T_obj_part        T×P×7  part poses in the object frame (part frame origin = rest centroid)
    T_cam_obj         T×7    object pose in the demo camera's OpenCV frame
    T_cam_world_part  T×P×7  takes a part's points in the scan's world frame (scan time) into the
                             camera frame: the evaluation interface
    residual          T×P    per-part feature residual after the per-frame solve
    visible           T×P    fraction of each part's rendered mass not occluded
    loss              T      per-frame total loss
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ._atomic import ArtefactError, atomic_write_json, atomic_write_npz, read_json, require

TRAJECTORY_FORMAT = "rsrd_jax.trajectory/1"
_ARRAYS = {"T_obj_part": 3, "T_cam_obj": 2, "T_cam_world_part": 3, "residual": 2, "visible": 2, "loss": 1}


@dataclasses.dataclass(frozen=True)
class PartTrajectory:
    """Tracked part motion of one demo video (numpy arrays; see the module docstring)."""

    T_obj_part: np.ndarray
    T_cam_obj: np.ndarray
    T_cam_world_part: np.ndarray
    residual: np.ndarray
    visible: np.ndarray
    loss: np.ndarray
    meta: dict

    @property
    def num_frames(self) -> int:
        return int(self.T_obj_part.shape[0])

    @property
    def num_parts(self) -> int:
        return int(self.T_obj_part.shape[1])


def save_trajectory(traj: PartTrajectory, out_dir: str | Path) -> Path:
    """Writes `trajectory.npz` and `trajectory.json` into `out_dir` (atomically, each)."""
    out = Path(out_dir)
    atomic_write_npz(out / "trajectory.npz", **{k: getattr(traj, k) for k in _ARRAYS})
    atomic_write_json(out / "trajectory.json", {"format": TRAJECTORY_FORMAT, **traj.meta})
    return out


def load_trajectory(path: str | Path) -> PartTrajectory:
    """Reads a PartTrajectory directory (or its `trajectory.npz`), validating shapes and values."""
    path = Path(path)
    d = path.parent if path.suffix == ".npz" else path
    npz = d / "trajectory.npz"
    if not npz.is_file():
        raise ArtefactError(f"trajectory not found: {npz}")
    meta = read_json(d / "trajectory.json", "trajectory.json")
    require(meta.get("format") == TRAJECTORY_FORMAT, d / "trajectory.json", "format", TRAJECTORY_FORMAT)
    with np.load(npz) as z:
        arrays = {}
        for k, nd in _ARRAYS.items():
            require(k in z.files, npz, k, "present")
            a = np.asarray(z[k], np.float64)
            require(a.ndim == nd, npz, k, f"{nd} dimensions")
            require(bool(np.all(np.isfinite(a))), npz, k, "finite values")
            arrays[k] = a
    T, P = arrays["T_obj_part"].shape[:2]
    for k in ("T_obj_part", "T_cam_world_part"):
        require(arrays[k].shape == (T, P, 7), npz, k, f"shape ({T}, {P}, 7)")
    require(arrays["T_cam_obj"].shape == (T, 7), npz, "T_cam_obj", f"shape ({T}, 7)")
    for k in ("residual", "visible"):
        require(arrays[k].shape == (T, P), npz, k, f"shape ({T}, {P})")
    meta.pop("format")
    return PartTrajectory(**arrays, meta=meta)
