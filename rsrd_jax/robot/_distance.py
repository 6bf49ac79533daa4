"""Signed distances between primitives in JAX (sphere = capsule with equal end points).

Why not MJX for distances: MJX-JAX's convex (box) collision functions return a constant 1.0 for
separated pairs (mujoco#3131), so a smooth distance for an optimiser needs its own functions. These
are exact for capsule-capsule (closest points of two segments, Ericson, *Real-Time Collision
Detection* 5.1.9) and capsule-box (minimum of the box SDF along the capsule axis; the SDF of a
convex set is convex, so a golden-section search on the segment parameter finds it). Closest-point
parameters are held constant under differentiation (envelope theorem), so gradients are the
gradients of the distance itself.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

_EPS = 1e-9
_GOLDEN_ITERS = 28
_INV_PHI = 0.6180339887498949


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


def box_sdf(x: Float[Array, "*n 3"], half: Float[Array, "3"]) -> Float[Array, "*n"]:
    """Signed distance from points in the box frame to a centred box with half extents ``half``."""
    d = jnp.abs(x) - half
    outside = _safe_norm(jnp.maximum(d, 0.0))
    outside = jnp.where(jnp.all(d <= 0.0, axis=-1), 0.0, outside)
    inside = jnp.minimum(jnp.max(d, axis=-1), 0.0)
    return outside + inside


def capsule_box(
    p: Float[Array, "3"], q: Float[Array, "3"], r: Float[Array, ""],
    R_world_box: Float[Array, "3 3"], c_box: Float[Array, "3"], half: Float[Array, "3"],
) -> Float[Array, ""]:
    """Signed distance between a capsule (p, q, r) and an oriented box (rotation, centre, half
    extents), all in the world frame: min over the axis of the box SDF minus r. Exact when
    separated; when overlapping it is the depth of the deepest axis point plus r (a penetration
    measure, not MuJoCo's contact depth)."""
    a = (p - c_box) @ R_world_box
    b = (q - c_box) @ R_world_box

    def f(t):
        return box_sdf(a + t * (b - a), half)

    def body(_, lohi):
        lo, hi = lohi
        m1 = hi - _INV_PHI * (hi - lo)
        m2 = lo + _INV_PHI * (hi - lo)
        left = f(m1) <= f(m2)
        return jnp.where(left, lo, m1), jnp.where(left, m2, hi)

    lo, hi = jax.lax.fori_loop(0, _GOLDEN_ITERS, body, (jnp.zeros(()), jnp.ones(())))
    t = jax.lax.stop_gradient(0.5 * (lo + hi))
    # The ends are checked too: golden search on a flat (parallel) stretch can stop mid-way.
    t = jax.lax.stop_gradient(jnp.where(f(0.0) < f(t), 0.0, jnp.where(f(1.0) < f(t), 1.0, t)))
    return f(t) - r
