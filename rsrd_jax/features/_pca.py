"""Principal component analysis of feature maps (fit on the host in float64, project in JAX)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import threadpoolctl
from jaxtyping import Array, Float

from ._extractor import FeatureMap

PCA_ARRAY_KEYS = ("pca_mean", "pca_components", "pca_explained_variance")
"""Names of the arrays ``PCA.to_arrays`` writes (e.g. into ``model.safetensors``)."""


class PCA(eqx.Module):
    """A linear map from D-dimensional features to their top-k principal components.

    ``project(x) = (x − mean) @ componentsᵀ``; rows of ``components`` are orthonormal, ordered by
    decreasing ``explained_variance``, and each row's largest-magnitude entry is positive (so a
    fit is deterministic up to ties).
    """

    mean: Float[Array, " d"]
    """Feature mean subtracted before projecting."""
    components: Float[Array, "k d"]
    """Principal axes, one per row, orthonormal."""
    explained_variance: Float[Array, " k"]
    """Variance of the training features along each axis (unbiased, descending)."""

    @property
    def dim(self) -> int:
        """Output dimension k."""
        return int(self.components.shape[0])

    @property
    def input_dim(self) -> int:
        """Input feature dimension D."""
        return int(self.components.shape[1])

    def project(self, x: Float[Array, "*batch d"]) -> Float[Array, "*batch k"]:
        """Coordinates of features ``x`` in the principal basis."""
        return (x - self.mean) @ self.components.T

    def reconstruct(self, y: Float[Array, "*batch k"]) -> Float[Array, "*batch d"]:
        """Features back from principal coordinates (the projection onto the k-dim subspace)."""
        return y @ self.components + self.mean

    def project_map(self, fmap: FeatureMap) -> FeatureMap:
        """Projects a feature map's vectors, keeping its grid and stride."""
        return FeatureMap(features=self.project(fmap.features), stride=fmap.stride)

    def to_arrays(self) -> dict[str, np.ndarray]:
        """float32 numpy arrays keyed by ``PCA_ARRAY_KEYS``, for safetensors/npz."""
        return {
            "pca_mean": np.asarray(self.mean, np.float32),
            "pca_components": np.asarray(self.components, np.float32),
            "pca_explained_variance": np.asarray(self.explained_variance, np.float32),
        }

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray], source: str = "arrays") -> PCA:
        """Inverse of ``to_arrays``; validates names, shapes and finiteness.

        Raises:
          ValueError: naming ``source`` and the bad field.
        """
        missing = [k for k in PCA_ARRAY_KEYS if k not in arrays]
        if missing:
            raise ValueError(f"{source}: missing PCA arrays {missing}")
        mean, comp, var = (np.asarray(arrays[k]) for k in PCA_ARRAY_KEYS)
        if comp.ndim != 2:
            raise ValueError(f"{source}: pca_components must be k×d, got shape {comp.shape}")
        k, d = comp.shape
        if mean.shape != (d,):
            raise ValueError(f"{source}: pca_mean has shape {mean.shape}, expected ({d},)")
        if var.shape != (k,):
            raise ValueError(
                f"{source}: pca_explained_variance has shape {var.shape}, expected ({k},)"
            )
        for name, a in zip(PCA_ARRAY_KEYS, (mean, comp, var), strict=True):
            if not np.issubdtype(a.dtype, np.floating) or not np.all(np.isfinite(a)):
                raise ValueError(f"{source}: {name} must be finite floats")
        return cls(
            mean=jnp.asarray(mean, jnp.float32),
            components=jnp.asarray(comp, jnp.float32),
            explained_variance=jnp.asarray(var, jnp.float32),
        )


def _rows(item, mask, i: int) -> np.ndarray:
    feats = item.features if isinstance(item, FeatureMap) else item
    arr = np.asarray(feats)
    if arr.ndim < 1:
        raise ValueError(f"features[{i}]: expected a ...×D array, got a scalar")
    rows = arr.reshape(-1, arr.shape[-1])
    if mask is not None:
        m = np.asarray(mask, bool)
        if m.shape != arr.shape[:-1]:
            raise ValueError(
                f"masks[{i}]: shape {m.shape} does not match the feature grid {arr.shape[:-1]}"
            )
        rows = rows[m.reshape(-1)]
    return rows


def fit_pca(
    features: Sequence[FeatureMap | np.ndarray | Array] | FeatureMap | np.ndarray | Array,
    dim: int = 64,
    masks: Sequence[np.ndarray | None] | None = None,
    max_samples: int = 100_000,
    seed: int = 0,
) -> PCA:
    """Fits a PCA to feature vectors pooled from many maps (e.g. all scan views).

    The covariance ``XᵀX/(n−1)`` of the centred vectors is eigendecomposed (float64 ``eigh``),
    exact and cheap for D up to a few thousand; more than ``max_samples`` vectors are uniformly
    subsampled (seeded) first.

    Args:
      features: one or a sequence of ``...×D`` arrays or ``FeatureMap``s (same D).
      dim: number of components k, ≤ D.
      masks: optional per-map boolean masks over the grid (``...``): only True cells are used.
      max_samples: cap on the number of vectors used.
      seed: subsampling seed.

    Returns:
      The fitted ``PCA``.

    Raises:
      ValueError: mismatched D, dim out of range, fewer than two vectors, non-finite values.
    """
    if isinstance(features, (FeatureMap, np.ndarray)) or hasattr(features, "shape"):
        features = [features]
    if masks is not None and len(masks) != len(features):
        raise ValueError(f"masks: {len(masks)} masks for {len(features)} feature maps")
    rows = [_rows(f, None if masks is None else masks[i], i) for i, f in enumerate(features)]
    if not rows:
        raise ValueError("features: no feature maps given")
    dims = {r.shape[1] for r in rows}
    if len(dims) != 1:
        raise ValueError(f"features: maps have different feature dimensions {sorted(dims)}")
    (d,) = dims
    if not 1 <= dim <= d:
        raise ValueError(f"dim={dim}: must be between 1 and the feature dimension {d}")
    x = np.concatenate(rows, axis=0)
    n = x.shape[0]
    if n < 2:
        raise ValueError(f"features: need at least 2 feature vectors, got {n}")
    if n > max_samples:
        x = x[np.random.default_rng(seed).choice(n, max_samples, replace=False)]
    if not np.all(np.isfinite(x)):
        raise ValueError("features: contain non-finite values")
    # Mean in float64; the centred Gram matrix in float32 (sgemm) then float64 for eigh: the
    # relative error of the covariance is ~1e-7, far below what PCA of features needs.
    # Single-threaded BLAS: on this shared 2-core machine OpenBLAS threads spin and make this
    # ~14× slower (2.6 s vs 0.19 s for 30k × 152).
    with threadpoolctl.threadpool_limits(1, user_api="blas"):
        mean = x.mean(axis=0, dtype=np.float64)
        xc = (x - mean).astype(np.float32)
        cov = (xc.T @ xc).astype(np.float64) / (x.shape[0] - 1)
        evals, evecs = np.linalg.eigh(cov)
    order = np.argsort(evals)[::-1][:dim]
    comps = evecs[:, order].T
    signs = np.sign(comps[np.arange(dim), np.argmax(np.abs(comps), axis=1)])
    comps = comps * signs[:, None]
    var = np.maximum(evals[order], 0.0)
    return PCA(
        mean=jnp.asarray(mean, jnp.float32),
        components=jnp.asarray(comps, jnp.float32),
        explained_variance=jnp.asarray(var, jnp.float32),
    )
