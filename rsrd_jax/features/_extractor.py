"""The ``FeatureExtractor`` interface, image validation, and the embedded EfficientNet extractor."""

from __future__ import annotations

import abc
from pathlib import Path

import cv2
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._efficientnet import STAGE_CHANNELS, STAGE_ENDS, EfficientNetLite0, load_efficientnet_lite0

MIN_IMAGE_SIDE = 32
"""Smallest accepted image side in pixels (EfficientNet's coarsest stride)."""


class FeatureMap(eqx.Module):
    """Dense image features on a regular grid.

    Cell ``(i, j)`` covers input-image pixels ``[i·sy, (i+1)·sy) × [j·sx, (j+1)·sx)``, so its centre
    is at pixel coordinate ``((i + ½)·sy, (j + ½)·sx)`` (pixel centres at +0.5, as nerfstudio).
    A camera rendering this grid is the image camera with intrinsics divided by ``(sx, sy)``.
    """

    features: Float[Array, "*batch h w d"]
    """Feature vectors, one per grid cell."""
    stride: tuple[float, float] = eqx.field(static=True)
    """(sy, sx): input-image pixels per feature cell along rows and columns."""

    @property
    def dim(self) -> int:
        """Feature dimension D."""
        return int(self.features.shape[-1])


def as_float_images(images, name: str = "images") -> tuple[np.ndarray, tuple[int, ...]]:
    """Validates images on the host and returns them as float32 in [0, 1], flattened to 4-D.

    Args:
      images: ``*batch × H × W × 3`` uint8 (0–255) or float (0–1) array.
      name: how error messages name the argument.

    Returns:
      ``(N × H × W × 3 float32 array, batch shape)``.

    Raises:
      ValueError: wrong rank, channel count, dtype, too small, non-finite or out-of-range values.
    """
    arr = np.asarray(images)
    if arr.ndim < 3 or arr.shape[-1] != 3:
        raise ValueError(
            f"{name}: expected an H×W×3 RGB image or a *batch×H×W×3 stack, got shape {arr.shape}"
        )
    h, w = arr.shape[-3:-1]
    if min(h, w) < MIN_IMAGE_SIDE:
        raise ValueError(f"{name}: image is {h}×{w}; both sides must be ≥ {MIN_IMAGE_SIDE} px")
    if arr.dtype == np.uint8:
        out = arr.astype(np.float32) / 255.0
    elif np.issubdtype(arr.dtype, np.floating):
        out = arr.astype(np.float32)
        if out.size and not np.all(np.isfinite(out)):
            raise ValueError(f"{name}: contains non-finite values")
        if out.size and (out.min() < -1e-3 or out.max() > 1.0 + 1e-3):
            raise ValueError(
                f"{name}: float images must lie in [0, 1], got range "
                f"[{out.min():.3g}, {out.max():.3g}] (pass uint8 for 0–255 data)"
            )
        out = np.clip(out, 0.0, 1.0)
    else:
        raise ValueError(f"{name}: dtype {arr.dtype} unsupported; use uint8 or float in [0, 1]")
    batch = arr.shape[:-3]
    return out.reshape((-1, h, w, 3)), batch


class FeatureExtractor(eqx.Module):
    """Image → dense feature map. Subclasses: ``EfficientNetExtractor``, ``OnnxFeatureExtractor``.

    Calling an extractor is a host-side entry (it validates its input); the EfficientNet one
    jits its device work once per image size.
    """

    @abc.abstractmethod
    def __call__(self, images) -> FeatureMap:
        """Extracts features.

        Args:
          images: ``H×W×3`` or ``*batch×H×W×3``; uint8 (0–255) or float in [0, 1], RGB.

        Returns:
          A ``FeatureMap`` with features ``*batch × H' × W' × D`` and its stride.
        """

    @property
    @abc.abstractmethod
    def feature_dim(self) -> int:
        """Feature dimension D of the output."""

    @abc.abstractmethod
    def output_shape(self, height: int, width: int) -> tuple[int, int]:
        """Grid size (H', W') produced for an input image of ``height × width`` pixels."""


class EfficientNetConfig(eqx.Module):
    """Options of the embedded EfficientNet-Lite0 extractor."""

    strides: tuple[int, ...] = eqx.field(static=True, default=(8, 16))
    """Stage outputs to use, by image stride (2, 4, 8, 16, 32: 16/24/40/112/320 channels). The
    output grid is the finest one; coarser maps are bilinearly upsampled and concatenated.
    Default (8, 16), by measurement (``benchmarks/features.py``, nearest-neighbour matching
    after PCA-64 under random similarity warps of 192×256 natural images): 89 % of cells within
    8 px, vs 73 % for stride 8 alone, 58 % for 16, 17 % for 32; adding 32 gains nothing; (4, 8, 16)
    halves the median error (3.7 → 2.0 px) but has 4× the cells to render and fit."""
    input_scale: float = eqx.field(static=True, default=1.0)
    """Resize factor applied to the image before the network (2.0 halves the effective stride)."""
    size_multiple: int = eqx.field(static=True, default=32)
    """The network input (after ``input_scale``) is resized so both sides are multiples of this.
    With multiples of 32 every stride-2 layer sees an even size, as in ImageNet training (224).
    Measured (``benchmarks/features.py``, gradient centroids of central cells, 3 images): the
    stride-8 stage's effective receptive-field centres are offset from the ``FeatureMap`` cell
    centres by (−0.3, +1.8) px (y, x) at 128 px, (−2.5, −1.1) at 100 px (≡ 4 mod 8) and
    (−4.2, −2.6) at 97 px (odd), spread ±1.8 px. 1 disables the rounding."""
    normalize_levels: bool = eqx.field(static=True, default=True)
    """L2-normalise each stage's per-cell vector (after upsampling) before concatenation, so
    that stages of very different magnitude contribute equally (norm sqrt(len(strides)))."""
    mean: tuple[float, float, float] = eqx.field(static=True, default=(127 / 255,) * 3)
    """Per-channel mean subtracted from [0, 1] RGB (TF EfficientNet-Lite: 127/255)."""
    std: tuple[float, float, float] = eqx.field(static=True, default=(128 / 255,) * 3)
    """Per-channel divisor after the mean (TF EfficientNet-Lite: 128/255)."""
    weights_path: str | None = eqx.field(static=True, default=None)
    """Legacy torch ``.pth`` with lukemelas-named weights; None: the packaged ImageNet weights."""
    chunk_size: int = eqx.field(static=True, default=8)
    """Images per network pass (``lax.map`` over chunks): bounds memory for many scan views."""

    def __check_init__(self):
        if not self.strides or any(s not in STAGE_ENDS for s in self.strides):
            raise ValueError(
                f"EfficientNetConfig.strides={self.strides!r}: each must be one of "
                f"{sorted(STAGE_ENDS)}"
            )
        if len(set(self.strides)) != len(self.strides):
            raise ValueError(f"EfficientNetConfig.strides={self.strides!r} has duplicates")
        if self.size_multiple < 1:
            raise ValueError(f"EfficientNetConfig.size_multiple={self.size_multiple} must be ≥ 1")
        if self.chunk_size < 1:
            raise ValueError(f"EfficientNetConfig.chunk_size={self.chunk_size} must be ≥ 1")
        if not self.input_scale > 0:
            raise ValueError(f"EfficientNetConfig.input_scale={self.input_scale!r} must be > 0")
        if len(self.mean) != 3 or len(self.std) != 3 or min(self.std) <= 0:
            raise ValueError("EfficientNetConfig.mean/std must be 3 values, std > 0")


def _network_size(h: int, w: int, config: EfficientNetConfig) -> tuple[int, int]:
    """Network input size for an h×w image: scaled, then rounded to ``size_multiple``."""
    m = config.size_multiple
    return (
        max(m, int(np.floor(h * config.input_scale / m + 0.5)) * m),
        max(m, int(np.floor(w * config.input_scale / m + 0.5)) * m),
    )


def _ceil_div(a: int, b: int) -> int:
    return -(-a // b)


@eqx.filter_jit
@eqx.debug.assert_max_traces(max_traces=None)  # counts traces (tests: one per image size)
def _efficientnet_features(
    net: EfficientNetLite0, x: Float[Array, "n h w 3"], config: EfficientNetConfig
) -> Float[Array, "n h2 w2 d"]:
    n = x.shape[0]
    c = min(config.chunk_size, n)
    if n == c:
        return _features_chunk(net, x, config)
    # Pad to whole chunks and map over them sequentially; memory ∝ chunk size, not n.
    pad = (-n) % c
    xs = jnp.concatenate([x, jnp.zeros((pad,) + x.shape[1:], x.dtype)]) if pad else x
    xs = xs.reshape((-1, c) + x.shape[1:])
    out = jax.lax.map(lambda xc: _features_chunk(net, xc, config), xs)
    return out.reshape((-1,) + out.shape[2:])[:n]


def _features_chunk(
    net: EfficientNetLite0, x: Float[Array, "n h w 3"], config: EfficientNetConfig
) -> Float[Array, "n h2 w2 d"]:
    n, h, w, _ = x.shape
    sh, sw = _network_size(h, w, config)
    if (sh, sw) != (h, w):
        x = jax.image.resize(x, (n, sh, sw, 3), method="linear", antialias=True)
    x = (x - jnp.asarray(config.mean, x.dtype)) / jnp.asarray(config.std, x.dtype)
    maps = net.features(x, config.strides)
    fine = min(config.strides)
    gh, gw = _ceil_div(sh, fine), _ceil_div(sw, fine)
    out = []
    for m in maps:
        if m.shape[1:3] != (gh, gw):
            m = jax.image.resize(m, (n, gh, gw, m.shape[-1]), method="linear", antialias=False)
        if config.normalize_levels:  # after upsampling, so every cell is exactly unit per level
            m = m / (jnp.linalg.norm(m, axis=-1, keepdims=True) + 1e-6)
        out.append(m)
    return jnp.concatenate(out, axis=-1)


class EfficientNetExtractor(FeatureExtractor):
    """ImageNet EfficientNet-Lite0 (JAX) intermediate stages as dense features.

    Example:
      >>> ext = EfficientNetExtractor.pretrained()
      >>> fmap = ext(image_uint8)  # 192×256×3 → 24×32×152 (stride 8)
    """

    net: EfficientNetLite0
    """The network (batch norm folded)."""
    config: EfficientNetConfig = eqx.field(static=True)
    """Stage selection and input normalisation."""

    @classmethod
    def pretrained(cls, config: EfficientNetConfig | None = None) -> EfficientNetExtractor:
        """Loads the weights named by ``config.weights_path`` (default: the packaged ones)."""
        config = EfficientNetConfig() if config is None else config
        path = None if config.weights_path is None else Path(config.weights_path)
        return cls(net=load_efficientnet_lite0(path), config=config)

    @property
    def feature_dim(self) -> int:
        return sum(STAGE_CHANNELS[s] for s in self.config.strides)

    def output_shape(self, height: int, width: int) -> tuple[int, int]:
        sh, sw = _network_size(height, width, self.config)
        fine = min(self.config.strides)
        return _ceil_div(sh, fine), _ceil_div(sw, fine)

    def __call__(self, images) -> FeatureMap:
        """Extracts features.

        Args:
          images: ``H×W×3`` or ``*batch×H×W×3``; uint8 (0–255) or float in [0, 1], RGB.

        Returns:
          ``FeatureMap`` with features ``*batch × H' × W' × D``, H' = Hn / s_min where Hn is
          H·scale rounded to ``size_multiple``; D = sum of the chosen stages' channels; stride
          (H/H', W/W') in input pixels.
        """
        x, batch = as_float_images(images)
        h, w = x.shape[1:3]
        feats = _efficientnet_features(self.net, jnp.asarray(x), self.config)
        gh, gw = feats.shape[1:3]
        feats = feats.reshape(batch + feats.shape[1:])
        return FeatureMap(features=feats, stride=(h / gh, w / gw))

    def logits(self, images) -> Float[Array, "*batch 1000"]:
        """ImageNet logits (1000) of ``*batch × H × W × 3`` images at their own size (no resize)."""
        x, batch = as_float_images(images)
        return _efficientnet_logits(self.net, jnp.asarray(x), self.config).reshape(batch + (1000,))


@eqx.filter_jit
def _efficientnet_logits(
    net: EfficientNetLite0, x: Float[Array, "n h w 3"], config: EfficientNetConfig
) -> Float[Array, "n 1000"]:
    x = (x - jnp.asarray(config.mean, x.dtype)) / jnp.asarray(config.std, x.dtype)
    return net.logits(x)


def mask_to_grid(mask, grid_shape: tuple[int, int], min_fraction: float = 0.5) -> np.ndarray:
    """Downsamples a pixel mask to a feature grid by area coverage (host-side, numpy).

    Args:
      mask: ``*batch × H × W`` boolean (or 0/1) pixel mask.
      grid_shape: (H', W') of the feature grid (e.g. ``extractor.output_shape(H, W)``); cell
        (i, j) covers pixels ``[i·H/H', (i+1)·H/H') × [j·W/W', (j+1)·W/W')``, as ``FeatureMap``.
      min_fraction: a cell is True when at least this fraction of its area is masked.

    Returns:
      ``*batch × H' × W'`` boolean array.
    """
    m = np.asarray(mask)
    if m.ndim < 2:
        raise ValueError(f"mask: expected *batch×H×W, got shape {m.shape}")
    h, w = m.shape[-2:]
    gh, gw = grid_shape
    if not (1 <= gh <= h and 1 <= gw <= w):
        raise ValueError(f"grid_shape={grid_shape!r}: must be between 1×1 and the mask's {h}×{w}")
    flat = m.reshape((-1, h, w)).astype(np.float32)
    # INTER_AREA averages exactly over the (fractional) source area of each output cell.
    cover = np.stack([cv2.resize(f, (gw, gh), interpolation=cv2.INTER_AREA) for f in flat])
    return (cover >= min_fraction - 1e-6).reshape(m.shape[:-2] + (gh, gw))
