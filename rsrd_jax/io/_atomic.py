"""Atomic writes: write to a temporary file in the same directory, then rename over the target.

A reader never sees a half-written artefact, and a crash mid-write leaves the old file intact.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path
from collections.abc import Callable
from typing import Any

import numpy as np


_UMASK = os.umask(0)
os.umask(_UMASK)


class ArtefactError(ValueError):
    """An artefact on disk is missing, malformed or inconsistent; the message names file and field."""


def _atomic(path: Path, write: Callable[[Path], None], suffix: str = "") -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=f".tmp{suffix}", dir=path.parent)
    os.close(fd)
    try:
        write(Path(tmp))
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600 files
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Writes `data` to `path` atomically."""
    return _atomic(Path(path), lambda p: p.write_bytes(data))


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Writes `text` (UTF-8) to `path` atomically."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | os.PathLike, obj: Any) -> Path:
    """Writes `obj` as indented JSON atomically."""
    return atomic_write_text(path, json.dumps(obj, indent=1, default=_json_default) + "\n")


def atomic_write_npz(path: str | os.PathLike, **arrays: np.ndarray) -> Path:
    """Writes a compressed `.npz` atomically."""

    def write(p: Path) -> None:
        with open(p, "wb") as f:
            np.savez_compressed(f, **{k: np.asarray(v) for k, v in arrays.items()})

    return _atomic(Path(path), write)


def atomic_write_image(path: str | os.PathLike, image: np.ndarray) -> Path:
    """Writes an image (PNG/JPG by suffix) atomically. RGB arrays are given RGB, not BGR."""
    import cv2

    path = Path(path)
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 3:
        img = img[..., ::-1]
    ok, buf = cv2.imencode(path.suffix or ".png", np.ascontiguousarray(img))
    if not ok:
        raise ArtefactError(f"{path}: could not encode image of shape {img.shape}, dtype {img.dtype}")
    return atomic_write_bytes(path, buf.tobytes())


def atomic_replace_dir(target: str | os.PathLike, fill: Callable[[Path], None]) -> Path:
    """Builds a directory with `fill(tmpdir)` next to `target`, then swaps it in.

    An existing `target` is replaced only once the new one is complete; `fill` raising leaves the
    old directory untouched.
    """
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent))
    try:
        fill(tmp)
        os.chmod(tmp, 0o777 & ~_UMASK)
        if target.exists():
            old = target.with_name(f".{target.name}.old")
            if old.exists():
                shutil.rmtree(old)
            os.replace(target, old)
            os.replace(tmp, target)
            shutil.rmtree(old)
        else:
            os.replace(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return target


def _json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    if hasattr(o, "__array__"):  # jax arrays (e.g. a config's weights)
        return np.asarray(o).tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def read_json(path: str | os.PathLike, what: str = "JSON file") -> dict:
    """Reads a JSON object, failing with a message naming the file."""
    path = Path(path)
    if not path.is_file():
        raise ArtefactError(f"{what} not found: {path}")
    try:
        obj = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise ArtefactError(f"{path}: not valid JSON ({e})") from e
    if not isinstance(obj, dict):
        raise ArtefactError(f"{path}: expected a JSON object at the top level")
    return obj


def require(cond: object, path: Any, field: str, expected: str) -> None:
    """Raises `ArtefactError` naming `path`, `field` and what was expected unless `cond`."""
    if not cond:
        raise ArtefactError(f"{path}: field {field!r}: expected {expected}")
