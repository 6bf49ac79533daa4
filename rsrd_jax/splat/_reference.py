"""Dense brute-force renderer (every pixel × every Gaussian, sorted by depth). Tests only.

Written independently of the tiled path: covariances as explicit 3×3 matrix products, the
Jacobian as a 2×3 matrix, the conic by matrix inversion, no boxes or tiles, and transmittance as
a cumulative product. Cost O(H·W·N): keep scenes tiny.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jaxlie

from ..geometry import Camera
from ._gaussians import Gaussians
from ._project import (
    ALPHA_THRESHOLD,
    EPS2D,
    FAR_PLANE,
    FRUSTUM_MARGIN,
    MAX_ALPHA,
    NEAR_PLANE,
    TRANSMITTANCE_THRESHOLD,
)


def render_reference(
    gaussians: Gaussians, camera: Camera, background: jax.Array | None = None
) -> dict[str, jax.Array]:
    """Dense render; returns a dict with rgb, features, depth, depth_accum, alpha, n_contrib."""
    intr = camera.intrinsics
    dtype = gaussians.means.dtype
    W, H = intr.width, intr.height
    fx, fy, cx, cy = (jnp.asarray(x, dtype) for x in (intr.fx, intr.fy, intr.cx, intr.cy))
    T = camera.T_cam_world.as_matrix().astype(dtype)
    Rv, tv = T[:3, :3], T[:3, 3]
    mu = gaussians.means @ Rv.T + tv
    q = gaussians.quats / jnp.linalg.norm(gaussians.quats, axis=-1, keepdims=True)
    R = jax.vmap(lambda qq: jaxlie.SO3(qq).as_matrix())(q)
    S2 = jax.vmap(jnp.diag)(jnp.exp(2.0 * gaussians.log_scales))
    cov = R @ S2 @ jnp.swapaxes(R, -1, -2)
    cov_c = Rv[None] @ cov @ Rv.T[None]

    def proj_one(p, C):
        x, y, z = p
        zs = jnp.where(z > NEAR_PLANE, z, 1.0)
        lx = cx / fx + FRUSTUM_MARGIN * 0.5 * W / fx
        hx = (W - cx) / fx + FRUSTUM_MARGIN * 0.5 * W / fx
        ly = cy / fy + FRUSTUM_MARGIN * 0.5 * H / fy
        hy = (H - cy) / fy + FRUSTUM_MARGIN * 0.5 * H / fy
        tx = zs * jnp.clip(x / zs, -lx, hx)
        ty = zs * jnp.clip(y / zs, -ly, hy)
        J = jnp.array([[fx / zs, 0.0, -fx * tx / zs**2], [0.0, fy / zs, -fy * ty / zs**2]], dtype)
        cov2 = J @ C @ J.T + EPS2D * jnp.eye(2, dtype=dtype)
        det = jnp.linalg.det(cov2)
        ok = (z > NEAR_PLANE) & (z < FAR_PLANE) & (det > 0)
        conic = jnp.linalg.inv(jnp.where(ok, cov2, jnp.eye(2, dtype=dtype)))
        uv = jnp.stack([fx * x / zs + cx, fy * y / zs + cy])
        return uv, conic, ok

    uv, conic, ok = jax.vmap(proj_one)(mu, cov_c)
    opac = jax.nn.sigmoid(gaussians.opacity_logits)
    ok = ok & (opac >= ALPHA_THRESHOLD)
    order = jnp.argsort(jnp.where(ok, mu[:, 2], jnp.inf))
    uv, conic, ok, opac, z = uv[order], conic[order], ok[order], opac[order], mu[order, 2]
    chans = jnp.concatenate([gaussians.colours, gaussians.features], -1)[order]

    px, py = jnp.meshgrid(jnp.arange(W, dtype=dtype) + 0.5, jnp.arange(H, dtype=dtype) + 0.5)
    d = uv[None, None, :, :] - jnp.stack([px, py], -1)[:, :, None, :]  # (H, W, N, 2)
    sigma = 0.5 * jnp.einsum("hwni,nij,hwnj->hwn", d, conic, d)
    alpha = jnp.minimum(MAX_ALPHA, opac * jnp.exp(-sigma))
    keep = ok & (sigma >= 0) & (alpha >= ALPHA_THRESHOLD)
    a = jnp.where(keep, alpha, 0.0)
    T_incl = jnp.cumprod(1.0 - a, axis=-1)
    used = keep & (T_incl > TRANSMITTANCE_THRESHOLD)
    a_used = jnp.where(used, a, 0.0)
    T_excl = jnp.cumprod(1.0 - a_used, axis=-1) / (1.0 - a_used)
    w = a_used * T_excl
    out = jnp.einsum("hwn,nc->hwc", w, chans)
    acc = 1.0 - jnp.prod(1.0 - a_used, axis=-1)
    d_acc = jnp.einsum("hwn,n->hw", w, z)
    rgb = out[..., :3]
    if background is not None:
        rgb = rgb + (1.0 - acc)[..., None] * background
    return {
        "rgb": rgb,
        "features": out[..., 3:],
        "depth": d_acc / jnp.maximum(acc, 1e-10),
        "depth_accum": d_acc,
        "alpha": acc,
        "n_contrib": jnp.sum(used, axis=-1),
    }
