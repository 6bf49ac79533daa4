"""Demo videos: any video OpenCV reads plus `camera.json` (`fl_x, fl_y, cx, cy, w, h`).

Studio demos add `gt/`: `part_poses.npz` (T_obj_part, T_world_part: T×P×7 wxyz_xyz;
T_cam_world_part: T×P×7), `depth/NNNNN.png` (16-bit mm), `hand_mask/NNNNN.png`,
`hand_keypoints.npz` (T×H×2×3 world points, T×H×2×2 pixels, visibility T×H×2).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ..geometry import Intrinsics
from ._atomic import ArtefactError, atomic_write_json, read_json, require
from ._images import read_video


@dataclasses.dataclass(frozen=True)
class Demo:
    """A decoded demo: frames T×H×W×3 uint8, fps, intrinsics, and where its files are."""

    video_path: Path
    frames: np.ndarray
    fps: float
    intrinsics: Intrinsics

    @property
    def num_frames(self) -> int:
        return int(self.frames.shape[0])

    @property
    def gt_dir(self) -> Path:
        return self.video_path.parent / "gt"


def write_camera_json(path: str | Path, intrinsics: Intrinsics, extra: dict | None = None) -> Path:
    """Writes a demo's `camera.json`."""
    return atomic_write_json(path, {**intrinsics.to_dict(), **(extra or {})})


def read_camera_json(path: str | Path) -> Intrinsics:
    """Reads and validates a `camera.json` into intrinsics."""
    path = Path(path)
    meta = read_json(path, "camera.json")
    for k in ("fl_x", "fl_y", "w", "h"):
        require(k in meta and isinstance(meta[k], (int, float)), path, k, "a number")
    try:
        return Intrinsics.create(
            meta["fl_x"], meta["fl_y"], meta.get("cx", meta["w"] / 2), meta.get("cy", meta["h"] / 2),
            int(meta["w"]), int(meta["h"]),
        )  # fmt: skip
    except ValueError as e:
        raise ArtefactError(f"{path}: {e}") from e


def read_demo(video: str | Path, camera_json: str | Path | None = None, max_frames: int | None = None) -> Demo:
    """Reads a demo video and its camera (default: `camera.json` next to the video).

    Raises `ArtefactError` if the video is unreadable, the camera file is missing, or the video's
    frame size differs from the camera's `w`×`h`.
    """
    video = Path(video)
    if video.is_dir():
        candidates = sorted(video.glob("*.mp4"))
        if len(candidates) != 1:
            raise ArtefactError(f"{video}: expected exactly one .mp4 in the demo directory, found {len(candidates)}")
        video = candidates[0]
    camera_json = Path(camera_json) if camera_json is not None else video.parent / "camera.json"
    intrinsics = read_camera_json(camera_json)
    frames, fps = read_video(video, max_frames)
    h, w = frames.shape[1:3]
    if (w, h) != (intrinsics.width, intrinsics.height):
        raise ArtefactError(
            f"{camera_json}: camera is {intrinsics.width}×{intrinsics.height} but {video} has "
            f"{w}×{h} frames"
        )
    return Demo(video, frames, fps, intrinsics)


def read_demo_gt(demo_dir: str | Path) -> dict[str, np.ndarray]:
    """Loads a studio demo's ground-truth arrays (`gt/part_poses.npz` + `gt/hand_keypoints.npz`)."""
    gt = Path(demo_dir) / "gt"
    out: dict[str, np.ndarray] = {}
    for name in ("part_poses.npz", "hand_keypoints.npz"):
        p = gt / name
        if not p.is_file():
            raise ArtefactError(f"studio ground truth not found: {p}")
        with np.load(p) as z:
            out.update({k: z[k] for k in z.files})
    T = out["T_obj_part"].shape[0]
    for k in ("T_obj_part", "T_world_part", "T_cam_world_part"):
        require(out[k].ndim == 3 and out[k].shape[0] == T and out[k].shape[2] == 7, gt / "part_poses.npz", k, "T×P×7")
    return out
