"""EWA projection of 3D Gaussians to screen-space conics, with gsplat's constants.

Follows gsplat's `fully_fused_projection` (classic mode): covariance Σ = R S² Rᵀ, world → camera,
perspective Jacobian evaluated at the frustum-clamped direction, a 0.3 px² blur on the diagonal,
conic = inverse of the blurred 2D covariance, and an axis-aligned box per Gaussian. The box uses
gsplat's opacity-aware extent (StopThePop, arXiv 2402.00525): outside k·σ with
k = min(3.33, √(2 ln(255·o))) every pixel has α < 1/255 and is skipped anyway, so this culls
nothing that could contribute.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from ..geometry import Camera
from ._gaussians import Gaussians

NEAR_PLANE = 0.01
"""Gaussians with camera depth below this (metres) are culled (gsplat `near_plane`)."""
FAR_PLANE = 1e10
"""Gaussians with camera depth above this (metres) are culled (gsplat `far_plane`)."""
EPS2D = 0.3
"""Screen-space blur added to both diagonal entries of the 2D covariance, px² (gsplat `eps2d`)."""
GAUSSIAN_EXTEND = 3.33
"""Maximum box half-extent in standard deviations per axis (gsplat `GAUSSIAN_EXTEND`)."""
ALPHA_THRESHOLD = 1.0 / 255.0
"""Pixel-Gaussian pairs with α below this are skipped; opacities below it are culled."""
MAX_ALPHA = 0.99
"""Cap on a single Gaussian's α. 0.99 as in current gsplat (main since c5ff586b); gsplat ≤ 1.5.3
(and so RSRD) used 0.999. Chosen so that TRANSMITTANCE_THRESHOLD = (1 − MAX_ALPHA)² as in gsplat."""
TRANSMITTANCE_THRESHOLD = 1e-4
"""A pixel stops when the transmittance after a Gaussian would fall to this or below; that
Gaussian is not added (gsplat's exclusive stop)."""
FRUSTUM_MARGIN = 0.3
"""J is evaluated with x/z, y/z clamped to the frustum widened by this fraction of tan(half-FOV)."""


class Projected(eqx.Module):
    """Screen-space Gaussians of one camera (all N, invisible ones flagged)."""

    xy: Float[Array, "n 2"]
    """Projected mean (u, v) in pixels, pixel centres at +0.5."""
    depth: Float[Array, " n"]
    """Camera-frame z of the mean, metres."""
    conic: Float[Array, "n 3"]
    """(a, b, c) = entries (00, 01, 11) of the inverse blurred 2D covariance, 1/px²."""
    opacity: Float[Array, " n"]
    """Peak opacity (zero where invisible)."""
    extent: Float[Array, "n 2"]
    """Half-widths of the axis-aligned box beyond which α < 1/255, pixels (no gradient)."""
    visible: Bool[Array, " n"]
    """In front of the near plane, finite non-degenerate conic, opacity ≥ 1/255, box in image."""


def quat_to_rotmat(q: Float[Array, "*batch 4"]) -> Float[Array, "*batch 3 3"]:
    """Rotation matrices of unit wxyz quaternions."""
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2)


def _dot3(a: jax.Array, b: jax.Array) -> jax.Array:
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def project_gaussians(gaussians: Gaussians, camera: Camera) -> Projected:
    """EWA-projects every Gaussian into `camera` (differentiable in means, rotations, scales,
    opacities and the camera pose; culling decisions carry no gradient).

    Returns:
        `Projected` with N entries; culled Gaussians have `visible = False` and opacity 0.
    """
    intr = camera.intrinsics
    dtype = gaussians.means.dtype
    R_cw = camera.T_cam_world.rotation().as_matrix().astype(dtype)
    t_cw = camera.T_cam_world.translation().astype(dtype)
    # Products over axes of size 3 are written out: XLA CPU sends tiny contractions and
    # reductions to a single-threaded library call that costs far more than the arithmetic.
    mx, my, mz = gaussians.means[:, 0], gaussians.means[:, 1], gaussians.means[:, 2]
    x, y, z = (R_cw[i, 0] * mx + R_cw[i, 1] * my + R_cw[i, 2] * mz + t_cw[i] for i in range(3))
    in_depth = (z > NEAR_PLANE) & (z < FAR_PLANE)
    z_safe = jnp.where(in_depth, z, 1.0)

    # Camera-frame covariance: M = R_cw R(q) S, Σ_c = M Mᵀ.
    R = quat_to_rotmat(gaussians.unit_quats())
    sc = gaussians.scales()
    # Rows of M = R_cw R(q) S.
    M0, M1, M2 = (sc * (R_cw[i, 0] * R[:, 0] + R_cw[i, 1] * R[:, 1] + R_cw[i, 2] * R[:, 2]) for i in range(3))
    fx, fy, cx, cy = (v.astype(dtype) for v in (intr.fx, intr.fy, intr.cx, intr.cy))
    W, H = intr.width, intr.height
    tan_x = 0.5 * W / fx
    tan_y = 0.5 * H / fy
    xz = jnp.clip(x / z_safe, -(cx / fx + FRUSTUM_MARGIN * tan_x), (W - cx) / fx + FRUSTUM_MARGIN * tan_x)
    yz = jnp.clip(y / z_safe, -(cy / fy + FRUSTUM_MARGIN * tan_y), (H - cy) / fy + FRUSTUM_MARGIN * tan_y)
    # Rows of J M (2×3 each): J = [[fx/z, 0, -fx·xz/z], [0, fy/z, -fy·yz/z]].
    JM0 = (fx / z_safe)[:, None] * (M0 - xz[:, None] * M2)
    JM1 = (fy / z_safe)[:, None] * (M1 - yz[:, None] * M2)
    s00 = _dot3(JM0, JM0) + EPS2D
    s01 = _dot3(JM0, JM1)
    s11 = _dot3(JM1, JM1) + EPS2D
    det = s00 * s11 - s01 * s01
    ok_det = det > 0
    det_safe = jnp.where(ok_det, det, 1.0)
    conic = jnp.stack([s11 / det_safe, -s01 / det_safe, s00 / det_safe], axis=-1)

    u = fx * x / z_safe + cx
    v = fy * y / z_safe + cy
    opac = gaussians.opacities()

    # Box (no gradient): opacity-aware extent, with a hair of slack for rounding.
    o_sg = jax.lax.stop_gradient(opac)
    k = jnp.sqrt(2.0 * jnp.log(jnp.maximum(o_sg * 255.0, 1.0)))
    k = jnp.minimum(k, GAUSSIAN_EXTEND) * (1.0 + 1e-4) + 1e-4
    ext = jax.lax.stop_gradient(
        jnp.stack([k * jnp.sqrt(jnp.maximum(s00, 0.0)), k * jnp.sqrt(jnp.maximum(s11, 0.0))], -1)
    )
    u_sg, v_sg = jax.lax.stop_gradient(u), jax.lax.stop_gradient(v)
    in_image = (
        (u_sg + ext[:, 0] > 0) & (u_sg - ext[:, 0] < W) & (v_sg + ext[:, 1] > 0) & (v_sg - ext[:, 1] < H)
    )
    finite = jnp.all(jnp.isfinite(conic), -1) & jnp.isfinite(u) & jnp.isfinite(v)
    visible = jax.lax.stop_gradient(in_depth & ok_det & finite & (o_sg >= ALPHA_THRESHOLD) & in_image)
    return Projected(
        xy=jnp.stack([jnp.where(visible, u, 0.0), jnp.where(visible, v, 0.0)], -1),
        depth=jnp.where(visible, z, 0.0),
        conic=jnp.where(visible[:, None], conic, 0.0),
        opacity=jnp.where(visible, opac, 0.0),
        extent=jnp.where(visible[:, None], ext, 0.0),
        visible=visible,
    )


def blend_weights(proj: Projected, points: np.ndarray) -> np.ndarray:
    """Each Gaussian's blending weight αᵢ·Tᵢ at screen points, as the rasterizer composites a
    pixel centred there (host, NumPy; for a few points, e.g. which part the render shows under a
    detected fingertip).

    The same rules as the tiled path: front to back by depth, α = min(MAX_ALPHA, o·exp(−σ)) with
    σ = ½(a·dx² + c·dy²) + b·dx·dy, pairs with σ < 0 or α < ALPHA_THRESHOLD skipped, and the
    exclusive stop at TRANSMITTANCE_THRESHOLD.

    Args:
        proj: projected Gaussians (N).
        points: (k, 2) screen positions in pixels (pixel centres at +0.5).

    Returns:
        (k, N) weights; a row sums to the rendered alpha there.
    """
    xy, depth = np.asarray(proj.xy, np.float64), np.asarray(proj.depth, np.float64)
    conic, opac = np.asarray(proj.conic, np.float64), np.asarray(proj.opacity, np.float64)
    vis = np.flatnonzero(np.asarray(proj.visible))
    vis = vis[np.argsort(depth[vis], kind="stable")]
    pts = np.asarray(points, np.float64).reshape(-1, 2)
    out = np.zeros((len(pts), len(xy)))
    for k, p in enumerate(pts):
        dx, dy = p[0] - xy[vis, 0], p[1] - xy[vis, 1]
        a, b, c = conic[vis, 0], conic[vis, 1], conic[vis, 2]
        sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
        alpha = np.minimum(MAX_ALPHA, opac[vis] * np.exp(-np.maximum(sigma, 0.0)))
        alpha = np.where((sigma >= 0) & (alpha >= ALPHA_THRESHOLD), alpha, 0.0)
        T_after = np.cumprod(1.0 - alpha)
        T_before = np.concatenate([[1.0], T_after[:-1]])
        keep = T_after > TRANSMITTANCE_THRESHOLD  # exclusive stop: the Gaussian that would cross it is not added
        keep &= np.concatenate([[True], np.cumprod(keep)[:-1].astype(bool)])
        out[k, vis] = np.where(keep, alpha * T_before, 0.0)
    return out
