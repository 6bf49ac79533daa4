"""4D-DPM loss terms: features, mono-depth ranking, ARAP with Barron's robust loss, smoothness."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jaxlie
from jaxtyping import Array, Bool, Float, Int

from ..geometry import project_points


def barron_loss(x: Float[Array, "*b"], alpha: Float[Array, ""] | float, c: Float[Array, ""] | float) -> Float[Array, "*b"]:
    """Barron's general robust loss ρ(x, α, c) (CVPR 2019, eq. 1), smooth in α.

    ρ = |α−2|/α · (((x/c)²/|α−2| + 1)^{α/2} − 1). α = 2 is L2/2, α = 1 pseudo-Huber, α → 0 Cauchy
    (log), α = −2 Geman–McClure. α exactly 0 or 2 is replaced by a nearby value (the limits are
    continuous), so the formula stays a single branch under jit.
    """
    alpha = jnp.asarray(alpha, x.dtype)
    eps = 1e-5
    a = jnp.where(jnp.abs(alpha) < eps, eps, alpha)
    a = jnp.where(jnp.abs(a - 2.0) < eps, 2.0 + eps, a)
    b = jnp.abs(a - 2.0)
    z = (x / c) ** 2
    # ((z/b + 1)^(a/2) − 1) as expm1(a/2 · log1p(z/b)): no cancellation near α = 0
    return b / a * jnp.expm1(0.5 * a * jnp.log1p(z / b))


def feature_loss(
    rendered: Float[Array, "h w d"],
    observed: Float[Array, "h w d"],
    weight: Float[Array, "h w"],
) -> Float[Array, ""]:
    """Weighted mean of the unsquared L2 feature distance per pixel (RSRD's DINO loss).

    `weight` is 0 on occluded (hand) pixels and 1 elsewhere in the ROI.
    """
    d = jnp.sqrt(jnp.sum((rendered - observed) ** 2, axis=-1) + 1e-12)
    return jnp.sum(weight * d) / jnp.maximum(jnp.sum(weight), 1.0)


def depth_ranking_loss(
    rendered_depth: Float[Array, " n"],
    mono_depth: Float[Array, " n"],
    pairs: Int[Array, "m 2"],
    pair_weight: Float[Array, " m"],
    margin: float = 1e-4,
) -> Float[Array, ""]:
    """Ranking loss on random pixel pairs: penalises rendered depth orders that disagree with the
    monocular depth's order (only order information of mono-depth is used).

    For a pair (i, j) with s = sign(mono_i − mono_j): loss = relu(margin − s·(r_i − r_j)), i.e. the
    rendered depth difference when the order is wrong (nerfstudio's `depth_ranking_loss`).
    """
    ri, rj = rendered_depth[pairs[:, 0]], rendered_depth[pairs[:, 1]]
    s = jnp.sign(mono_depth[pairs[:, 0]] - mono_depth[pairs[:, 1]])
    per = jax.nn.relu(margin - s * (ri - rj)) * (s != 0)
    return jnp.sum(pair_weight * per) / jnp.maximum(jnp.sum(pair_weight), 1.0)


def arap_loss(
    means: Float[Array, "n 3"],
    rest_means: Float[Array, "n 3"],
    pairs: Int[Array, "m 2"],
    pair_weight: Float[Array, " m"],
    alpha: Float[Array, ""] | float,
    scale: Float[Array, ""] | float,
) -> Float[Array, ""]:
    """As-rigid-as-possible term on cross-part boundary pairs: Barron loss of the change of each
    pair's distance relative to rest, scale `scale` (metres). Zero at the rest configuration and
    for any rigid motion of the whole object; rises when touching parts separate."""
    d = jnp.linalg.norm(means[pairs[:, 0]] - means[pairs[:, 1]] + 1e-12, axis=-1)
    d0 = jnp.linalg.norm(rest_means[pairs[:, 0]] - rest_means[pairs[:, 1]] + 1e-12, axis=-1)
    per = barron_loss(d - d0, alpha, scale)
    return jnp.sum(pair_weight * per) / jnp.maximum(jnp.sum(pair_weight), 1.0)


def touch_loss(
    means: Float[Array, "n 3"],
    points: Int[Array, " e"],
    candidates: Int[Array, "e k"],
    rest: Float[Array, " e"],
    weight: Float[Array, " e"],
    direction: Int[Array, " e"],
    pair_directions: Int[Array, "u 2"],
    alpha: Float[Array, ""] | float,
    scale: Float[Array, ""] | float,
) -> Float[Array, ""]:
    """As-touching-as-possible term. Each contact Gaussian of part q should keep its rest distance
    to the nearest of its candidate Gaussians on part r (Barron loss, scale `scale`); the mean per
    direction q → r is taken, and each touching part pair scores the *smaller* of its two
    directions (a slider's contacts stay on the rail while the rail's contacts lose the slider).
    Unlike pair-distance ARAP it is ~zero when a part slides along the other (a drawer, a slide) as
    well as when it turns about a hinge through the contact; it rises when the parts separate or
    interpenetrate. Mean over touching part pairs."""
    d = jnp.linalg.norm(means[points][:, None, :] - means[candidates] + 1e-12, axis=-1)
    per = weight * barron_loss(jnp.min(d, axis=-1) - rest, alpha, scale)
    nd = pair_directions.shape[0] * 2
    tot = jax.ops.segment_sum(per, direction, nd)
    cnt = jax.ops.segment_sum(weight, direction, nd)
    mean_d = tot / jnp.maximum(cnt, 1e-9)
    has = cnt > 0

    def side(i):
        ok = (i >= 0) & has[jnp.maximum(i, 0)]
        return jnp.where(ok, mean_d[jnp.maximum(i, 0)], jnp.inf)

    lu = jnp.minimum(side(pair_directions[:, 0]), side(pair_directions[:, 1]))
    valid = jnp.isfinite(lu)
    return jnp.sum(jnp.where(valid, lu, 0.0)) / jnp.maximum(jnp.sum(valid), 1)


def prismatic_loss(
    T_obj_part: jaxlie.SE3,
    centroids: Float[Array, "p 3"],
    parts: Int[Array, "q 2"],
    axes: Float[Array, "q 3"],
    lengths: Float[Array, " q"],
    weight: Float[Array, " q"],
    alpha: Float[Array, ""] | float,
    scale: Float[Array, ""] | float,
) -> Float[Array, ""]:
    """Slide joints: part k = parts[i, 0] moves relative to part n = parts[i, 1] only by a
    translation along `axes[i]` (a unit vector in n's frame, i.e. the object frame at rest).

    With T_rel = T_n⁻¹ T_k (rest: a translation by c_k − c_n), the residuals are the part of
    T_rel's translation change orthogonal to the axis (metres) and its rotation angle times
    `lengths[i]` (metres at the part's radius), each through Barron's loss at `scale`. Zero at
    rest, for any rigid motion of the whole object and for any slide along the axis; weighted
    mean over the entries."""
    rel = _relative(T_obj_part, parts)
    perp = _off_axis(rel.translation() - (centroids[parts[:, 0]] - centroids[parts[:, 1]]), axes)
    ang = jnp.linalg.norm(rel.rotation().log() + 1e-12, axis=-1)
    per = barron_loss(jnp.linalg.norm(perp + 1e-12, axis=-1), alpha, scale) + barron_loss(ang * lengths, alpha, scale)
    return jnp.sum(weight * per) / jnp.maximum(jnp.sum(weight), 1.0)


def _relative(T_obj_part: jaxlie.SE3, parts: Int[Array, "q 2"]) -> jaxlie.SE3:
    """T_n⁻¹ T_k of each (k, n) row of `parts`."""
    return jaxlie.SE3(T_obj_part.wxyz_xyz[parts[:, 1]]).inverse() @ jaxlie.SE3(T_obj_part.wxyz_xyz[parts[:, 0]])


def _off_axis(v: Float[Array, "q 3"], axes: Float[Array, "q 3"]) -> Float[Array, "q 3"]:
    """The component of each v orthogonal to its unit axis."""
    return v - jnp.sum(v * axes, -1, keepdims=True) * axes


def revolute_loss(
    T_obj_part: jaxlie.SE3,
    parts: Int[Array, "q 2"],
    axes: Float[Array, "q 3"],
    lengths: Float[Array, " q"],
    weight: Float[Array, " q"],
    alpha: Float[Array, ""] | float,
    scale: Float[Array, ""] | float,
) -> Float[Array, ""]:
    """Hinge axes: part k = parts[i, 0] turns relative to part n = parts[i, 1] only about
    `axes[i]` (a unit vector in n's frame, i.e. the object frame at rest); where the axis passes
    is left to the joint point's ARAP pair (`with_joint_slots`).

    With R_rel = R_n⁻¹ R_k and ω = log(R_rel), the residual is ω's component orthogonal to the
    axis (radians) times `lengths[i]` (metres at the part's radius), through Barron's loss at
    `scale`. Zero at rest, for any rigid motion of the whole object, for any turn about the axis
    and for any translation; weighted mean over the entries."""
    off = _off_axis(_relative(T_obj_part, parts).rotation().log(), axes)
    per = barron_loss(jnp.linalg.norm(off + 1e-12, axis=-1) * lengths, alpha, scale)
    return jnp.sum(weight * per) / jnp.maximum(jnp.sum(weight), 1.0)


def _held_points_in_camera(T_obj_part: jaxlie.SE3, T_cam_obj: jaxlie.SE3, parts: Int[Array, " k"], points: Float[Array, "k 3"]) -> Float[Array, "k 3"]:
    """Each hand's pinched point (`points[k]` in part `parts[k]`'s frame) in the camera frame."""
    return T_cam_obj @ (jaxlie.SE3(T_obj_part.wxyz_xyz[parts]) @ points)


def hand_loss(
    T_obj_part: jaxlie.SE3,
    T_cam_obj: jaxlie.SE3,
    intrinsics,
    parts: Int[Array, " k"],
    points: Float[Array, "k 3"],
    uv: Float[Array, "k 2"],
    weight: Float[Array, " k"],
    alpha: Float[Array, ""] | float,
    scale: Float[Array, ""] | float,
) -> Float[Array, ""]:
    """Hand term: each anchored hand k pinches the point `points[k]` of part `parts[k]` (part
    frame), so that point projects onto the hand's detected pinch point `uv[k]` (pixels of
    `intrinsics`). Barron's loss of the reprojection distance at `scale` pixels, weighted mean
    over the hands (`weight` 0: not detected or not anchored). Only the image position is used:
    a monocular detector's hand depth is not trusted."""
    pc = _held_points_in_camera(T_obj_part, T_cam_obj, parts, points)
    ok = pc[:, 2] > 1e-3  # behind the camera: no pull
    pred, _ = project_points(intrinsics, jnp.where(ok[:, None], pc, jnp.array([0.0, 0.0, 1.0])))
    r = jnp.linalg.norm(pred - uv + 1e-9, axis=-1)
    w = weight * ok
    return jnp.sum(w * barron_loss(r, alpha, scale)) / jnp.maximum(jnp.sum(w), 1.0)


def hand_depth_loss(
    T_obj_part: jaxlie.SE3,
    T_cam_obj: jaxlie.SE3,
    parts: Int[Array, " k"],
    points: Float[Array, "k 3"],
    depth: Float[Array, " k"],
    weight: Float[Array, " k"],
    scale: Float[Array, ""] | float,
) -> Float[Array, ""]:
    """Hand depth term: the held part's surface at each hand k's pinch point (`points[k]` of part
    `parts[k]`, part frame) lies at the depth `depth[k]` (camera z, m) that the mono-depth gives
    the pinch point
    (`Observer.hand_depths`): Cauchy loss of the depth difference at `scale` metres, weighted
    mean over the hands (`weight` 0: unknown depth, not anchored or not seen)."""
    z = _held_points_in_camera(T_obj_part, T_cam_obj, parts, points)[:, 2]
    return jnp.sum(weight * barron_loss(z - depth, 0.0, scale)) / jnp.maximum(jnp.sum(weight), 1.0)


def pose_smoothness(T: jaxlie.SE3, valid: Bool[Array, " t"] | None = None) -> Float[Array, ""]:
    """First-difference smoothness over a T×P pose sequence: Σ ‖Δtranslation‖² + ‖Δrotation‖²
    (rotation as the tangent angle vector, squared), averaged over neighbouring frame pairs."""
    a = jaxlie.SE3(T.wxyz_xyz[:-1])
    b = jaxlie.SE3(T.wxyz_xyz[1:])
    d = (a.inverse() @ b).log()
    per = jnp.sum(d**2, axis=-1).sum(-1)
    if valid is not None:
        per = per * (valid[:-1] & valid[1:])
    return jnp.mean(per)


def support_loss(
    means: Float[Array, "n 3"],
    rest_means: Float[Array, "n 3"],
    plane: Float[Array, "4"],
    scale: Float[Array, ""] | float,
) -> Float[Array, ""]:
    """Support-plane term: no part passes through the table the object rests on. `plane` is
    (n, d) with unit normal n pointing up (object frame). A posed Gaussian centre x costs
    (h / scale)² when it is h = f − n·x > 0 below its floor f = min(d, n·x_rest) (a centre that
    the scan put below the table may not sink further); above it nothing. Mean over the
    Gaussians: zero at rest and for any motion that stays above the table."""
    floor = jnp.minimum(plane[3], rest_means @ plane[:3])
    h = jax.nn.relu(floor - means @ plane[:3])
    return jnp.mean((h / scale) ** 2)
