"""The Gaussians pytree (raw parameters, activations in one place) and per-part rigid posing."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Array, Float, Int

# Logit given to padding Gaussians: sigmoid(-1e4) == 0 exactly in float32, with zero gradient.
PAD_OPACITY_LOGIT = -1e4


class Gaussians(eqx.Module):
    """N anisotropic 3D Gaussians with colour, an F-dimensional feature vector and a part id.

    Raw (unconstrained) parameters are stored; `opacities()`, `scales()` and `unit_quats()` apply
    the activations (sigmoid, exp, normalisation) and are the only place that does. Colours and
    features are used as stored (linear values; clamp or activate them in the fitting code if
    wanted). Padding entries have opacity logit `PAD_OPACITY_LOGIT` (opacity 0): the projection
    culls them, so they cost nothing in compositing and receive zero gradient.
    """

    means: Float[Array, "n 3"]
    """Centres in the model (object) frame, metres."""
    quats: Float[Array, "n 4"]
    """Rotations as wxyz quaternions (any norm; normalised by `unit_quats`)."""
    log_scales: Float[Array, "n 3"]
    """Natural log of the standard deviations along the Gaussian's own axes, log-metres."""
    opacity_logits: Float[Array, " n"]
    """Logit of the peak opacity."""
    colours: Float[Array, "n 3"]
    """Linear RGB, nominally in [0, 1]."""
    features: Float[Array, "n f"]
    """Per-Gaussian feature vectors (F may be 0)."""
    part_ids: Int[Array, " n"]
    """Index of the rigid part each Gaussian belongs to (0 when there is a single part)."""

    @staticmethod
    def create(
        means,
        quats,
        log_scales,
        opacity_logits,
        colours,
        features=None,
        part_ids=None,
    ) -> Gaussians:
        """Builds and validates Gaussians from array-likes (host boundary).

        `features` defaults to an empty N×0 array and `part_ids` to zeros.
        """
        means = np.asarray(means, np.float32)
        if means.ndim != 2 or means.shape[1] != 3:
            raise ValueError(f"Gaussians.means must be N×3, got shape {means.shape}")
        n = means.shape[0]
        fields = {
            "quats": (quats, (n, 4)),
            "log_scales": (log_scales, (n, 3)),
            "opacity_logits": (opacity_logits, (n,)),
            "colours": (colours, (n, 3)),
        }
        arrays = {}
        for name, (value, shape) in fields.items():
            a = np.asarray(value, np.float32)
            if a.shape != shape:
                raise ValueError(f"Gaussians.{name} must have shape {shape}, got {a.shape}")
            arrays[name] = a
        features = np.zeros((n, 0), np.float32) if features is None else np.asarray(features, np.float32)
        if features.ndim != 2 or features.shape[0] != n:
            raise ValueError(f"Gaussians.features must be N×F with N={n}, got {features.shape}")
        part_ids = np.zeros(n, np.int32) if part_ids is None else np.asarray(part_ids)
        if part_ids.shape != (n,) or not np.issubdtype(part_ids.dtype, np.integer):
            raise ValueError(f"Gaussians.part_ids must be N integers, got {part_ids.shape} {part_ids.dtype}")
        if n and part_ids.min() < 0:
            raise ValueError("Gaussians.part_ids must be non-negative")
        for name, a in [("means", means), *arrays.items(), ("features", features)]:
            if not np.all(np.isfinite(a)):
                raise ValueError(f"Gaussians.{name} has non-finite values")
        if n and np.any(np.linalg.norm(arrays["quats"], axis=1) == 0):
            raise ValueError("Gaussians.quats has zero quaternions")
        return Gaussians(
            jnp.asarray(means),
            jnp.asarray(arrays["quats"]),
            jnp.asarray(arrays["log_scales"]),
            jnp.asarray(arrays["opacity_logits"]),
            jnp.asarray(arrays["colours"]),
            jnp.asarray(features),
            jnp.asarray(part_ids, jnp.int32),
        )

    @property
    def num_gaussians(self) -> int:
        return self.means.shape[-2]

    @property
    def num_features(self) -> int:
        return self.features.shape[-1]

    def opacities(self) -> Float[Array, " n"]:
        """Peak opacities in [0, 1] (sigmoid of the logits)."""
        return jax.nn.sigmoid(self.opacity_logits)

    def scales(self) -> Float[Array, "n 3"]:
        """Standard deviations in metres (exp of the log-scales)."""
        return jnp.exp(self.log_scales)

    def unit_quats(self) -> Float[Array, "n 4"]:
        """Unit wxyz quaternions."""
        q = self.quats  # the norm written out (a size-4 reduction is slow on XLA CPU)
        n2 = q[..., 0] * q[..., 0] + q[..., 1] * q[..., 1] + q[..., 2] * q[..., 2] + q[..., 3] * q[..., 3]
        return q / jnp.sqrt(n2)[..., None]

    def padded(self, n: int) -> Gaussians:
        """These Gaussians followed by zero-opacity padding up to `n` entries (host-side)."""
        m = self.num_gaussians
        if n < m:
            raise ValueError(f"cannot pad {m} Gaussians down to {n}")
        k = n - m

        def pad(x, value):
            return jnp.concatenate([x, jnp.full((k, *x.shape[1:]), value, x.dtype)], axis=0)

        quat_pad = jnp.concatenate(
            [self.quats, jnp.tile(jnp.asarray([[1.0, 0.0, 0.0, 0.0]], self.quats.dtype), (k, 1))]
        )
        return Gaussians(
            pad(self.means, 0.0),
            quat_pad,
            pad(self.log_scales, -5.0),
            pad(self.opacity_logits, PAD_OPACITY_LOGIT),
            pad(self.colours, 0.0),
            pad(self.features, 0.0),
            pad(self.part_ids, 0),
        )


def rest_part_poses(part_centroids: Float[Array, "p 3"]) -> jaxlie.SE3:
    """`T_obj_part` of every part at rest: identity rotation, translation to the part centroid.

    With these poses `apply_part_poses` returns the Gaussians unchanged (up to rounding).
    """
    c = jnp.asarray(part_centroids)
    wxyz = jnp.broadcast_to(jnp.asarray([1.0, 0.0, 0.0, 0.0], c.dtype), (*c.shape[:-1], 4))
    return jaxlie.SE3(jnp.concatenate([wxyz, c], axis=-1))


def apply_part_poses(
    gaussians: Gaussians,
    T_obj_part: jaxlie.SE3,
    part_centroids: Float[Array, "p 3"],
) -> Gaussians:
    """Moves each part rigidly: the Gaussians of part p go to `T_obj_part[p] @ (x - c_p)`.

    Frames: `gaussians` are the model at rest in the object frame; the part frame of part p has
    its origin at the rest centroid `c_p` and the object's axes, so a Gaussian's part-frame
    position is `x - c_p`. `T_obj_part` (batch shape (P,)) maps part-frame points into the
    object frame; `rest_part_poses(part_centroids)` is the rest configuration. Tracking can
    parameterise `T_obj_part = rest @ delta` (RSRD's `init_p2o · part_delta`) and differentiate
    through this function. Rotations compose as `q' = q_part ⊗ q` (covariance R Σ Rᵀ).

    Args:
        gaussians: the rest-pose model (means in metres, object frame).
        T_obj_part: per-part poses, `wxyz_xyz` of shape (P, 7).
        part_centroids: (P, 3) rest centroids in the object frame, metres.

    Returns:
        Gaussians with moved means and rotated quaternions; everything else unchanged.
    """
    T = jaxlie.SE3(T_obj_part.wxyz_xyz[gaussians.part_ids])
    local = gaussians.means - jnp.asarray(part_centroids)[gaussians.part_ids]
    means = T @ local
    quats = (T.rotation() @ jaxlie.SO3(gaussians.quats)).wxyz
    return eqx.tree_at(lambda g: (g.means, g.quats), gaussians, (means, quats))
