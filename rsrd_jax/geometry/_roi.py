"""Square regions of interest around an object's projection: the box rule, resampling an image
to a box, and the intrinsics of the resampled camera. Shared by feature extraction on scans,
tracking and registration so that all three see the object at the same scale."""

from __future__ import annotations

import cv2
import numpy as np

from ._camera import Intrinsics


def roi_box(uv: np.ndarray, width: int, height: int, margin: float, min_side: float = 32.0) -> tuple[float, float, float]:
    """Square crop (x0, y0, side) in pixels around projected points `uv` (N×2), grown by `margin`
    of the extent per side. The box may extend past the image (padding is masked out)."""
    uv = np.asarray(uv, np.float64)
    uv = uv[np.all(np.isfinite(uv), axis=1)]
    if len(uv) == 0:
        s = float(max(width, height))
        return (width - s) / 2, (height - s) / 2, s
    lo, hi = np.percentile(uv, 1, axis=0), np.percentile(uv, 99, axis=0)
    ext = hi - lo
    side = float(max(ext.max() * (1 + 2 * margin), min_side))
    side = min(side, 2.0 * max(width, height))
    c = (lo + hi) / 2
    return float(c[0] - side / 2), float(c[1] - side / 2), side


def full_frame_box(width: int, height: int) -> tuple[float, float, float]:
    """The square box covering the whole frame (letterboxed)."""
    s = float(max(width, height))
    return (width - s) / 2, (height - s) / 2, s


def crop(img: np.ndarray, box: tuple[float, float, float], size: int, interp: int = cv2.INTER_LINEAR) -> np.ndarray:
    """Resamples the square `box` (x0, y0, side; continuous pixel coords, centres at +0.5) of `img`
    to `size`×`size`; outside the image is 0."""
    x0, y0, s = box
    k = size / s
    M = np.array([[k, 0, (0.5 - x0) * k - 0.5], [0, k, (0.5 - y0) * k - 0.5]], np.float64)
    if interp == cv2.INTER_AREA:  # area downsampling: blur by the scale first, then linear
        sigma = max(0.0, 0.5 / k - 0.5)
        if sigma > 0.3:
            img = cv2.GaussianBlur(img, (0, 0), sigma)
        interp = cv2.INTER_LINEAR
    return cv2.warpAffine(img, M, (size, size), flags=interp, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def box_intrinsics(K: Intrinsics, box: tuple[float, float, float], size: int) -> Intrinsics:
    """Intrinsics of the `size`×`size` resampling of `box` from the camera `K`."""
    x0, y0, s = box
    k = size / s
    return Intrinsics(K.fx * k, K.fy * k, (K.cx - x0) * k, (K.cy - y0) * k, size, size)
