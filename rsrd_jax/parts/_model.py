"""The ObjectModel (Gaussians + feature decoder + PCA + parts), its feature decoder, and its files."""

from __future__ import annotations

import json
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ..features import PCA, EfficientNetConfig, EfficientNetExtractor, FeatureExtractor, OnnxConfig, OnnxFeatureExtractor
from ..io import ArtefactError, atomic_write_bytes, atomic_write_json, read_json
from ..splat import Gaussians
from ..splat._project import quat_to_rotmat

MODEL_FORMAT = "rsrd_jax.object_model/1"
"""`format` field of `model.json`; bumped on incompatible changes."""


class FrozenDict(dict):
    """A plain dict that is hashable (by its JSON text), so it can be a static Module field."""

    def __hash__(self):  # type: ignore[override]
        return hash(json.dumps(self, sort_keys=True, default=str))


class FeatureDecoder(eqx.Module):
    """Bias-free ReLU MLP applied per pixel (DiG): F → width → … → D, `len(weights)` layers."""

    weights: tuple[Array, ...]
    """Layer matrices (in × out), applied as x @ W with ReLU between layers (not after the last)."""

    @staticmethod
    def create(in_dim: int, out_dim: int, width: int = 64, layers: int = 4, key: jax.Array | None = None) -> FeatureDecoder:
        """He-uniform initialised decoder with `layers` linear layers of hidden width `width`."""
        if layers < 1:
            raise ValueError(f"FeatureDecoder needs ≥ 1 layer, got {layers}")
        key = jax.random.key(0) if key is None else key
        dims = [in_dim] + [width] * (layers - 1) + [out_dim]
        ws = []
        for a, b in zip(dims[:-1], dims[1:]):
            key, sub = jax.random.split(key)
            lim = float(np.sqrt(6.0 / a))
            ws.append(jax.random.uniform(sub, (a, b), jnp.float32, -lim, lim))
        return FeatureDecoder(tuple(ws))

    @property
    def in_dim(self) -> int:
        return int(self.weights[0].shape[0])

    @property
    def out_dim(self) -> int:
        return int(self.weights[-1].shape[1])

    def __call__(self, f: Float[Array, "... fin"]) -> Float[Array, "... fout"]:
        """Decodes feature vectors (e.g. a rendered feature map divided by alpha) into PCA space."""
        x = f
        for w in self.weights[:-1]:
            x = jax.nn.relu(x @ w)
        return x @ self.weights[-1]


def decode_rendered(decoder: FeatureDecoder, features: Float[Array, "*b f"], alpha: Float[Array, "*b"]) -> Float[Array, "*b d"]:
    """What the model's feature field predicts for a render: decoder(features / max(alpha, 1e-6))."""
    return decoder(features / jnp.maximum(alpha, 1e-6)[..., None])


class ObjectModel(eqx.Module):
    """A part-segmented Gaussian-splat model of one object with a feature field.

    Frames: the object frame is the scan capture's world frame (metres). Part k's Gaussians have
    `gaussians.part_ids == k`; with mask labels, part k is mask label k + 1.
    """

    gaussians: Gaussians
    """N Gaussians (object frame, metres); `features` are the learnt F-dim field vectors."""
    decoder: FeatureDecoder
    """Per-pixel MLP F → D (PCA space). Apply to rendered features divided by alpha
    (`decode_rendered`)."""
    pca: PCA
    """PCA of the extractor's features over the scan views (D components)."""
    part_centroids: Float[Array, "p 3"]
    """Rest centroid (mean Gaussian centre) of each part, object frame, metres."""
    arap_pairs: Int[Array, "m 2"]
    """Gaussian index pairs (i < j) in different parts within `meta['arap_radius_m']`."""
    feature_backend: dict = eqx.field(static=True)
    """How to rebuild the extractor (`make_extractor`): name, config, stride, input scale."""
    part_names: tuple[str, ...] = eqx.field(static=True)
    """One name per part."""
    meta: dict = eqx.field(static=True)
    """Scale, build config, metrics, versions (JSON-serialisable)."""

    @property
    def num_parts(self) -> int:
        return int(self.part_centroids.shape[0])

    def part_points(self, k: int) -> np.ndarray:
        """Centres (object frame, metres) of part k's Gaussians, n_k × 3 numpy."""
        if not 0 <= k < self.num_parts:
            raise IndexError(f"part {k} out of range (model has {self.num_parts} parts)")
        ids = np.asarray(self.gaussians.part_ids)
        return np.asarray(self.gaussians.means)[ids == k]

    def part_extent_points(self, k: int, sigmas: float = 1.0, cap_percentile: float = 90.0) -> np.ndarray:
        """Part k's Gaussian centres and, for each Gaussian, the 6 points ± `sigmas` standard
        deviations along its principal axes (object frame, metres; 7·n_k × 3). Each axis's scale is
        capped at the `cap_percentile`-th percentile of the part's scales (a few large Gaussians do
        not inflate the part).

        Why: a part thinner than about two scan pixels gets its Gaussians' centres on its
        mid-surface, its thickness only in their scales (the studio sunglasses' 4 mm arms: centres
        within ±1 mm, 0.8 mm standard deviation across the arm at 160×120), so a mesh of the
        centres is a sheet that no antipodal grasp fits."""
        if not 0 <= k < self.num_parts:
            raise IndexError(f"part {k} out of range (model has {self.num_parts} parts)")
        ids = np.asarray(self.gaussians.part_ids) == k
        mu = np.asarray(self.gaussians.means, np.float64)[ids]
        s = np.exp(np.asarray(self.gaussians.log_scales, np.float64)[ids])
        s = np.minimum(s, np.percentile(s, cap_percentile)) * sigmas
        q = np.asarray(self.gaussians.quats, np.float64)[ids]
        R = np.asarray(quat_to_rotmat(jnp.asarray(q / np.linalg.norm(q, axis=1, keepdims=True))), np.float64)
        axes = np.transpose(R, (0, 2, 1)) * s[:, :, None]  # (n, 3 axes, 3): column i of R scaled
        return np.concatenate([mu, (mu[:, None] + axes).reshape(-1, 3), (mu[:, None] - axes).reshape(-1, 3)])


def feature_backend_record(extractor: FeatureExtractor, image_hw: tuple[int, int]) -> dict:
    """The `feature_backend` record of an extractor (used by `make_extractor`)."""
    h, w = image_hw
    gh, gw = extractor.output_shape(h, w)
    if isinstance(extractor, EfficientNetExtractor):
        c = extractor.config
        cfg = {"strides": list(c.strides), "input_scale": c.input_scale, "normalize_levels": c.normalize_levels,
               "mean": list(c.mean), "std": list(c.std), "weights_path": c.weights_path}  # fmt: skip
        name, scale = "efficientnet_lite0", c.input_scale
    elif isinstance(extractor, OnnxFeatureExtractor):
        c = extractor.config
        cfg = {"path": c.path, "patch_size": c.patch_size, "input_size": None if c.input_size is None else list(c.input_size),
               "mean": list(c.mean), "std": list(c.std), "num_prefix_tokens": c.num_prefix_tokens,
               "output_name": c.output_name}  # fmt: skip
        name, scale = "onnx", None
    else:
        raise TypeError(f"unsupported extractor type {type(extractor).__name__}")
    return FrozenDict(
        name=name, config=cfg, feature_dim=int(extractor.feature_dim), input_scale=scale,
        stride=[h / gh, w / gw], scan_image_hw=[h, w],
    )  # fmt: skip


def make_extractor(feature_backend: dict) -> FeatureExtractor:
    """Rebuilds the feature extractor recorded in an ObjectModel's `feature_backend`."""
    name = feature_backend.get("name")
    cfg = dict(feature_backend.get("config", {}))
    if name == "efficientnet_lite0":
        return EfficientNetExtractor.pretrained(
            EfficientNetConfig(
                strides=tuple(cfg["strides"]), input_scale=float(cfg["input_scale"]),
                normalize_levels=bool(cfg["normalize_levels"]), mean=tuple(cfg["mean"]), std=tuple(cfg["std"]),
                weights_path=cfg.get("weights_path"),
            )  # fmt: skip
        )
    if name == "onnx":
        isz = cfg.get("input_size")
        return OnnxFeatureExtractor(
            OnnxConfig(
                path=cfg["path"], patch_size=int(cfg["patch_size"]), input_size=None if isz is None else tuple(isz),
                mean=tuple(cfg["mean"]), std=tuple(cfg["std"]), num_prefix_tokens=cfg.get("num_prefix_tokens"),
                output_name=cfg.get("output_name"),
            )  # fmt: skip
        )
    raise ValueError(f"feature_backend.name={name!r}: unknown (expected 'efficientnet_lite0' or 'onnx')")


# ---------------------------------------------------------------------------------------------
# Files
# ---------------------------------------------------------------------------------------------

_G_FIELDS = ("means", "quats", "log_scales", "opacity_logits", "colours", "features", "part_ids")


def save_object_model(model: ObjectModel, out_dir: str | Path) -> Path:
    """Writes `model.safetensors` + `model.json` into `out_dir` (each atomically). Returns the dir."""
    from safetensors.numpy import save

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    arrays = {f"gaussians.{f}": np.asarray(getattr(model.gaussians, f)) for f in _G_FIELDS}
    arrays["gaussians.part_ids"] = arrays["gaussians.part_ids"].astype(np.int32)
    for i, w in enumerate(model.decoder.weights):
        arrays[f"decoder.{i}"] = np.asarray(w, np.float32)
    arrays.update(model.pca.to_arrays())
    arrays["part_centroids"] = np.asarray(model.part_centroids, np.float32)
    arrays["arap_pairs"] = np.asarray(model.arap_pairs, np.int32).reshape(-1, 2)
    arrays = {k: np.ascontiguousarray(v) for k, v in arrays.items()}
    atomic_write_bytes(out / "model.safetensors", save(arrays))
    import rsrd_jax

    meta = {
        "format": MODEL_FORMAT,
        "rsrd_jax_version": getattr(rsrd_jax, "__version__", "unknown"),
        "num_gaussians": model.gaussians.num_gaussians,
        "feature_dim": model.gaussians.num_features,
        "decoder_layers": len(model.decoder.weights),
        "pca_dim": model.pca.dim,
        "num_parts": model.num_parts,
        "part_names": list(model.part_names),
        "feature_backend": dict(model.feature_backend),
        "meta": dict(model.meta),
    }
    atomic_write_json(out / "model.json", meta)
    return out


def load_object_model(model_dir: str | Path) -> ObjectModel:
    """Reads and validates an ObjectModel directory (errors name the file and the field)."""
    from safetensors.numpy import load_file

    d = Path(model_dir)
    jpath, spath = d / "model.json", d / "model.safetensors"
    for p in (jpath, spath):
        if not p.is_file():
            raise ArtefactError(f"{p}: not found (an ObjectModel directory holds model.json and model.safetensors)")
    meta = read_json(jpath, "ObjectModel model.json")
    if meta.get("format") != MODEL_FORMAT:
        raise ArtefactError(f"{jpath}: format: expected {MODEL_FORMAT!r}, got {meta.get('format')!r}")
    for k in ("num_gaussians", "feature_dim", "decoder_layers", "pca_dim", "num_parts", "part_names", "feature_backend"):
        if k not in meta:
            raise ArtefactError(f"{jpath}: {k}: missing")
    try:
        arr = load_file(str(spath))
    except Exception as e:  # noqa: BLE001
        raise ArtefactError(f"{spath}: unreadable safetensors ({e})") from e

    def get(key, shape, kind="f"):
        if key not in arr:
            raise ArtefactError(f"{spath}: {key}: missing")
        a = arr[key]
        if len(a.shape) != len(shape) or any(s is not None and s != t for s, t in zip(shape, a.shape)):
            raise ArtefactError(f"{spath}: {key}: expected shape {shape}, got {a.shape}")
        if a.dtype.kind != kind:
            raise ArtefactError(f"{spath}: {key}: expected dtype kind {kind!r}, got {a.dtype}")
        if kind == "f" and not np.all(np.isfinite(a)):
            raise ArtefactError(f"{spath}: {key}: non-finite values")
        return a

    n, f, p = int(meta["num_gaussians"]), int(meta["feature_dim"]), int(meta["num_parts"])
    g = {
        "means": get("gaussians.means", (n, 3)),
        "quats": get("gaussians.quats", (n, 4)),
        "log_scales": get("gaussians.log_scales", (n, 3)),
        "opacity_logits": get("gaussians.opacity_logits", (n,)),
        "colours": get("gaussians.colours", (n, 3)),
        "features": get("gaussians.features", (n, f)),
        "part_ids": get("gaussians.part_ids", (n,), "i"),
    }
    if n and (g["part_ids"].min() < 0 or g["part_ids"].max() >= p):
        raise ArtefactError(f"{spath}: gaussians.part_ids: values must lie in [0, {p})")
    try:
        gaussians = Gaussians(**{k: jnp.asarray(v) for k, v in g.items()})
    except Exception as e:  # noqa: BLE001
        raise ArtefactError(f"{spath}: gaussians: {e}") from e
    ws = tuple(jnp.asarray(get(f"decoder.{i}", (None, None))) for i in range(int(meta["decoder_layers"])))
    if ws[0].shape[0] != f or any(a.shape[1] != b.shape[0] for a, b in zip(ws[:-1], ws[1:])):
        raise ArtefactError(f"{spath}: decoder.*: layer shapes do not chain from F={f}")
    try:
        pca = PCA.from_arrays(arr, str(spath))
    except ValueError as e:
        raise ArtefactError(str(e)) from e
    if pca.dim != int(meta["pca_dim"]) or ws[-1].shape[1] != pca.dim:
        raise ArtefactError(f"{spath}: decoder output {ws[-1].shape[1]} / pca dim {pca.dim} disagree with pca_dim")
    cents = get("part_centroids", (p, 3))
    pairs = get("arap_pairs", (None, 2), "i")
    if pairs.size and (pairs.min() < 0 or pairs.max() >= n):
        raise ArtefactError(f"{spath}: arap_pairs: indices must lie in [0, {n})")
    names = meta["part_names"]
    if not isinstance(names, list) or len(names) != p:
        raise ArtefactError(f"{jpath}: part_names: expected {p} names")
    return ObjectModel(
        gaussians=gaussians,
        decoder=FeatureDecoder(ws),
        pca=pca,
        part_centroids=jnp.asarray(cents),
        arap_pairs=jnp.asarray(pairs.astype(np.int32)),
        feature_backend=FrozenDict(meta["feature_backend"]),
        part_names=tuple(str(s) for s in names),
        meta=FrozenDict(meta.get("meta", {})),
    )
