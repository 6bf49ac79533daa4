"""Collision queries: robot-self, robot-table, robot-object signed distances (JAX) and an MJX
penetration check.

Choice (see robot.md section 3): distances come from our own JAX capsule/box functions over explicit
pair lists (``_distance.py``), because MJX's convex pairs (anything with a box: the table, the
robot body, object boxes) report 1.0 instead of the distance when separated. MJX is used where it
is correct: penetration detection (dist < 0) against the table and object in the full scene
(:func:`mjx_penetration`), including thin slabs that C MuJoCo can miss.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ._constants import LINK_NAMES
from ._distance import capsule_box, capsule_capsule
from ._kinematics import _check_finite, _fk_single
from ._model import YumiModel, check_q


class ObjectGeometry(eqx.Module):
    """An articulated object as primitives in its part frames (build with
    :func:`object_boxes_from_points` / :func:`object_capsules_from_points`, or by hand)."""

    box_part: Int[Array, " boxes"]
    """Part index of each box."""
    box_wxyz_xyz: Float[Array, "boxes 7"]
    """Box pose in its part frame."""
    box_half: Float[Array, "boxes 3"]
    """Box half extents (m)."""
    cap_part: Int[Array, " caps"]
    """Part index of each capsule (sphere = capsule with p0 == p1)."""
    cap_p0: Float[Array, "caps 3"]
    """Capsule axis start in the part frame (m)."""
    cap_p1: Float[Array, "caps 3"]
    """Capsule axis end in the part frame (m)."""
    cap_radius: Float[Array, " caps"]
    """Capsule radius (m)."""
    num_parts: int = eqx.field(static=True)
    """Number of parts P (poses are given per part at query time)."""


def object_boxes_from_points(
    points: Float[Array | np.ndarray, "n 3"], part_ids: Int[Array | np.ndarray, " n"],
    num_parts: int, pad: float = 0.0, min_half: float = 0.002,
) -> ObjectGeometry:
    """One oriented bounding box per part from its points (host-side, numpy).

    The box axes are the principal axes of the part's points (PCA); extents cover all points,
    plus ``pad`` (m) on every side, at least ``min_half``. Points are in each part's own frame.

    Args:
        points: (n, 3) points (m), e.g. Gaussian centres of the object in part frames.
        part_ids: (n,) part index in [0, num_parts) of each point.
        num_parts: P.
        pad: margin added to every half extent (m).
        min_half: smallest half extent (m), so flat parts keep a thickness.

    Returns:
        :class:`ObjectGeometry` with P boxes and no capsules.

    Raises:
        ValueError: on mismatched shapes or a part without points.
    """
    pts = np.asarray(points, float)
    ids = np.asarray(part_ids)
    if pts.ndim != 2 or pts.shape[1] != 3 or ids.shape != (pts.shape[0],):
        raise ValueError(f"points must be (n, 3) and part_ids (n,); got {pts.shape}, {ids.shape}")
    poses, halves = [], []
    for k in range(num_parts):
        x = pts[ids == k]
        if len(x) == 0:
            raise ValueError(f"part {k} has no points")
        c = x.mean(0)
        _, _, vt = np.linalg.svd(x - c, full_matrices=True)
        R = vt.T
        if np.linalg.det(R) < 0:
            R[:, 2] *= -1
        loc = (x - c) @ R
        lo, hi = loc.min(0), loc.max(0)
        centre = c + R @ ((lo + hi) / 2)
        halves.append(np.maximum((hi - lo) / 2 + pad, min_half))
        poses.append(np.asarray(jaxlie.SE3.from_rotation_and_translation(
            jaxlie.SO3.from_matrix(jnp.asarray(R, jnp.float32)), jnp.asarray(centre, jnp.float32)
        ).wxyz_xyz))
    return ObjectGeometry(
        box_part=jnp.arange(num_parts, dtype=jnp.int32),
        box_wxyz_xyz=jnp.asarray(np.stack(poses), jnp.float32),
        box_half=jnp.asarray(np.stack(halves), jnp.float32),
        cap_part=jnp.zeros((0,), jnp.int32), cap_p0=jnp.zeros((0, 3)), cap_p1=jnp.zeros((0, 3)),
        cap_radius=jnp.zeros((0,)), num_parts=num_parts,
    )


def object_capsules_from_points(
    points: Float[Array | np.ndarray, "n 3"], part_ids: Int[Array | np.ndarray, " n"],
    num_parts: int, pad: float = 0.0,
) -> ObjectGeometry:
    """One capsule per part from its points (host-side): axis = principal axis through the mean,
    radius = largest distance of a point from the axis segment (+ ``pad``), so it covers all points.
    """
    pts = np.asarray(points, float)
    ids = np.asarray(part_ids)
    if pts.ndim != 2 or pts.shape[1] != 3 or ids.shape != (pts.shape[0],):
        raise ValueError(f"points must be (n, 3) and part_ids (n,); got {pts.shape}, {ids.shape}")
    p0s, p1s, rs = [], [], []
    for k in range(num_parts):
        x = pts[ids == k]
        if len(x) == 0:
            raise ValueError(f"part {k} has no points")
        c = x.mean(0)
        _, _, vt = np.linalg.svd(x - c)
        ax = vt[0]
        t = (x - c) @ ax
        radial = np.linalg.norm((x - c) - np.outer(t, ax), axis=1)
        r = radial.max()
        # Shrink the axis so the round caps do not over-cover the ends more than needed.
        lo, hi = t.min() + min(r, (t.max() - t.min()) / 2), t.max() - min(r, (t.max() - t.min()) / 2)
        a, b = c + lo * ax, c + hi * ax
        seg = b - a
        tt = np.clip(((x - a) @ seg) / max(seg @ seg, 1e-12), 0, 1)
        r = np.linalg.norm(x - (a + tt[:, None] * seg), axis=1).max() + pad
        p0s.append(a), p1s.append(b), rs.append(max(r, 1e-3))
    return ObjectGeometry(
        box_part=jnp.zeros((0,), jnp.int32), box_wxyz_xyz=jnp.zeros((0, 7)),
        box_half=jnp.zeros((0, 3)), cap_part=jnp.arange(num_parts, dtype=jnp.int32),
        cap_p0=jnp.asarray(np.stack(p0s), jnp.float32), cap_p1=jnp.asarray(np.stack(p1s), jnp.float32),
        cap_radius=jnp.asarray(rs, jnp.float32), num_parts=num_parts,
    )


class CollisionResult(eqx.Module):
    """Signed distances (m; negative = penetration) and flags for a batch of configurations."""

    self_distance: Float[Array, "*batch self_pairs"]
    """Per self-collision pair (capsule-capsule pairs, then capsule-body-box pairs)."""
    table_distance: Float[Array, "*batch caps"]
    """Per robot capsule against the table box."""
    object_distance: Float[Array, "*batch caps obj"]
    """Per robot capsule against each object primitive (object boxes, then object capsules)."""
    min_self: Float[Array, "*batch"]
    """Smallest self distance."""
    min_table: Float[Array, "*batch"]
    """Smallest robot-table distance."""
    min_object: Float[Array, "*batch"]
    """Smallest robot-object distance (without the hand if ``hand_touches_object``; +inf if no object)."""
    in_collision: Bool[Array, "*batch"]
    """Any minimum below the margin."""
    self_collision: Bool[Array, "*batch"]
    """min_self < margin."""
    table_collision: Bool[Array, "*batch"]
    """min_table < margin."""
    object_collision: Bool[Array, "*batch"]
    """min_object < margin."""


def _distances_single(kin, geom, obj, q, T_world_part):
    """All signed distances for one configuration: (self, table (caps,), object (caps, K+M)).

    Every capsule-box pair (self vs body box, table, object boxes) goes through one batched
    ``capsule_box`` call and every capsule-capsule pair (self, object capsules) through one
    ``capsule_capsule`` call, over index lists fixed at trace time.
    """
    R, p, _, _ = _fk_single(kin, q)
    Rc, pc = R[geom.cap_link], p[geom.cap_link]
    p0 = pc + jnp.einsum("nij,nj->ni", Rc, geom.cap_p0)
    p1 = pc + jnp.einsum("nij,nj->ni", Rc, geom.cap_p1)
    r = geom.cap_radius
    n, nb = p0.shape[0], geom.box_half.shape[0]
    nob = 0 if obj is None else obj.box_part.shape[0]
    noc = 0 if obj is None else obj.cap_part.shape[0]

    # Boxes in the world: robot boxes, the table, object boxes.
    Tbl = jaxlie.SE3(geom.box_wxyz_xyz)
    Rb = [jnp.einsum("nij,njk->nik", R[geom.box_link], Tbl.rotation().as_matrix())]
    cb = [p[geom.box_link] + jnp.einsum("nij,nj->ni", R[geom.box_link], Tbl.translation())]
    hb = [geom.box_half]
    Tt = jaxlie.SE3(geom.table_wxyz_xyz)
    Rb.append(Tt.rotation().as_matrix()[None]), cb.append(Tt.translation()[None])
    hb.append(geom.table_half[None])
    if nob:
        Tob = jaxlie.SE3(T_world_part[obj.box_part]) @ jaxlie.SE3(obj.box_wxyz_xyz)
        Rb.append(Tob.rotation().as_matrix()), cb.append(Tob.translation()), hb.append(obj.box_half)
    Rb, cb, hb = (jnp.concatenate(x) for x in (Rb, cb, hb))
    ncb = geom.self_cb.shape[0]
    cap_idx = jnp.concatenate([geom.self_cb[:, 0], jnp.asarray(np.repeat(np.arange(n), 1 + nob))])
    box_idx = jnp.concatenate([geom.self_cb[:, 1],
                               jnp.asarray(np.tile(np.arange(nb, nb + 1 + nob), n))])
    d_b = capsule_box(p0[cap_idx], p1[cap_idx], r[cap_idx], Rb[box_idx], cb[box_idx], hb[box_idx])
    d_cb = d_b[:ncb]
    d_env = d_b[ncb:].reshape(n, 1 + nob)
    d_table, d_obox = d_env[:, 0], d_env[:, 1:]

    # Capsules: robot then object capsules.
    if noc:
        Toc = jaxlie.SE3(T_world_part[obj.cap_part])
        P0 = jnp.concatenate([p0, Toc @ obj.cap_p0])
        P1 = jnp.concatenate([p1, Toc @ obj.cap_p1])
        RR = jnp.concatenate([r, obj.cap_radius])
    else:
        P0, P1, RR = p0, p1, r
    i = jnp.concatenate([geom.self_cc[:, 0], jnp.asarray(np.repeat(np.arange(n), noc))])
    j = jnp.concatenate([geom.self_cc[:, 1], jnp.asarray(np.tile(np.arange(n, n + noc), n))])
    d_c = jax.vmap(capsule_capsule)(P0[i], P1[i], RR[i], P0[j], P1[j], RR[j])
    ncc = geom.self_cc.shape[0]
    d_cc, d_ocap = d_c[:ncc], d_c[ncc:].reshape(n, noc)
    return jnp.concatenate([d_cc, d_cb]), d_table, jnp.concatenate([d_obox, d_ocap], axis=1)


@eqx.filter_jit
def _collide_jit(kin, geom, obj, q, T_world_part, object_mask, margin, check_finite):
    """Flat batch: q (N, 16), T_world_part (N, P, 7) or None."""
    if check_finite:
        q = _check_finite(q)
    if T_world_part is None:
        d_self, d_table, d_obj = jax.vmap(lambda x: _distances_single(kin, geom, obj, x, None))(q)
    else:
        d_self, d_table, d_obj = jax.vmap(
            lambda x, t: _distances_single(kin, geom, obj, x, t))(q, T_world_part)
    inf = jnp.asarray(jnp.inf, d_self.dtype)
    min_self = jnp.min(d_self, axis=-1, initial=inf)
    min_table = jnp.min(d_table, axis=-1, initial=inf)
    min_obj = jnp.min(jnp.where(object_mask[:, None], d_obj, inf), axis=(-2, -1), initial=inf)
    sc, tc, oc = min_self < margin, min_table < margin, min_obj < margin
    return CollisionResult(
        self_distance=d_self, table_distance=d_table, object_distance=d_obj,
        min_self=min_self, min_table=min_table, min_object=min_obj,
        in_collision=sc | tc | oc, self_collision=sc, table_collision=tc, object_collision=oc)


def collision_distances(
    model: YumiModel,
    q: Float[Array | np.ndarray, "*batch 16"],
    obj: ObjectGeometry | None = None,
    T_world_part: Float[Array | np.ndarray, "*#pbatch parts 7"] | None = None,
    margin: float = 0.0,
    hand_touches_object: bool = False,
    check_finite: bool = True,
) -> CollisionResult:
    """Minimum signed distances robot-self, robot-table and robot-object for a batch of
    configurations (e.g. trajectories x waypoints: q of shape (n_traj, T, 16)).

    Self pairs follow SELF_COLLISION_IGNORE; robot geometry is the MJCF ``c_*`` capsules/spheres
    and the body box. Collisions are values, never exceptions.

    Args:
        model: from :func:`load_yumi`.
        q: joints in JOINT_NAMES order, shape (*batch, 16).
        obj: object primitives in part frames, or None.
        T_world_part: part poses (wxyz_xyz, world frame), shape (*batch, P, 7) or broadcastable
            to it (e.g. (P, 7) for a static object). Required when ``obj`` is given.
        margin: a minimum below this counts as a collision (m).
        hand_touches_object: if True the gripper base and finger capsules are left out of
            ``min_object`` (for grasping); ``object_distance`` always has every capsule.
        check_finite: raise on NaN/inf in q (``eqx.error_if``).

    Returns:
        :class:`CollisionResult` with leading shape *batch.

    Raises:
        ValueError: bad q shape, or an object without part poses of the right size.
    """
    check_q(q)
    q = jnp.asarray(q)
    if obj is not None:
        if T_world_part is None:
            raise ValueError("T_world_part (*batch, P, 7) is required when obj is given")
        T_world_part = jnp.asarray(T_world_part, q.dtype)
        if T_world_part.ndim < 2 or T_world_part.shape[-2:] != (obj.num_parts, 7):
            raise ValueError(
                f"T_world_part must have shape (*batch, {obj.num_parts}, 7); got {T_world_part.shape}")
        try:
            np.broadcast_shapes(T_world_part.shape[:-2], q.shape[:-1])
        except ValueError as e:
            raise ValueError(f"T_world_part batch {T_world_part.shape[:-2]} does not broadcast "
                             f"to q batch {q.shape[:-1]}") from e
    else:
        T_world_part = None
    batch = q.shape[:-1]
    qf = q.reshape(-1, q.shape[-1])
    if T_world_part is not None:  # broadcast on the host, flatten: one compile per batch size
        T_world_part = jnp.broadcast_to(T_world_part, (*batch, *T_world_part.shape[-2:]))
        T_world_part = T_world_part.reshape(-1, *T_world_part.shape[-2:])
    mask = ~model.geom.hand_mask if hand_touches_object else jnp.ones_like(model.geom.hand_mask)
    res = _collide_jit(model.kin, model.geom, obj, qf, T_world_part, mask,
                       jnp.asarray(margin, q.dtype), check_finite)
    return jax.tree.map(lambda x: x.reshape(*batch, *x.shape[1:]), res)


class MJXContacts(eqx.Module):
    """MJX contacts of the scene (robot-table, robot-object, object-table) at a batch of
    configurations: one slot per candidate geom pair; separated convex pairs read 1.0."""

    dist: Float[Array, "*batch slots"]
    """Contact distance per slot (m; < 0 = penetration; 1.0 or > 0 when separated)."""
    geom: Int[Array, "slots 2"]
    """MuJoCo geom ids of each slot (fixed topology)."""
    penetrating: Bool[Array, "*batch"]
    """Any robot slot with dist < 0."""


def mjx_penetration(model: YumiModel, q: Float[Array | np.ndarray, "*batch 16"]) -> MJXContacts:
    """Penetration check with MJX (``mjx.kinematics`` + ``mjx.collision``) on the scene model.

    Only the sign is meaningful for pairs involving a box (table, object boxes, finger pads):
    MJX reports 1.0 for separated convex pairs. Robot-robot pairs are not candidates in the scene
    (robot contype 2 / conaffinity 1); use :func:`collision_distances` for self-collision.

    Args:
        model: from :func:`load_yumi` (the object, if any, at its qpos0 pose in the spec).
        q: joints in JOINT_NAMES order, shape (*batch, 16).

    Returns:
        :class:`MJXContacts`.
    """
    check_q(q)
    q = jnp.asarray(q)
    batch = q.shape[:-1]
    res = _mjx_jit(model.mjx_model, q.reshape(-1, q.shape[-1]), model.qpos_adr,
                   model.mimic_qpos_adr, _robot_geom_mask(model))
    return MJXContacts(dist=res.dist.reshape(*batch, -1), geom=res.geom,
                       penetrating=res.penetrating.reshape(batch))


def _robot_geom_mask(model: YumiModel) -> tuple[bool, ...]:
    m = model.mj_model
    robot_bodies = {m.body(n).id for n in LINK_NAMES}
    return tuple(bool(int(m.geom_bodyid[g]) in robot_bodies) for g in range(m.ngeom))


@functools.partial(jax.jit, static_argnums=(2, 3, 4))
def _mjx_jit(mjx_model, q, qpos_adr, mimic_adr, robot_geom):
    from mujoco import mjx

    q = _check_finite(q)
    d0 = mjx.make_data(mjx_model)

    def one(x):
        qpos = d0.qpos.at[jnp.array(qpos_adr)].set(x.astype(d0.qpos.dtype))
        qpos = qpos.at[jnp.array(mimic_adr)].set(x[14:16].astype(d0.qpos.dtype))
        d = mjx.collision(mjx_model, mjx.kinematics(mjx_model, d0.replace(qpos=qpos)))
        c = d._impl.contact
        return c.dist, c.geom

    dist, geom = jax.vmap(one)(q)
    geom = geom[0]
    rg = jnp.asarray(robot_geom)
    is_robot = rg[geom[:, 0]] | rg[geom[:, 1]]
    pen = jnp.any((dist < 0) & is_robot, axis=-1)
    return MJXContacts(dist=dist, geom=geom, penetrating=pen)
