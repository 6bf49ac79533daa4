"""Signed distances between primitives in JAX (sphere = capsule with equal end points).

Why not MJX for distances: MJX-JAX's convex (box) collision functions return a constant 1.0 for
separated pairs (mujoco#3131), so a smooth distance for an optimiser needs its own functions. These
are exact for capsule-capsule (closest points of two segments, Ericson, *Real-Time Collision
Detection* 5.1.9) and capsule-box (minimum of the box SDF along the capsule axis; the SDF of a
convex set is convex and piecewise simple along a segment, so its minimiser is one of a few
closed-form candidates, see ``_segment_box_param``). Closest-point
parameters are held constant under differentiation (envelope theorem), so gradients are the
gradients of the distance itself.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

_EPS = 1e-9


def _safe_norm(x: Array) -> Array:
    sq = jnp.sum(x * x, axis=-1)
    return jnp.sqrt(jnp.maximum(sq, 1e-12))


def segment_segment_params(p1: Array, q1: Array, p2: Array, q2: Array) -> tuple[Array, Array]:
    """Parameters (s, t) in [0, 1] of the closest points p1 + s (q1 - p1), p2 + t (q2 - p2)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f = d1 @ d1, d2 @ d2, d2 @ r
    c, b = d1 @ r, d1 @ d2
    a_ok, e_ok = a > _EPS, e > _EPS
    denom = a * e - b * b
    s_gen = jnp.where(denom > _EPS * jnp.maximum(a * e, _EPS),
                      jnp.clip((b * f - c * e) / jnp.where(denom > 0, denom, 1.0), 0.0, 1.0), 0.0)
    t_gen = (b * s_gen + f) / jnp.where(e_ok, e, 1.0)
    s_gen = jnp.where(t_gen < 0.0, jnp.clip(-c / jnp.where(a_ok, a, 1.0), 0.0, 1.0),
                      jnp.where(t_gen > 1.0, jnp.clip((b - c) / jnp.where(a_ok, a, 1.0), 0.0, 1.0),
                                s_gen))
    t_gen = jnp.clip(t_gen, 0.0, 1.0)
    # Degenerate segments (spheres).
    s_e0 = jnp.clip(-c / jnp.where(a_ok, a, 1.0), 0.0, 1.0)  # second is a point
    t_a0 = jnp.clip(f / jnp.where(e_ok, e, 1.0), 0.0, 1.0)  # first is a point
    s = jnp.where(a_ok, jnp.where(e_ok, s_gen, s_e0), 0.0)
    t = jnp.where(a_ok, jnp.where(e_ok, t_gen, 0.0), jnp.where(e_ok, t_a0, 0.0))
    return s, t


def capsule_capsule(
    p1: Float[Array, "3"], q1: Float[Array, "3"], r1: Float[Array, ""],
    p2: Float[Array, "3"], q2: Float[Array, "3"], r2: Float[Array, ""],
) -> Float[Array, ""]:
    """Signed distance between two capsules (axis end points, radii; m). Negative = overlap."""
    s, t = jax.lax.stop_gradient(segment_segment_params(p1, q1, p2, q2))
    c1 = p1 + s * (q1 - p1)
    c2 = p2 + t * (q2 - p2)
    return _safe_norm(c1 - c2) - r1 - r2


def box_sdf(x: Float[Array, "*n 3"], half: Float[Array, "*#n 3"]) -> Float[Array, "*n"]:
    """Signed distance from points in the box frame to a centred box with half extents ``half``."""
    d = jnp.abs(x) - half
    outside = _safe_norm(jnp.maximum(d, 0.0))
    outside = jnp.where(jnp.all(d <= 0.0, axis=-1), 0.0, outside)
    inside = jnp.minimum(jnp.max(d, axis=-1), 0.0)
    return outside + inside


def _segment_box_param(a: Array, d: Array, half: Array) -> Array:
    """Parameter t in [0, 1] minimising the box SDF along x(t) = a + t d (box frame), exactly.

    sdf(x(t)) is convex in t. Where it is >= 0 its square is piecewise quadratic,
    sum_i max(|a_i + t d_i| - h_i, 0)^2, with pieces delimited by the kinks t = (+-h_i - a_i) / d_i,
    so its minimiser is an end point, a kink or the stationary point of one quadratic piece: all
    2 + 9 + 7 candidates are evaluated and the best kept (no iterations, no sort). This is exact
    whenever the axis stays outside the box. If the axis enters the box, an interval between kinks
    lies inside and its candidate (the midpoint) has a negative SDF, so the result is negative but
    only an upper bound of the deepest point (exact depth would need the crossings of the six
    linear pieces +-(a_i + t d_i) - h_i as candidates too). Coordinates are kept as separate arrays
    with candidates on a trailing axis, so XLA sees long vectors and few ops.
    """
    A = [a[..., i, None] for i in range(3)]
    D = [d[..., i, None] for i in range(3)]
    H = [half[..., i, None] for i in range(3)]
    Ac, Dc, Hc = (jnp.concatenate(x, axis=-1) for x in (A, D, H))  # (*b, 3)
    ok = jnp.abs(Dc) > 1e-12
    Ds = jnp.where(ok, Dc, 1.0)
    kinks = jnp.concatenate([(Hc - Ac) / Ds, (-Hc - Ac) / Ds, -Ac / Ds], axis=-1)
    kinks = jnp.where(jnp.concatenate([ok, ok, ok], axis=-1), kinks, 0.0)  # (*b, 9)
    # Quadratic pieces: intervals [b, next bound above b] between 0, 1 and the six kinks.
    zero = jnp.zeros_like(A[0])
    lo = jnp.concatenate([zero, jnp.clip(kinks[..., :6], 0.0, 1.0)], axis=-1)  # (*b, 7)
    bounds = jnp.concatenate([lo, zero + 1.0], axis=-1)  # (*b, 8)
    above = bounds[..., None, :] > lo[..., :, None]
    hi = jnp.min(jnp.where(above, bounds[..., None, :], 1.0), axis=-1)
    mid = 0.5 * (lo + hi)
    num, dsq = zero, zero
    for i in range(3):
        x = A[i] + mid * D[i]
        act = jnp.abs(x) > H[i]
        num = num - jnp.where(act, D[i] * (A[i] - jnp.sign(x) * H[i]), 0.0)
        dsq = dsq + jnp.where(act, D[i] * D[i], 0.0)
    okq = dsq > 1e-12
    stat = jnp.where(okq, jnp.clip(num / jnp.where(okq, dsq, 1.0), lo, hi), mid)
    cand = jnp.clip(jnp.concatenate([zero, zero + 1.0, kinks, stat], axis=-1), 0.0, 1.0)
    ex = [jnp.abs(A[i] + cand * D[i]) - H[i] for i in range(3)]
    # Ordering key of the SDF: squared distance outside, the (negative) max excess inside.
    inner = jnp.maximum(jnp.maximum(ex[0], ex[1]), ex[2])
    out = jnp.where(inner > 0.0, sum(jnp.maximum(e, 0.0) ** 2 for e in ex), inner)
    return jnp.take_along_axis(cand, jnp.argmin(out, axis=-1)[..., None], axis=-1)[..., 0]


def capsule_box(
    p: Float[Array, "*b 3"], q: Float[Array, "*b 3"], r: Float[Array, "*b"],
    R_world_box: Float[Array, "*b 3 3"], c_box: Float[Array, "*b 3"], half: Float[Array, "*b 3"],
) -> Float[Array, "*b"]:
    """Signed distance between capsules (p, q, r) and oriented boxes (rotation, centre, half
    extents), all in the world frame, batched over leading axes: min over the capsule axis of the
    box SDF minus r. Exact while the capsule axis is outside the box (any separation, and overlaps
    up to the radius); once the axis enters the box the value is negative but a bound, not the exact
    depth (a penetration measure, not MuJoCo's contact depth)."""
    a = jnp.einsum("...j,...jk->...k", p - c_box, R_world_box)
    b = jnp.einsum("...j,...jk->...k", q - c_box, R_world_box)
    t = jax.lax.stop_gradient(_segment_box_param(a, b - a, half))
    return box_sdf(a + t[..., None] * (b - a), half) - r
