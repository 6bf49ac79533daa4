"""Scan captures in nerfstudio's `transforms.json` convention.

Layout (all paths relative to the capture directory):
    transforms.json   fl_x, fl_y, cx, cy, w, h, [camera_model], frames[]:
                      file_path, transform_matrix (camera-to-world, OpenGL axes, metres),
                      [depth_file_path] (16-bit PNG, millimetres, 0 = no depth),
                      [mask_path] (8-bit PNG, nerfstudio meaning: 0 = pixel to ignore),
                      [part_mask_path] (8-bit label PNG: 0 = background, k = part k)
    gt/               studio ground truth (optional)

Real phone scans (Polycam, Record3D exports) load directly. Cameras are converted to OpenCV axes
here, once.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ..geometry import Intrinsics, T_cam_world_to_opengl_c2w, opengl_c2w_to_T_cam_world
from ._atomic import ArtefactError, atomic_write_json, read_json, require
from ._images import read_depth_png, read_image_rgb, read_label_png

_DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")


@dataclasses.dataclass(frozen=True)
class CaptureFrame:
    """One scan view: files (absolute paths) and `T_cam_world` (4×4, OpenCV axes)."""

    image_path: Path
    T_cam_world: np.ndarray
    depth_path: Path | None = None
    mask_path: Path | None = None
    part_mask_path: Path | None = None


@dataclasses.dataclass(frozen=True)
class Capture:
    """A multi-view scan: shared intrinsics and per-view poses and files."""

    root: Path
    intrinsics: Intrinsics
    frames: tuple[CaptureFrame, ...]

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def has_depth(self) -> bool:
        return all(f.depth_path is not None for f in self.frames)

    @property
    def has_part_masks(self) -> bool:
        return all(f.part_mask_path is not None for f in self.frames)

    def T_cam_world(self) -> np.ndarray:
        """All views' world-to-camera transforms, V×4×4 (OpenCV axes)."""
        return np.stack([f.T_cam_world for f in self.frames])

    def image(self, i: int | np.integer) -> np.ndarray:
        """View i's RGB image, H×W×3 uint8."""
        return self._checked(read_image_rgb(self.frames[i].image_path), self.frames[i].image_path)

    def depth(self, i: int | np.integer) -> np.ndarray:
        """View i's metric z-depth, H×W float32 metres (0 where unknown)."""
        p = self.frames[i].depth_path
        if p is None:
            raise ArtefactError(f"{self.root / 'transforms.json'}: frame {i} has no depth_file_path")
        return self._checked(read_depth_png(p), p)

    def valid_mask(self, i: int | np.integer) -> np.ndarray:
        """View i's pixels to use (nerfstudio mask: nonzero = use), H×W bool; all True if none."""
        p = self.frames[i].mask_path
        if p is None:
            return np.ones((self.intrinsics.height, self.intrinsics.width), bool)
        return self._checked(read_label_png(p), p) > 0

    def part_mask(self, i: int | np.integer) -> np.ndarray:
        """View i's part labels, H×W uint8 (0 background, k = part k)."""
        p = self.frames[i].part_mask_path
        if p is None:
            raise ArtefactError(f"{self.root / 'transforms.json'}: frame {i} has no part_mask_path")
        return self._checked(read_label_png(p), p)

    def _checked(self, arr: np.ndarray, path: Path) -> np.ndarray:
        h, w = self.intrinsics.height, self.intrinsics.width
        if arr.shape[:2] != (h, w):
            raise ArtefactError(
                f"{path}: image is {arr.shape[1]}×{arr.shape[0]} but transforms.json says w={w}, h={h}"
            )
        return arr


def read_capture(root: str | Path) -> Capture:
    """Reads and validates a capture directory (or a path to its `transforms.json`).

    Every referenced file must exist; poses must be finite rigid transforms; intrinsics positive;
    lens distortion must be zero (undistort first). Raises `ArtefactError` naming file and field.
    """
    root = Path(root)
    path = root if root.name == "transforms.json" else root / "transforms.json"
    root = path.parent
    meta = read_json(path, "capture transforms.json")
    for k in ("fl_x", "fl_y", "w", "h"):
        require(k in meta and _is_number(meta[k]), path, k, "a number")
    cx = meta.get("cx", meta["w"] / 2.0)
    cy = meta.get("cy", meta["h"] / 2.0)
    for k in _DISTORTION_KEYS:
        require(abs(float(meta.get(k, 0.0))) < 1e-12, path, k, "0 (undistorted images)")
    try:
        intrinsics = Intrinsics.create(meta["fl_x"], meta["fl_y"], cx, cy, int(meta["w"]), int(meta["h"]))
    except ValueError as e:
        raise ArtefactError(f"{path}: {e}") from e
    frames_meta = meta.get("frames")
    require(isinstance(frames_meta, list) and len(frames_meta) > 0, path, "frames", "a non-empty list")
    frames = []
    for i, fm in enumerate(frames_meta):
        where = f"frames[{i}]"
        for k in ("fl_x", "fl_y", "cx", "cy", "w", "h"):
            if k in fm and abs(float(fm[k]) - float({"cx": cx, "cy": cy}.get(k, meta.get(k, 0)))) > 1e-6:
                raise ArtefactError(f"{path}: {where}.{k}: per-frame intrinsics differ from the shared ones")
        require("file_path" in fm, path, f"{where}.file_path", "an image path")
        c2w = np.asarray(fm.get("transform_matrix", []), dtype=np.float64)
        require(c2w.shape in ((4, 4), (3, 4)), path, f"{where}.transform_matrix", "a 4×4 matrix")
        require(bool(np.all(np.isfinite(c2w))), path, f"{where}.transform_matrix", "finite values")
        R = c2w[:3, :3]
        require(
            bool(np.allclose(R @ R.T, np.eye(3), atol=1e-3)) and np.linalg.det(R) > 0,
            path, f"{where}.transform_matrix", "a rigid transform (orthonormal rotation)",
        )  # fmt: skip
        files = {}
        for key in ("file_path", "depth_file_path", "mask_path", "part_mask_path"):
            if fm.get(key) is None:
                files[key] = None
                continue
            f = root / fm[key]
            if not f.is_file():
                raise ArtefactError(f"{path}: {where}.{key}: file not found: {f}")
            files[key] = f
        T = np.asarray(opengl_c2w_to_T_cam_world(c2w).as_matrix(), np.float64)
        frames.append(
            CaptureFrame(files["file_path"], T, files["depth_file_path"], files["mask_path"], files["part_mask_path"])
        )
    return Capture(root, intrinsics, tuple(frames))


def write_transforms(
    root: str | Path,
    intrinsics: Intrinsics,
    T_cam_world: np.ndarray,
    files: list[dict[str, str]],
    extra: dict | None = None,
) -> Path:
    """Writes `transforms.json` for views whose files already exist under `root`.

    Args:
        T_cam_world: V×4×4 world-to-camera transforms (OpenCV axes); stored as OpenGL c2w.
        files: per view, relative paths keyed by `file_path`, `depth_file_path`, `mask_path`,
            `part_mask_path` (missing keys are omitted).
        extra: more top-level fields (e.g. studio metadata).
    """
    import jaxlie

    frames = []
    for T, f in zip(np.asarray(T_cam_world), files, strict=True):
        c2w = T_cam_world_to_opengl_c2w(jaxlie.SE3.from_matrix(T))
        frames.append({**f, "transform_matrix": np.round(c2w, 9).tolist()})
    meta = {**intrinsics.to_dict(), "camera_model": "OPENCV", **(extra or {}), "frames": frames}
    return atomic_write_json(Path(root) / "transforms.json", meta)


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and bool(np.isfinite(v))
