"""Images, depth PNGs, label masks and videos, with validation."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ._atomic import ArtefactError, _atomic, atomic_write_image

DEPTH_PNG_SCALE = 1000.0
"""16-bit depth PNGs store millimetres (Polycam's convention); 0 means no depth."""


def _imread(path: Path, flags: int) -> np.ndarray:
    import cv2

    path = Path(path)
    if not path.is_file():
        raise ArtefactError(f"image not found: {path}")
    img = cv2.imread(str(path), flags)
    if img is None:
        raise ArtefactError(f"{path}: not a readable image")
    return img


def read_image_rgb(path: str | Path) -> np.ndarray:
    """An RGB image as H×W×3 uint8 (alpha dropped, grey expanded)."""
    import cv2

    img = _imread(Path(path), cv2.IMREAD_COLOR)
    return np.ascontiguousarray(img[..., ::-1])


def read_label_png(path: str | Path) -> np.ndarray:
    """An 8-bit single-channel label/mask PNG as H×W uint8."""
    import cv2

    img = _imread(Path(path), cv2.IMREAD_UNCHANGED)
    if img.ndim != 2 or img.dtype != np.uint8:
        raise ArtefactError(f"{path}: expected an 8-bit single-channel PNG, got {img.dtype} {img.shape}")
    return img


def read_depth_png(path: str | Path) -> np.ndarray:
    """A 16-bit millimetre depth PNG as H×W float32 metres (0 = no depth)."""
    import cv2

    img = _imread(Path(path), cv2.IMREAD_UNCHANGED)
    if img.ndim != 2 or img.dtype != np.uint16:
        raise ArtefactError(f"{path}: expected a 16-bit single-channel depth PNG, got {img.dtype} {img.shape}")
    return img.astype(np.float32) / DEPTH_PNG_SCALE


def write_depth_png(path: str | Path, depth_m: np.ndarray) -> Path:
    """Writes metric depth (metres; ≤ 0 or non-finite = none) as a 16-bit millimetre PNG."""
    d = np.asarray(depth_m, np.float64)
    d = np.where(np.isfinite(d) & (d > 0), d, 0.0)
    mm = np.clip(np.round(d * DEPTH_PNG_SCALE), 0, 65535).astype(np.uint16)
    return atomic_write_image(path, mm)


def write_label_png(path: str | Path, labels: np.ndarray) -> Path:
    """Writes an H×W uint8 label/mask PNG."""
    labels = np.asarray(labels)
    if labels.ndim != 2 or labels.dtype != np.uint8:
        raise ValueError(f"labels must be H×W uint8, got {labels.dtype} {labels.shape}")
    return atomic_write_image(path, labels)


def write_video(path: str | Path, frames: np.ndarray, fps: float = 30.0) -> Path:
    """Writes T×H×W×3 uint8 RGB frames as an mp4 (mp4v codec), atomically."""
    import cv2

    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8 or len(frames) == 0:
        raise ValueError(f"frames must be a non-empty T×H×W×3 uint8 array, got {frames.dtype} {frames.shape}")
    h, w = frames.shape[1:3]

    def write(p: Path) -> None:
        writer = cv2.VideoWriter(str(p), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (w, h))
        if not writer.isOpened():
            raise ArtefactError(f"{path}: OpenCV cannot open an mp4 writer")
        try:
            for f in frames:
                writer.write(np.ascontiguousarray(f[..., ::-1]))
        finally:
            writer.release()

    return _atomic(Path(path), write, suffix=Path(path).suffix)


def read_video(path: str | Path, max_frames: int | None = None) -> tuple[np.ndarray, float]:
    """Reads a video OpenCV can decode into T×H×W×3 uint8 RGB frames, and its fps.

    Raises `ArtefactError` for a missing, unreadable or empty video.
    """
    import cv2

    path = Path(path)
    if not path.is_file():
        raise ArtefactError(f"video not found: {path}")
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise ArtefactError(f"{path}: OpenCV cannot open this video (corrupt or unsupported codec)")
    fps = float(cap.get(cv2.CAP_PROP_FPS)) or 30.0
    frames = []
    try:
        while max_frames is None or len(frames) < max_frames:
            ok, f = cap.read()
            if not ok:
                break
            frames.append(f[..., ::-1])
    finally:
        cap.release()
    if not frames:
        raise ArtefactError(f"{path}: the video has no decodable frames (corrupt or empty)")
    return np.ascontiguousarray(np.stack(frames)), fps
