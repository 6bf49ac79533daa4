"""Contact sheets: a grid of labelled thumbnails in one PNG."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ..io import atomic_write_image


def contact_sheet(
    images: list[np.ndarray], labels: list[str] | None = None, columns: int = 6, thumb_width: int = 200
) -> np.ndarray:
    """Tiles RGB images (any sizes) into one H×W×3 uint8 sheet with a caption on each tile."""
    if not images:
        raise ValueError("contact_sheet needs at least one image")
    labels = labels or [""] * len(images)
    thumbs = []
    for img, text in zip(images, labels):
        img = np.asarray(img)
        if img.ndim == 2:
            img = np.repeat(img[..., None], 3, axis=2)
        h = int(round(img.shape[0] * thumb_width / img.shape[1]))
        t = cv2.resize(img, (thumb_width, h), interpolation=cv2.INTER_AREA)
        if text:
            cv2.putText(t, text, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 3, cv2.LINE_AA)
            cv2.putText(t, text, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1, cv2.LINE_AA)
        thumbs.append(t)
    th = max(t.shape[0] for t in thumbs)
    rows = []
    for r in range(0, len(thumbs), columns):
        row = [np.pad(t, ((0, th - t.shape[0]), (0, 0), (0, 0)), constant_values=255) for t in thumbs[r : r + columns]]
        row += [np.full((th, thumb_width, 3), 255, np.uint8)] * (columns - len(row))
        rows.append(np.concatenate(row, axis=1))
    return np.concatenate(rows, axis=0)


def save_contact_sheet(path: str | Path, images: list[np.ndarray], labels: list[str] | None = None, **kw) -> Path:
    """Writes `contact_sheet(images, labels)` to a PNG atomically."""
    return atomic_write_image(path, contact_sheet(images, labels, **kw))


def colorize_labels(labels: np.ndarray) -> np.ndarray:
    """H×W integer labels -> H×W×3 uint8 with a fixed palette (0 black)."""
    rng = np.random.default_rng(3)
    palette = rng.integers(40, 255, (256, 3)).astype(np.uint8)
    palette[0] = 0
    return palette[np.asarray(labels, np.int64) % 256]


def colorize_depth(depth: np.ndarray) -> np.ndarray:
    """H×W metric depth -> H×W×3 uint8 (turbo colormap, 0 = black)."""
    d = np.asarray(depth, np.float32)
    valid = d > 0
    if not valid.any():
        return np.zeros(d.shape + (3,), np.uint8)
    lo, hi = np.percentile(d[valid], [1, 99])
    n = np.clip((d - lo) / max(hi - lo, 1e-6), 0, 1)
    out = cv2.applyColorMap((n * 255).astype(np.uint8), cv2.COLORMAP_TURBO)[..., ::-1]
    out[~valid] = 0
    return out
