"""Backend selection and its JSON form (stored in ``model.json`` so tracking rebuilds the same
extractor that the model's features were fitted to)."""

from __future__ import annotations

import dataclasses
from typing import Any

import equinox as eqx

from ._extractor import EfficientNetConfig, EfficientNetExtractor, FeatureExtractor
from ._onnx import OnnxConfig, OnnxFeatureExtractor

BACKENDS = ("efficientnet", "onnx")
"""Names of the feature backends."""

FEATURE_CONFIG_VERSION = 1
"""Version of ``FeatureConfig.to_dict``'s layout."""


class FeatureConfig(eqx.Module):
    """Which extractor produces the features and how many PCA dimensions are kept."""

    backend: str = eqx.field(static=True, default="efficientnet")
    """``"efficientnet"`` (embedded ImageNet EfficientNet-Lite0) or ``"onnx"`` (user ViT file)."""
    efficientnet: EfficientNetConfig = eqx.field(static=True, default=EfficientNetConfig())
    """Options of the EfficientNet backend."""
    onnx: OnnxConfig | None = eqx.field(static=True, default=None)
    """Options of the ONNX backend (required when ``backend == "onnx"``)."""
    pca_dim: int = eqx.field(static=True, default=64)
    """Dimension the features are reduced to by PCA over all scan views."""

    def __check_init__(self):
        if self.backend not in BACKENDS:
            raise ValueError(f"FeatureConfig.backend={self.backend!r}: expected one of {BACKENDS}")
        if self.backend == "onnx" and self.onnx is None:
            raise ValueError(
                "FeatureConfig.backend='onnx' needs FeatureConfig.onnx (the model path)"
            )
        if self.pca_dim < 1:
            raise ValueError(f"FeatureConfig.pca_dim={self.pca_dim} must be ≥ 1")

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable form (tuples become lists)."""
        return {
            "version": FEATURE_CONFIG_VERSION,
            "backend": self.backend,
            "pca_dim": self.pca_dim,
            "efficientnet": _fields(self.efficientnet),
            "onnx": None if self.onnx is None else _fields(self.onnx),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "feature config") -> FeatureConfig:
        """Inverse of ``to_dict``; errors name ``source`` and the bad field."""
        if not isinstance(d, dict):
            raise ValueError(f"{source}: expected a JSON object, got {type(d).__name__}")
        if d.get("version") != FEATURE_CONFIG_VERSION:
            raise ValueError(
                f"{source}: version {d.get('version')!r} unsupported "
                f"(expected {FEATURE_CONFIG_VERSION})"
            )
        try:
            eff = _build(EfficientNetConfig, d.get("efficientnet") or {}, f"{source}.efficientnet")
            onnx = (
                None if d.get("onnx") is None else _build(OnnxConfig, d["onnx"], f"{source}.onnx")
            )
            return cls(
                backend=d.get("backend", "efficientnet"),
                efficientnet=eff,
                onnx=onnx,
                pca_dim=int(d.get("pca_dim", 64)),
            )
        except (TypeError, ValueError) as e:
            raise ValueError(f"{source}: {e}") from e


def _fields(cfg: eqx.Module) -> dict[str, Any]:
    out = {}
    for f in dataclasses.fields(cfg):
        v = getattr(cfg, f.name)
        out[f.name] = list(v) if isinstance(v, tuple) else v
    return out


def _build(cls, d: dict[str, Any], source: str):
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(d) - names
    if unknown:
        raise ValueError(f"{source}: unknown fields {sorted(unknown)}")
    kwargs = {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}
    return cls(**kwargs)


def make_extractor(config: FeatureConfig) -> FeatureExtractor:
    """Builds the extractor named by ``config.backend`` (loads weights / the ONNX session)."""
    if config.backend == "efficientnet":
        return EfficientNetExtractor.pretrained(config.efficientnet)
    assert config.onnx is not None  # checked by FeatureConfig
    return OnnxFeatureExtractor(config.onnx)
