"""User-supplied ViT (DINOv2 and the like) ONNX feature extractor, run on the host (onnxruntime)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ._extractor import FeatureExtractor, FeatureMap, as_float_images


class OnnxConfig(eqx.Module):
    """Options of the ONNX ViT extractor (all static)."""

    path: str = eqx.field(static=True)
    """The ``.onnx`` file. Its first input is an N×3×H×W float image batch."""
    patch_size: int = eqx.field(static=True, default=14)
    """ViT patch size in pixels (DINOv2: 14)."""
    input_size: tuple[int, int] | None = eqx.field(static=True, default=None)
    """(H, W) the image is resized to, multiples of ``patch_size``; None: the model's fixed input
    size if it has one, else the image size rounded to the nearest multiple of ``patch_size``."""
    mean: tuple[float, float, float] = eqx.field(static=True, default=(0.485, 0.456, 0.406))
    """Per-channel mean subtracted from [0, 1] RGB (DINOv2: ImageNet mean)."""
    std: tuple[float, float, float] = eqx.field(static=True, default=(0.229, 0.224, 0.225))
    """Per-channel divisor after the mean (DINOv2: ImageNet std)."""
    num_prefix_tokens: int | None = eqx.field(static=True, default=None)
    """Tokens before the patch tokens in an N×T×D output, dropped (CLS = 1; DINOv2 with
    registers = 5); None: inferred as T − h·w. Ignored for models that output an N×D×h×w grid."""
    output_name: str | None = eqx.field(static=True, default=None)
    """Which model output holds the tokens; None: the first output."""

    def __check_init__(self):
        if self.patch_size < 1:
            raise ValueError(f"OnnxConfig.patch_size={self.patch_size} must be ≥ 1")
        if self.input_size is not None and (
            len(self.input_size) != 2
            or any(s < self.patch_size or s % self.patch_size for s in self.input_size)
        ):
            raise ValueError(
                f"OnnxConfig.input_size={self.input_size!r} must be two positive multiples of "
                f"patch_size={self.patch_size}"
            )
        if self.num_prefix_tokens is not None and self.num_prefix_tokens < 0:
            raise ValueError(f"OnnxConfig.num_prefix_tokens={self.num_prefix_tokens} must be ≥ 0")
        if len(self.mean) != 3 or len(self.std) != 3 or min(self.std) <= 0:
            raise ValueError("OnnxConfig.mean/std must be 3 values, std > 0")


class OnnxFeatureExtractor(FeatureExtractor):
    """Patch-token features of a user-supplied ViT ONNX model (e.g. DINOv2 ViT-S/14).

    Runs on the host with onnxruntime (CPU); not jittable. Images are resized to the model's
    input size, normalised, run one batch at a time (one image at a time when the model's batch
    dimension is fixed to 1), and the patch tokens are reshaped to the ``h × w`` patch grid.
    """

    config: OnnxConfig = eqx.field(static=True)
    """Model file, patch size, input size, normalisation and prefix tokens."""
    session: object = eqx.field(static=True)
    """The onnxruntime ``InferenceSession``."""
    feature_dim_: int = eqx.field(static=True)
    """Token dimension D, read from the model's output shape on the first run (-1 if unknown)."""

    def __init__(self, config: OnnxConfig):
        import onnxruntime as ort

        path = Path(config.path)
        if not path.is_file():
            raise FileNotFoundError(f"ONNX feature model not found: {path}")
        try:
            opts = ort.SessionOptions()
            opts.log_severity_level = 3
            session = ort.InferenceSession(
                str(path), sess_options=opts, providers=["CPUExecutionProvider"]
            )
        except Exception as e:  # noqa: BLE001 - onnxruntime raises several private types
            raise ValueError(f"{path}: onnxruntime cannot load this model: {e}") from e
        inputs = session.get_inputs()
        if len(inputs) != 1 or len(inputs[0].shape) != 4:
            raise ValueError(
                f"{path}: expected one N×3×H×W image input, got "
                f"{[(i.name, i.shape) for i in inputs]}"
            )
        fixed = tuple(inputs[0].shape[2:])
        if all(isinstance(d, int) and d > 0 for d in fixed):
            if config.input_size is not None and tuple(config.input_size) != fixed:
                raise ValueError(
                    f"{path}: the model's input is fixed to {fixed[0]}×{fixed[1]} but "
                    f"OnnxConfig.input_size={config.input_size!r}"
                )
            if any(d % config.patch_size for d in fixed):
                raise ValueError(
                    f"{path}: fixed input {fixed[0]}×{fixed[1]} is not a multiple of "
                    f"OnnxConfig.patch_size={config.patch_size}"
                )
            config = dataclasses.replace(config, input_size=fixed)
        names = [o.name for o in session.get_outputs()]
        if config.output_name is not None and config.output_name not in names:
            raise ValueError(
                f"{path}: OnnxConfig.output_name={config.output_name!r} not among outputs {names}"
            )
        out = session.get_outputs()[names.index(config.output_name or names[0])]
        dim = -1
        if len(out.shape) == 3 and isinstance(out.shape[2], int):
            dim = out.shape[2]
        elif len(out.shape) == 4 and isinstance(out.shape[1], int):
            dim = out.shape[1]
        self.config = config
        self.session = session
        self.feature_dim_ = dim

    @property
    def feature_dim(self) -> int:
        return self.feature_dim_

    def _model_input_size(self, height: int, width: int) -> tuple[int, int]:
        if self.config.input_size is not None:
            return self.config.input_size
        p = self.config.patch_size
        return max(p, round(height / p) * p), max(p, round(width / p) * p)

    def output_shape(self, height: int, width: int) -> tuple[int, int]:
        h, w = self._model_input_size(height, width)
        return h // self.config.patch_size, w // self.config.patch_size

    def __call__(self, images) -> FeatureMap:
        """Extracts patch features.

        Args:
          images: ``H×W×3`` or ``*batch×H×W×3``; uint8 (0–255) or float in [0, 1], RGB.

        Returns:
          ``FeatureMap`` with features ``*batch × h × w × D`` (h = H_in / patch) and stride
          (H/h, W/w) in original-image pixels.
        """
        x, batch = as_float_images(images)
        n, h, w, _ = x.shape
        ih, iw = self._model_input_size(h, w)
        if (ih, iw) != (h, w):
            shrink = ih < h and iw < w
            interp = cv2.INTER_AREA if shrink else cv2.INTER_LINEAR
            x = np.stack([cv2.resize(im, (iw, ih), interpolation=interp) for im in x])
        mean = np.asarray(self.config.mean, np.float32)
        std = np.asarray(self.config.std, np.float32)
        nchw = np.ascontiguousarray(((x - mean) / std).transpose(0, 3, 1, 2), dtype=np.float32)

        inp = self.session.get_inputs()[0]
        out_name = self.config.output_name or self.session.get_outputs()[0].name
        chunk = 1 if inp.shape[0] == 1 else n
        outs = []
        for i in range(0, n, chunk):
            try:
                (o,) = self.session.run([out_name], {inp.name: nchw[i : i + chunk]})
            except Exception as e:  # noqa: BLE001
                raise ValueError(
                    f"{self.config.path}: running the model on a {ih}×{iw} input failed "
                    f"(check OnnxConfig.input_size / patch_size): {e}"
                ) from e
            outs.append(np.asarray(o, np.float32))
        tokens = np.concatenate(outs, axis=0)
        gh, gw = ih // self.config.patch_size, iw // self.config.patch_size
        grid = self._to_grid(tokens, n, gh, gw)
        feats = jnp.asarray(grid.reshape(batch + grid.shape[1:]))
        return FeatureMap(features=feats, stride=(h / gh, w / gw))

    def _to_grid(self, tokens: np.ndarray, n: int, gh: int, gw: int) -> np.ndarray:
        if tokens.ndim == 4:  # already N × D × h × w
            if tokens.shape[0] != n or tokens.shape[2:] != (gh, gw):
                raise ValueError(
                    f"{self.config.path}: output grid {tokens.shape} does not match "
                    f"{n}×D×{gh}×{gw} (check OnnxConfig.patch_size={self.config.patch_size})"
                )
            return tokens.transpose(0, 2, 3, 1)
        if tokens.ndim != 3 or tokens.shape[0] != n:
            raise ValueError(
                f"{self.config.path}: expected N×T×D tokens or an N×D×h×w grid, got {tokens.shape}"
            )
        k = self.config.num_prefix_tokens
        if k is None:
            k = tokens.shape[1] - gh * gw
            if k < 0:
                raise ValueError(
                    f"{self.config.path}: {tokens.shape[1]} tokens are fewer than the {gh}×{gw} "
                    f"patch grid (check OnnxConfig.patch_size={self.config.patch_size})"
                )
        elif tokens.shape[1] - k != gh * gw:
            raise ValueError(
                f"{self.config.path}: {tokens.shape[1]} tokens minus num_prefix_tokens={k} is "
                f"{tokens.shape[1] - k}, but a {gh}×{gw} patch grid (patch_size="
                f"{self.config.patch_size}) needs {gh * gw}"
            )
        return tokens[:, k:].reshape(n, gh, gw, tokens.shape[2])
