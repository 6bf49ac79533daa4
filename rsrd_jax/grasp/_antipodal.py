"""Antipodal parallel-jaw grasps on a closed part mesh (Dex-Net style sampling, RSRD-style
augmentation), in JAX.

Grasp frame (what `PartGrasps.T_part_grasp` holds, and what the planner tracks as the TCP
target): origin at the grasp centre (midpoint between the two contacts, shifted along x by the
augmentation), **x = grasp axis** = finger travel axis (from contact 1 to contact 2 for the
unflipped pose), **z = approach axis**: the gripper moves along +z to reach the part (fingertips
point along +z; YuMi's TCP frame has z out of the flange), y = z × x.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from ._mesh import MeshConfig, PartMesh, build_part_mesh


class GraspConfig(eqx.Module):
    """Antipodal grasp sampling and augmentation."""

    num_samples: int = 1000
    """Surface points sampled (area-weighted) as first contacts (RSRD: 1000)."""
    num_grasps: int = 10
    """Base grasps kept, best first by score. 10 as in RSRD's code (it keeps the first 10), so
    that 10 × 2 signs × 8 rolls × 3 shifts = the paper's 480 candidates per part; 20 gives 960."""
    max_width: float = 0.05
    """Largest contact separation in metres (YuMi jaw: 2 × 25 mm = 50 mm; RSRD samples ≤ 40 mm)."""
    min_width: float = 0.002
    """Smallest contact separation in metres (Dex-Net `min_contact_dist` 2.5 mm)."""
    friction_angle_deg: float = 45.0
    """Both contact normals must lie within this angle of the grasp axis (RSRD 45°, i.e.
    friction coefficient 1; Dex-Net atan(0.5) = 26.6°)."""
    axis_jitter: float = 0.0
    """Dex-Net samples the grasp axis inside a cone around the inward normal: deviation
    tan ≤ this value (Dex-Net 0.5). 0 = exactly along the normal, as RSRD."""
    min_separation: float = 0.003
    """Non-maximum suppression: a grasp is dropped when both of its contacts lie within this
    distance (metres) of the contacts of a better kept grasp."""
    antipodal_weight: float = 1.0
    """Score weight of antipodality: mean cosine between the normals and the axis, rescaled so
    that the friction-cone edge is 0 and perfect alignment 1."""
    centre_weight: float = 0.5
    """Score weight of centredness: 1 at the mesh centroid, 0 at the farthest vertex."""
    num_rolls: int = 8
    """Augmentation: distinct rotations about the grasp axis, 2πk/num_rolls."""
    shifts: tuple[float, ...] = (-0.005, 0.0, 0.005)
    """Augmentation: offsets of the grasp centre along the grasp axis (metres; RSRD ±5 mm)."""
    approach_reference: tuple[float, float, float] = (0.0, 0.0, -1.0)
    """Part-frame direction the unrolled approach axis z is taken closest to (default: from
    above, moving down); rolls then cover the other approach directions."""
    ray_batch: int = 256
    """Rays per chunk in the ray–triangle tests (bounds memory to ray_batch × faces)."""
    normal_radius: float = 0.0
    """With a radius > 0 (m), contact normals (the grasp axis and the friction-cone test) are
    the area-weighted mean normal of the faces whose centroids lie within it of the contact's
    face and whose normals lie within 60° of its own (:func:`patch_normals`), not the single
    face's normal: a finger pad (25 × 50 mm on the YuMi) presses on a patch, and single-face
    normals of a decimated alpha shape of Gaussian centres scatter by 10–25°. A grasp axis
    tilted that far from a round part's cross-section turns the part in the pinch until its
    surface lies flat on the pads (studio frog legs, tracked: jaw 75–84° to the leg, legs turned
    16–19° by the close). 0 = single-face normals (RSRD), the default; the planner's
    ``PlanConfig.with_square_grasps`` (off by default, ``PipelineConfig.plan_square_grasps``)
    uses 8 mm with a 15° cone."""


class GraspResult(eqx.Enumeration):
    """Outcome of grasp sampling on one part."""

    success = "at least one antipodal grasp was found"
    no_opposite_surface = "no ray along an inward normal hit the opposite surface (open or degenerate mesh)"
    width_out_of_range = "every opposite surface lies outside [min_width, max_width]: the part does not fit the gripper"
    outside_friction_cone = "no contact pair within the width limits has both normals inside the friction cone"


class PartGrasps(eqx.Module):
    """Augmented grasps of one part, fixed size n = num_grasps × 2 × num_rolls × len(shifts).

    Index order is (base grasp, axis sign, roll, shift), flattened. Rows whose base grasp was not
    found are padding (`valid` False, score -inf).
    """

    T_part_grasp: Float[Array, "n 7"]
    """Grasp (TCP target) poses in the part frame, wxyz_xyz: x = finger travel (grasp) axis,
    z = approach direction (fingertips point along +z), origin at the (shifted) grasp centre."""
    width: Float[Array, " n"]
    """Contact separation, metres."""
    score: Float[Array, " n"]
    """Quality of the base grasp (higher is better; -inf for padding)."""
    valid: Bool[Array, " n"]
    """Row holds a real grasp."""
    base_index: Int[Array, " n"]
    """Index of the base grasp the row was augmented from."""
    contacts: Float[Array, "g 2 3"]
    """Contact points of the base grasps, part frame, metres."""
    base_valid: Bool[Array, " g"]
    """Base grasp found."""
    result: GraspResult
    """Why there are no grasps, or success."""
    num_hit: Int[Array, ""]
    """Samples whose inward ray hit the opposite surface."""
    num_width_ok: Int[Array, ""]
    """... of which the width is within [min_width, max_width]."""
    num_antipodal: Int[Array, ""]
    """... of which both normals are inside the friction cone (candidates before NMS)."""

    @property
    def poses(self) -> jaxlie.SE3:
        return jaxlie.SE3(self.T_part_grasp)


def _ray_triangle(
    origin: Float[Array, "r 3"],
    direction: Float[Array, "r 3"],
    tri: Float[Array, "f 3 3"],
    exclude: Int[Array, " r"],
) -> tuple[Float[Array, " r"], Int[Array, " r"]]:
    """Nearest forward hit of each ray with a triangle; returns (t, face), t = inf on a miss.
    Face `exclude[i]` (the ray's own face) is skipped.

    Plane intersection t = (v0 - o)·n / (d·n) with n = e1 × e2, then barycentrics of the hit
    point w = o + t d - v0 as u = w·(e2 × n)/|n|², v = w·(n × e1)/|n|² (dual basis of e1, e2 in
    the plane), all linear per face.
    """
    v0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    n = jnp.cross(e1, e2)
    nn = jnp.sum(n * n, axis=-1)
    good = nn > 1e-20  # degenerate (padding) faces never hit
    inv_nn = jnp.where(good, 1.0 / jnp.where(good, nn, 1.0), 0.0)[:, None]
    a = jnp.cross(e2, n) * inv_nn
    b = jnp.cross(n, e1) * inv_nn
    denom = direction @ n.T  # r f
    ok = good[None] & (jnp.abs(denom) > 1e-12 * jnp.sqrt(nn)[None])
    num = jnp.sum(v0 * n, axis=-1)[None] - origin @ n.T
    t = num / jnp.where(ok, denom, 1.0)
    # w·a = (o - v0)·a + t d·a
    u = (origin @ a.T - jnp.sum(v0 * a, axis=-1)[None]) + t * (direction @ a.T)
    v = (origin @ b.T - jnp.sum(v0 * b, axis=-1)[None]) + t * (direction @ b.T)
    eps = 1e-6
    hit = ok & (u >= -eps) & (v >= -eps) & (u + v <= 1 + eps) & (t > 1e-7)
    hit &= jnp.arange(tri.shape[0])[None] != exclude[:, None]
    t = jnp.where(hit, t, jnp.inf)
    face = jnp.argmin(t, axis=-1)
    return jnp.min(t, axis=-1), face


def _frames(
    axis: Float[Array, "g 3"], reference: Float[Array, "3"]
) -> Float[Array, "g 3 3"]:
    """Rotation matrices with x = axis and z the unit vector closest to `reference` that is
    orthogonal to x (falling back to part-frame y, then x, when the axis is parallel to it)."""
    def ortho(ref):
        z = ref[None] - jnp.sum(ref[None] * axis, -1, keepdims=True) * axis
        return z, jnp.linalg.norm(z, axis=-1, keepdims=True)

    z, nz = ortho(reference)
    z1, nz1 = ortho(jnp.array([0.0, 1.0, 0.0]))
    z2, nz2 = ortho(jnp.array([1.0, 0.0, 0.0]))
    z = jnp.where(nz > 0.1, z / jnp.maximum(nz, 1e-12), jnp.where(nz1 > 0.1, z1 / jnp.maximum(nz1, 1e-12), z2 / jnp.maximum(nz2, 1e-12)))
    y = jnp.cross(z, axis)
    return jnp.stack([axis, y, z], axis=-1)


def _nms(
    p1: Float[Array, "s 3"], p2: Float[Array, "s 3"], order: Int[Array, " s"], ok: Bool[Array, " s"],
    num_keep: int, min_sep: Float[Array, ""]
) -> Int[Array, " g"]:
    """Greedy non-maximum suppression over candidates in `order`; returns up to num_keep
    candidate indices (-1 padding). Duplicates: both endpoints within min_sep (either pairing)."""
    far = jnp.full((num_keep, 3), jnp.inf)

    def body(i, carry):
        kept, k1, k2, count = carry
        j = order[i]
        a, b = p1[j], p2[j]
        d_same = jnp.maximum(jnp.linalg.norm(k1 - a, axis=-1), jnp.linalg.norm(k2 - b, axis=-1))
        d_swap = jnp.maximum(jnp.linalg.norm(k1 - b, axis=-1), jnp.linalg.norm(k2 - a, axis=-1))
        dup = jnp.any(jnp.minimum(d_same, d_swap) < min_sep)
        take = ok[j] & ~dup & (count < num_keep)
        slot = jnp.minimum(count, num_keep - 1)
        kept = jnp.where(take, kept.at[slot].set(j), kept)
        k1 = jnp.where(take, k1.at[slot].set(a), k1)
        k2 = jnp.where(take, k2.at[slot].set(b), k2)
        return kept, k1, k2, count + take.astype(jnp.int32)

    init = (jnp.full((num_keep,), -1, jnp.int32), far, far, jnp.array(0, jnp.int32))
    kept, *_ = jax.lax.fori_loop(0, order.shape[0], body, init)
    return kept


class _Params(eqx.Module):
    """The float options of GraspConfig as arrays, so that changing them does not recompile."""

    max_width: Float[Array, ""]
    min_width: Float[Array, ""]
    cos_cone: Float[Array, ""]
    min_separation: Float[Array, ""]
    axis_jitter: Float[Array, ""]
    antipodal_weight: Float[Array, ""]
    centre_weight: Float[Array, ""]
    shifts: Float[Array, " s"]
    approach_reference: Float[Array, "3"]

    @staticmethod
    def of(cfg: GraspConfig) -> "_Params":
        f = lambda x: jnp.asarray(x, jnp.float32)
        return _Params(
            f(cfg.max_width), f(cfg.min_width), f(math.cos(math.radians(cfg.friction_angle_deg))),
            f(cfg.min_separation), f(cfg.axis_jitter), f(cfg.antipodal_weight), f(cfg.centre_weight), f(cfg.shifts),
            f(cfg.approach_reference),
        )


def _sample_impl(
    tri: Float[Array, "f 3 3"],
    normal: Float[Array, "f 3"],
    face_weight: Float[Array, " f"],
    centroid: Float[Array, "3"],
    radius: Float[Array, ""],
    key: PRNGKeyArray,
    prm: _Params,
    num_samples: int,
    num_grasps: int,
    num_rolls: int,
    ray_batch: int,
) -> PartGrasps:
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    cross = jnp.cross(e1, e2)
    area = 0.5 * jnp.linalg.norm(cross, axis=-1)  # contact normals: `normal` (patch_normals, host)

    k_face, k_bary, k_cone = jax.random.split(key, 3)
    face = jax.random.choice(k_face, tri.shape[0], (num_samples,), p=area * face_weight / jnp.sum(area * face_weight))
    r = jax.random.uniform(k_bary, (num_samples, 2))
    s = jnp.sqrt(r[:, 0])
    w = jnp.stack([1.0 - s, s * (1.0 - r[:, 1]), s * r[:, 1]], axis=-1)
    p1 = jnp.einsum("sk,skd->sd", w, tri[face])
    n1 = normal[face]
    # Ray along the inward normal, tilted inside the sampling cone (Dex-Net: -normalize(n +
    # r (cos θ t1 + sin θ t2)), r ~ U(0, jitter), θ ~ U(0, 2π)).
    helper = jnp.where(jnp.abs(n1[:, :1]) < 0.9, jnp.array([1.0, 0.0, 0.0]), jnp.array([0.0, 1.0, 0.0]))
    t1 = jnp.cross(n1, helper)
    t1 = t1 / jnp.maximum(jnp.linalg.norm(t1, axis=-1, keepdims=True), 1e-12)
    t2 = jnp.cross(n1, t1)
    rc = jax.random.uniform(k_cone, (num_samples, 2))
    tilt = prm.axis_jitter * rc[:, :1]
    ang = 2.0 * jnp.pi * rc[:, 1:]
    d = -(n1 + tilt * (jnp.cos(ang) * t1 + jnp.sin(ang) * t2))
    d = d / jnp.linalg.norm(d, axis=-1, keepdims=True)

    def cast(args):
        o, dd, ex = args
        return _ray_triangle(o, dd, tri, ex)

    nb = max(1, math.ceil(num_samples / ray_batch))
    pad = nb * ray_batch - num_samples
    chunk = lambda x: jnp.pad(x, [(0, pad)] + [(0, 0)] * (x.ndim - 1)).reshape(nb, ray_batch, *x.shape[1:])
    t, hit_face = jax.lax.map(cast, (chunk(p1), chunk(d), chunk(face.astype(jnp.int32))))
    t, hit_face = t.reshape(-1)[: num_samples], hit_face.reshape(-1)[: num_samples]

    hit = jnp.isfinite(t)
    width = jnp.where(hit, t, 0.0)
    p2 = p1 + width[:, None] * d
    n2 = normal[hit_face]
    # Contact 1 pushes along +d (its inward normal is -n1 = d); contact 2's outward normal
    # should point along +d too. Signed cosines: a ray that leaves through an inward-facing
    # face (bad orientation) is rejected.
    cos1 = jnp.sum(-n1 * d, axis=-1)
    cos2 = jnp.sum(n2 * d, axis=-1)
    width_ok = hit & (width >= prm.min_width) & (width <= prm.max_width)
    cos_cone = prm.cos_cone
    # first contacts beyond `radius` of the centre point are dropped (a no-op without `near`:
    # every surface point lies within the farthest vertex's distance of the centroid)
    within = jnp.linalg.norm(p1 - centroid, axis=-1) <= radius * (1.0 + 1e-4)
    antipodal = width_ok & (cos1 >= cos_cone) & (cos2 >= cos_cone) & within

    mid = 0.5 * (p1 + p2)
    anti = (0.5 * (cos1 + cos2) - cos_cone) / jnp.maximum(1.0 - cos_cone, 1e-9)
    centred = 1.0 - jnp.clip(jnp.linalg.norm(mid - centroid, axis=-1) / radius, 0.0, 1.0)
    score = prm.antipodal_weight * anti + prm.centre_weight * centred
    score = jnp.where(antipodal, score, -jnp.inf)
    order = jnp.argsort(-score)
    kept = _nms(p1, p2, order, antipodal, num_grasps, prm.min_separation)
    base_valid = kept >= 0
    kk = jnp.maximum(kept, 0)

    axis = d[kk]
    R0 = _frames(axis, prm.approach_reference)  # g 3 3
    # Axis sign flip = rotation by π about z (x → -x, y → -y); then rolls about the new x.
    flip = jnp.diag(jnp.array([-1.0, -1.0, 1.0]))
    Rs = jnp.stack([R0, R0 @ flip], axis=1)  # g 2 3 3
    roll = jaxlie.SO3.from_x_radians(2.0 * jnp.pi * jnp.arange(num_rolls) / num_rolls).as_matrix()
    R = Rs[:, :, None] @ roll[None, None]  # g 2 K 3 3
    shifts = prm.shifts
    centre = mid[kk][:, None, None, None, :] + shifts[None, None, None, :, None] * R[:, :, :, None, :, 0]
    g, K, S = num_grasps, num_rolls, shifts.shape[0]
    R_full = jnp.broadcast_to(R[:, :, :, None], (g, 2, K, S, 3, 3))
    pose = jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.from_matrix(R_full), centre)
    n = g * 2 * K * S
    rep = lambda x: jnp.broadcast_to(x[:, None, None, None], (g, 2, K, S)).reshape(n)

    num_hit = jnp.sum(hit)
    num_width = jnp.sum(width_ok)
    num_anti = jnp.sum(antipodal)
    result = GraspResult.where(
        num_hit == 0,
        GraspResult.no_opposite_surface,
        GraspResult.where(
            num_width == 0,
            GraspResult.width_out_of_range,
            GraspResult.where(num_anti == 0, GraspResult.outside_friction_cone, GraspResult.success),
        ),
    )
    return PartGrasps(
        T_part_grasp=pose.wxyz_xyz.reshape(n, 7),
        width=rep(jnp.where(base_valid, width[kk], 0.0)),
        score=rep(jnp.where(base_valid, score[kk], -jnp.inf)),
        valid=rep(base_valid),
        base_index=rep(jnp.arange(g)),
        contacts=jnp.where(base_valid[:, None, None], jnp.stack([p1[kk], p2[kk]], axis=1), 0.0),
        base_valid=base_valid,
        result=result,
        num_hit=num_hit,
        num_width_ok=num_width,
        num_antipodal=num_anti,
    )


# Counts traces (tests check that float options do not retrace).
_traced = eqx.debug.assert_max_traces(_sample_impl, max_traces=None)
_sample = eqx.filter_jit(_traced)


def patch_normals(tri: Float[np.ndarray, "f 3 3"], radius: float) -> Float[np.ndarray, "f 3"]:
    """Unit normal of each face averaged (area-weighted) over the faces whose centroids lie
    within `radius` (m) of its own and whose normals lie within 60° of its own (the same side of
    a thin part; not a perpendicular face across an edge); `radius` 0 gives the faces' own
    normals. Degenerate faces get zero normals."""
    tri = np.asarray(tri, np.float64)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # 2 × area × normal
    norm = np.linalg.norm(cross, axis=-1, keepdims=True)
    unit = np.where(norm > 1e-30, cross / np.maximum(norm, 1e-30), 0.0)
    if radius <= 0:
        return unit
    c = tri.mean(1)
    mean = np.empty_like(cross)
    for i in range(0, len(tri), 2048):  # rows in chunks: bounded memory on unsimplified meshes
        near = np.linalg.norm(c[i : i + 2048, None] - c[None], axis=-1) <= radius
        near &= unit[i : i + 2048] @ unit.T > 0.5
        mean[i : i + 2048] = near.astype(np.float64) @ cross  # area-weighted sums
    n = np.linalg.norm(mean, axis=-1, keepdims=True)
    return np.where(n > 1e-30, mean / np.maximum(n, 1e-30), unit)


def _bucket(n: int) -> int:
    return max(256, 1 << (n - 1).bit_length())


def sample_antipodal_grasps(
    mesh: PartMesh, key: PRNGKeyArray, config: GraspConfig = GraspConfig(),
    near: tuple[Float[np.ndarray, "3"], float] | None = None,
) -> PartGrasps:
    """Antipodal parallel-jaw grasps of one part, augmented to a fixed-size candidate set.

    Dex-Net-style sampling (Mahler et al. 2017) as RSRD uses it: `num_samples` area-weighted
    surface points; from each, a ray along the inward normal to the first opposite surface
    (Möller–Trumbore against every face); a pair is antipodal when the width lies in
    [min_width, max_width] and both outward normals lie within `friction_angle_deg` of the
    axis (contact 1's negated). Candidates are scored (antipodality + centredness), de-duplicated
    greedily (`min_separation`) and the best `num_grasps` kept; each is augmented to
    2 axis signs × `num_rolls` rolls × `len(shifts)` shifts (10 × 2 × 8 × 3 = 480 by default).
    See the module docstring for the grasp frame. Deterministic for a given key.

    No grasp is not an error: `result` says why (e.g. `width_out_of_range`) and every row is
    padding.

    With `near = (point, radius)` the first contacts are sampled only within `radius` plus the
    nearest vertex's distance of `point` (e.g. where the demonstrator's hand held the part, a
    point inside the part or just off its surface), and centredness is measured from `point` (1
    there, 0 at that distance) instead of the mesh centroid.

    Args:
        mesh: closed, outward-oriented part mesh (part frame, metres).
        key: PRNG key.
        config: sampling options (static: changing one recompiles).
        near: optional (point (3,), radius) in the part frame, metres.

    Returns:
        PartGrasps with n = num_grasps × 2 × num_rolls × len(shifts) rows.
    """
    if len(mesh.faces) == 0:
        raise ValueError("mesh: has no faces")
    if config.num_grasps < 1 or config.num_samples < 1 or config.num_rolls < 1 or len(config.shifts) < 1:
        raise ValueError(f"config: counts must be positive, got {config}")
    tri = np.asarray(mesh.vertices, dtype=np.float32)[np.asarray(mesh.faces)]
    n_f = len(tri)
    fb = _bucket(n_f)
    # Degenerate padding faces have zero area: never sampled, never hit.
    tri = np.concatenate([tri, np.zeros((fb - n_f, 3, 3), np.float32)])
    weight = np.zeros(fb, np.float32)
    verts = np.asarray(mesh.vertices, dtype=np.float64)
    if near is None:
        weight[:n_f] = 1.0
        tm = mesh.to_trimesh()
        centroid = np.asarray(tm.center_mass if mesh.watertight and tm.volume > 0 else verts.mean(0))
        radius = max(float(np.linalg.norm(verts - centroid, axis=-1).max()), 1e-9)
    else:
        centroid = np.asarray(near[0], np.float64).reshape(-1)
        if centroid.shape != (3,) or not np.all(np.isfinite(centroid)) or not float(near[1]) > 0:
            raise ValueError(f"near: expected a finite point (3,) and a radius > 0 (m), got {near}")
        dist = np.linalg.norm(tri[:n_f] - centroid, axis=-1).min(1)  # nearest vertex of each face
        radius = float(near[1]) + float(dist.min())  # measured from the surface nearest the point
        weight[:n_f] = dist <= radius
    if not config.normal_radius >= 0:
        raise ValueError(f"config.normal_radius: expected >= 0 (m), got {config.normal_radius}")
    if not 0 < config.friction_angle_deg < 90:  # also refuses NaN
        raise ValueError(f"config.friction_angle_deg: expected degrees in (0, 90), got {config.friction_angle_deg}")
    normal = patch_normals(tri, config.normal_radius).astype(np.float32)
    return _sample(
        jnp.asarray(tri), jnp.asarray(normal), jnp.asarray(weight), jnp.asarray(centroid, jnp.float32), jnp.asarray(radius, jnp.float32), key,
        _Params.of(config), config.num_samples, config.num_grasps, config.num_rolls, config.ray_batch,
    )


def merge_grasps(a: PartGrasps, b: PartGrasps) -> PartGrasps:
    """One candidate set from two samplings of the same part (e.g. the best-scored grasps and a
    spatially spread set): rows of ``b`` follow those of ``a``; a base grasp of ``b`` whose two
    contacts equal those of a base grasp of ``a`` (within 0.1 mm) is turned into padding, so no
    candidate is solved twice. ``result`` is success when either set has a grasp; counts add."""
    ca, cb = np.asarray(a.contacts), np.asarray(b.contacts)
    same = np.abs(cb[:, None] - ca[None]).max(axis=(-2, -1)) <= 1e-4  # (gb, ga)
    dup = (same & np.asarray(a.base_valid)[None]).any(1) & np.asarray(b.base_valid)  # (gb,)
    bi = np.asarray(b.base_index)
    row_dup = dup[bi]
    b_valid = np.asarray(b.valid) & ~row_dup
    b_score = np.where(row_dup, -np.inf, np.asarray(b.score))
    cat = lambda x, y: jnp.concatenate([jnp.asarray(x), jnp.asarray(y)])  # noqa: E731
    return PartGrasps(
        T_part_grasp=cat(a.T_part_grasp, b.T_part_grasp), width=cat(a.width, b.width),
        score=cat(a.score, jnp.asarray(b_score, a.score.dtype)), valid=cat(a.valid, b_valid),
        base_index=cat(a.base_index, jnp.asarray(bi + ca.shape[0], a.base_index.dtype)),
        contacts=cat(a.contacts, b.contacts), base_valid=cat(a.base_valid, np.asarray(b.base_valid) & ~dup),
        result=b.result if bool(b.result == GraspResult.success) and not bool(a.result == GraspResult.success) else a.result,
        num_hit=a.num_hit + b.num_hit, num_width_ok=a.num_width_ok + b.num_width_ok,
        num_antipodal=a.num_antipodal + b.num_antipodal,
    )


def sample_part_grasps(
    part_points: Sequence[Float[np.ndarray, "_n 3"]],
    key: PRNGKeyArray,
    mesh_config: MeshConfig = MeshConfig(),
    grasp_config: GraspConfig = GraspConfig(),
) -> tuple[list[PartMesh], PartGrasps]:
    """Meshes and grasps of every part: `build_part_mesh` then `sample_antipodal_grasps` with
    one key per part (split from `key`).

    Args:
        part_points: P point sets (part frames, metres), e.g. Gaussian centres per part.
        key: PRNG key.
        mesh_config: meshing options.
        grasp_config: grasp options.

    Returns:
        (P meshes, PartGrasps with a leading part axis: T_part_grasp is P×n×7, result is P, ...).
    """
    if len(part_points) == 0:
        raise ValueError("part_points: need at least one part")
    meshes = [build_part_mesh(np.asarray(p), mesh_config) for p in part_points]
    keys = jax.random.split(key, len(meshes))
    grasps = [sample_antipodal_grasps(m, k, grasp_config) for m, k in zip(meshes, keys)]
    return meshes, jax.tree.map(lambda *x: jnp.stack(x), *grasps)
