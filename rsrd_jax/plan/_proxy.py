"""Collision proxies for planning: signed-distance grids of the object's parts and the robot as
capsules sampled along their axes.

Why grids and not primitives. A part is only known by points on its surface (Gaussian centres,
or a studio scan's surface samples). Boxes or capsules fitted to clusters of those points cover
empty space next to the part, and a gripper holding part k sits millimetres from the other
parts, so every such proxy reports phantom collisions. Here part k is the union of balls of
radius ``r_s`` around its points, closed and filled: on a regular grid in the part frame the
distance to the nearest point minus ``r_s`` is stored, and cells that the outside cannot reach
(6-connected flood fill from the grid boundary through cells farther than ``r_close`` from every
point) are the interior, with negative values. Values between grid nodes are trilinear, and a
query outside the grid adds its distance to the grid (the grid extends ``margin`` beyond the
points, so outside it nothing collides).

The robot side is a list of capsules: the MJCF link capsules, except that each finger capsule
(which over-covers the finger by ~1 cm towards the jaw, cuRobo's spheres) is replaced by four
thin capsules covering the finger's contact pad box (1 mm over-cover), the geometry the simulator grasps with.
The distance of a capsule to a part is the minimum of the grid distance over points spaced at
most ``sample_spacing`` along its axis, minus its radius (the grid distance is 1-Lipschitz, so
the error is below half the spacing, and far smaller near smooth surfaces).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ..robot import LINK_NAMES, YumiModel, capsule_box, forward_kinematics


class PartSDF(eqx.Module):
    """Signed-distance grids of P parts (m; negative inside), each in its own part frame.

    All parts share one grid shape (the largest needed) and spacing; each has its own origin."""

    values: Float[Array, "parts nx ny nz"]
    """Signed distance at grid nodes (m)."""
    origin: Float[Array, "parts 3"]
    """Part-frame position of node (0, 0, 0) (m)."""
    spacing: Float[Array, ""]
    """Node spacing (m)."""
    radius: Float[Array, " parts"]
    """Ball radius r_s around the points that the grid measures from (m)."""


def part_sdf(
    part_points: list[np.ndarray] | tuple[np.ndarray, ...],
    spacing: float = 0.004,
    margin: float = 0.04,
    radius: float | None = None,
    max_nodes: int = 2_000_000,
) -> PartSDF:
    """Builds the signed-distance grids of the parts from their points (host, numpy + scipy).

    Args:
        part_points: P arrays (n_k, 3) of surface points in the part frames (m).
        spacing: grid node spacing (m); coarsened if the grids would exceed ``max_nodes`` nodes.
        margin: the grid extends this far beyond each part's points (m).
        radius: ball radius r_s around every point (m); None = half the median nearest-neighbour
            spacing (at least 0.5 mm): about the mean distance from a surface location to its
            nearest sample. Gaps of the sampling are closed separately (``r_close``, 2.5 × the
            99th percentile spacing) when labelling the interior.
        max_nodes: cap on the total number of grid nodes.

    Returns:
        :class:`PartSDF`.

    Raises:
        ValueError: on an empty part or points that are not (n, 3).
    """
    from scipy import ndimage
    from scipy.spatial import cKDTree

    pts = []
    for k, p in enumerate(part_points):
        p = np.asarray(p, float)
        if p.ndim != 2 or p.shape[1] != 3 or len(p) == 0:
            raise ValueError(f"part_points[{k}]: expected (n ≥ 1, 3) points, got {p.shape}")
        pts.append(p)
    P = len(pts)
    lo = np.stack([p.min(0) for p in pts]) - margin
    ext = np.stack([p.max(0) for p in pts]) + margin - lo
    h = float(spacing)
    while True:
        shape = np.ceil(ext.max(0) / h).astype(int) + 1
        if P * int(np.prod(shape)) <= max_nodes:
            break
        h *= 1.25
    axes = [np.arange(n) * h for n in shape]
    rel = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    values, radii = [], []
    for k, p in enumerate(pts):
        tree = cKDTree(p)
        nn = tree.query(p, k=2)[0][:, 1] if len(p) > 1 else np.zeros(1)
        if radius is None:
            r_s = max(0.5 * float(np.median(nn)), 0.0005)
        else:
            r_s = float(radius)
        r_close = max(2.5 * float(np.percentile(nn, 99)), 2.0 * r_s, 1.5 * h)
        d = tree.query(rel + lo[k], workers=-1)[0].reshape(shape)
        free = d > r_close
        lab, _ = ndimage.label(free)
        border = np.unique(np.concatenate([lab[[0, -1]].ravel(), lab[:, [0, -1]].ravel(), lab[:, :, [0, -1]].ravel()]))
        outside = np.isin(lab, border[border > 0])
        # Give the band r_s < d <= r_close back to the outside where it lies next to it: a cell at
        # distance d from the points, outside, has free space about r_close - d away; a cell at
        # depth z under a gap of the sampled surface is about z + r_close away from it.
        e_out = ndimage.distance_transform_edt(~outside) * h
        outside |= (d > r_s) & (e_out <= (r_close - d) + 1.5 * h)
        values.append(np.where(outside, d - r_s, -np.abs(d - r_s)))
        radii.append(r_s)
    return PartSDF(values=jnp.asarray(np.stack(values), jnp.float32), origin=jnp.asarray(lo, jnp.float32),
                   spacing=jnp.asarray(h, jnp.float32), radius=jnp.asarray(radii, jnp.float32))


def sdf_distance(sdf: PartSDF, part: Int[Array, "*n"], x: Float[Array, "*n 3"]) -> Float[Array, "*n"]:
    """Signed distance of points ``x`` (in the frame of part ``part``) to that part (m):
    trilinear inside the grid, plus the distance to the grid outside it."""
    shape = jnp.asarray(sdf.values.shape[1:])
    g = (x - sdf.origin[part]) / sdf.spacing
    gc = jnp.clip(g, 0.0, (shape - 1).astype(g.dtype))
    out = jnp.linalg.norm(g - gc, axis=-1) * sdf.spacing
    i0 = jnp.clip(jnp.floor(gc).astype(jnp.int32), 0, shape - 2)
    f = gc - i0
    flat = sdf.values.reshape(-1)
    nx, ny, nz = sdf.values.shape[1:]
    base = ((part * nx + i0[..., 0]) * ny + i0[..., 1]) * nz + i0[..., 2]
    v = 0.0
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                w = ((f[..., 0] if dx else 1 - f[..., 0]) * (f[..., 1] if dy else 1 - f[..., 1])
                     * (f[..., 2] if dz else 1 - f[..., 2]))
                v = v + w * flat[base + (dx * ny + dy) * nz + dz]
    return v + out


class RobotProxy(eqx.Module):
    """The robot as capsules in link frames for robot-object and robot-table checks, with the
    sample points along their axes (host-fixed topology)."""

    link: Int[Array, " caps"]
    """Link index (LINK_NAMES order) of each capsule."""
    p0: Float[Array, "caps 3"]
    """Axis start in the link frame (m)."""
    p1: Float[Array, "caps 3"]
    """Axis end in the link frame (m)."""
    radius: Float[Array, " caps"]
    """Radius (m)."""
    arm: Int[Array, " caps"]
    """0 right, 1 left."""
    kind: Int[Array, " caps"]
    """0 arm link, 1 gripper base (palm), 2 finger pad."""
    sample_cap: Int[Array, " samples"]
    """Capsule of each axis sample."""
    sample_t: Float[Array, " samples"]
    """Axis parameter in [0, 1] of each sample."""
    names: tuple[str, ...] = eqx.field(static=True)
    """Names (MJCF capsule name, or ``pad_<side>_<finger>_<i>``)."""


def robot_proxy(robot: YumiModel, sample_spacing: float = 0.01, pad_capsules: int = 4) -> RobotProxy:
    """Capsules of :class:`RobotProxy` from the loaded YuMi: every MJCF collision capsule of the
    arms and gripper bases, and for each finger ``pad_capsules`` capsules along the finger (z) that
    cover its pad box (instead of the finger's over-covering query capsule).

    Args:
        robot: from :func:`rsrd_jax.robot.load_yumi`.
        sample_spacing: largest spacing of the axis samples (m).
        pad_capsules: capsules per finger pad, side by side across the pad's width.
    """
    g = robot.geom
    m = robot.mj_model
    link_of_body = {m.body(n).id: i for i, n in enumerate(LINK_NAMES)}
    link, p0, p1, rad, arm, kind, names = [], [], [], [], [], [], []
    for i, n in enumerate(g.cap_names):
        if "finger" in n:
            continue
        li = int(g.cap_link[i])
        link.append(li), p0.append(np.asarray(g.cap_p0[i])), p1.append(np.asarray(g.cap_p1[i]))
        rad.append(float(g.cap_radius[i])), names.append(n)
        arm.append(0 if LINK_NAMES[li].endswith("_r") or "_r_" in LINK_NAMES[li] else 1)
        kind.append(1 if "gripper" in n else 0)
    for gi in range(m.ngeom):
        n = m.geom(gi).name
        if not n.startswith("pad_"):
            continue
        body = int(m.geom_bodyid[gi])
        li = link_of_body[body]
        c = np.asarray(m.geom_pos[gi], float)  # in the finger body frame
        half = np.asarray(m.geom_size[gi], float)
        quat = np.asarray(m.geom_quat[gi], float)
        if not np.allclose(quat, [1, 0, 0, 0]):
            raise ValueError(f"pad geom {n} is rotated in its body; expected an axis-aligned box")
        # capsules along the pad's longest axis, side by side across its middle axis
        order = np.argsort(half)  # thin, middle, long
        a_thin, a_mid, a_long = order
        w = half[a_mid] / pad_capsules
        r = float(np.hypot(half[a_thin], w))
        for j in range(pad_capsules):
            off = np.zeros(3)
            off[a_mid] = -half[a_mid] + (2 * j + 1) * w
            e = np.zeros(3)
            e[a_long] = max(half[a_long] - r, 0.0)  # the round ends reach the pad's ends
            link.append(li), p0.append(c + off - e), p1.append(c + off + e), rad.append(r)
            names.append(f"{n}_{j}")
            arm.append(0 if LINK_NAMES[li].startswith("gripper_r") else 1)
            kind.append(2)
    p0, p1 = np.stack(p0), np.stack(p1)
    sc, st = [], []
    for c in range(len(link)):
        ns = int(np.ceil(np.linalg.norm(p1[c] - p0[c]) / sample_spacing)) + 1
        sc += [c] * ns
        st += list(np.linspace(0.0, 1.0, ns)) if ns > 1 else [0.0]
    return RobotProxy(
        link=jnp.asarray(link, jnp.int32), p0=jnp.asarray(p0, jnp.float32), p1=jnp.asarray(p1, jnp.float32),
        radius=jnp.asarray(rad, jnp.float32), arm=jnp.asarray(arm, jnp.int32), kind=jnp.asarray(kind, jnp.int32),
        sample_cap=jnp.asarray(sc, jnp.int32), sample_t=jnp.asarray(st, jnp.float32), names=tuple(names),
    )


def proxy_distances(
    robot: YumiModel, proxy: RobotProxy, sdf: PartSDF, q: Float[Array, "16"], T_world_part: Float[Array, "parts 7"]
) -> tuple[Float[Array, " caps"], Float[Array, "caps parts"]]:
    """Robot-table (caps,) and robot-part (caps, P) signed distances (m) of one configuration."""
    T = forward_kinematics(robot, q, check_finite=False).T_world_link
    Tl = jaxlie.SE3(T.wxyz_xyz[proxy.link])
    a, b = Tl @ proxy.p0, Tl @ proxy.p1
    geom = robot.geom
    Tt = jaxlie.SE3(geom.table_wxyz_xyz)
    n = proxy.radius.shape[0]
    d_table = capsule_box(a, b, proxy.radius, jnp.broadcast_to(Tt.rotation().as_matrix(), (n, 3, 3)),
                          jnp.broadcast_to(Tt.translation(), (n, 3)), jnp.broadcast_to(geom.table_half, (n, 3)))
    t = proxy.sample_t[:, None]
    xs = a[proxy.sample_cap] * (1 - t) + b[proxy.sample_cap] * t  # (S, 3) world
    P = sdf.values.shape[0]
    Tp = jaxlie.SE3(T_world_part).inverse()  # (P,)
    x_part = jax.vmap(lambda Ti: Ti @ xs)(Tp)  # (P, S, 3)
    d = sdf_distance(sdf, jnp.broadcast_to(jnp.arange(P)[:, None], x_part.shape[:2]), x_part)  # (P, S)
    d_cap = jax.ops.segment_min(d.T, proxy.sample_cap, num_segments=n, indices_are_sorted=True)  # (caps, P)
    return d_table, d_cap - proxy.radius[:, None]


def hand_part_mask(proxy: RobotProxy, num_parts: int, grasped: dict[int, int] | list, pads_only: bool = True
                   ) -> Bool[np.ndarray, "caps parts"]:
    """(caps, P) True where a robot-part distance counts. For each (arm, part) in ``grasped``
    the arm's finger pads (and its palm too when not ``pads_only``) may touch that part."""
    kind = np.asarray(proxy.kind)
    arm = np.asarray(proxy.arm)
    mask = np.ones((kind.shape[0], num_parts), bool)
    items = grasped.items() if isinstance(grasped, dict) else grasped
    for a, k in items:
        sel = (arm == a) & ((kind == 2) if pads_only else (kind >= 1))
        mask[sel, k] = False
    return mask


class HandGeometry(eqx.Module):
    """One gripper's palm and pad capsules in the TCP frame (both grippers are identical):
    end points at zero opening plus their rate of change with the finger opening."""

    p0: Float[Array, "caps 3"]
    """Axis start at zero opening (TCP frame, m)."""
    p1: Float[Array, "caps 3"]
    """Axis end at zero opening (TCP frame, m)."""
    dp: Float[Array, "caps 3"]
    """d(end point)/d(opening) (TCP frame; zero for the palm)."""
    radius: Float[Array, " caps"]
    """Radius (m)."""
    kind: Int[Array, " caps"]
    """1 palm, 2 finger pad."""
    sample_cap: Int[Array, " samples"]
    """Capsule of each axis sample."""
    sample_t: Float[Array, " samples"]
    """Axis parameter of each sample."""


def hand_geometry(robot: YumiModel, proxy: RobotProxy) -> HandGeometry:
    """The right gripper's capsules of ``proxy`` expressed in its TCP frame (host, FK at home)."""
    from ..robot import HOME_Q

    sel = np.nonzero((np.asarray(proxy.arm) == 0) & (np.asarray(proxy.kind) >= 1))[0]
    pts = []
    for o in (0.0, 0.025):
        q = np.asarray(HOME_Q, np.float32).copy()
        q[14] = o
        fk = forward_kinematics(robot, jnp.asarray(q), check_finite=False)
        T_tcp_link = jaxlie.SE3(fk.T_world_tcp.wxyz_xyz[0]).inverse() @ jaxlie.SE3(fk.T_world_link.wxyz_xyz[np.asarray(proxy.link)[sel]])
        pts.append((np.asarray(T_tcp_link @ proxy.p0[sel]), np.asarray(T_tcp_link @ proxy.p1[sel])))
    (a0, b0), (a1, _) = pts
    dp = (a1 - a0) / 0.025
    sc = np.asarray(proxy.sample_cap)
    keep = np.isin(sc, sel)
    remap = {int(c): i for i, c in enumerate(sel)}
    return HandGeometry(
        p0=jnp.asarray(a0, jnp.float32), p1=jnp.asarray(b0, jnp.float32), dp=jnp.asarray(dp, jnp.float32),
        radius=proxy.radius[sel], kind=proxy.kind[sel],
        sample_cap=jnp.asarray([remap[int(c)] for c in sc[keep]], jnp.int32),
        sample_t=proxy.sample_t[keep],
    )


@eqx.filter_jit
def hand_clearance(
    robot: YumiModel, hand: HandGeometry, sdf: PartSDF, T_world_tcp: Float[Array, "n k 7"],
    opening: Float[Array, " n"], T_world_part: Float[Array, "k parts 7"], part: Int[Array, ""],
    check_palm: bool = True, pad_table_allowance: Float[Array, ""] | float = 0.0,
    own_pad_offset: Float[Array, ""] | float = jnp.inf,
) -> Float[Array, " n"]:
    """Smallest signed distance (m) of a free-floating gripper at TCP poses ``T_world_tcp``
    (n grasps × k keyframes) with finger ``opening`` (m) to the table and the parts: the pads
    may touch ``part`` (the grasped one), the palm too unless ``check_palm``; the pads' table
    distances are increased by ``pad_table_allowance`` (m). A finite ``own_pad_offset`` (m) counts
    the pads' distances to ``part`` too, increased by it (an open jaw must not end inside its part:
    ``PlanConfig.approach_grasp_pads_margin``)."""
    geom = robot.geom
    Tt = jaxlie.SE3(geom.table_wxyz_xyz)
    P = sdf.values.shape[0]
    c = hand.radius.shape[0]
    allow = (jnp.arange(P)[None, :] == part) & ((hand.kind == 2) | (not check_palm))[:, None]  # (caps, P)
    own_pad = (jnp.arange(P)[None, :] == part) & (hand.kind == 2)[:, None]

    def one(T7, o, Tp):
        T = jaxlie.SE3(T7)
        a = T @ (hand.p0 + o * hand.dp)
        b = T @ (hand.p1 + o * hand.dp)
        d_tab = capsule_box(a, b, hand.radius, jnp.broadcast_to(Tt.rotation().as_matrix(), (c, 3, 3)),
                            jnp.broadcast_to(Tt.translation(), (c, 3)), jnp.broadcast_to(geom.table_half, (c, 3)))
        d_tab = d_tab + jnp.where(hand.kind == 2, pad_table_allowance, 0.0)
        t = hand.sample_t[:, None]
        xs = a[hand.sample_cap] * (1 - t) + b[hand.sample_cap] * t
        x_part = jax.vmap(lambda Ti: Ti @ xs)(jaxlie.SE3(Tp).inverse())
        d = sdf_distance(sdf, jnp.broadcast_to(jnp.arange(P)[:, None], x_part.shape[:2]), x_part)
        d_cap = jax.ops.segment_min(d.T, hand.sample_cap, num_segments=c, indices_are_sorted=True) - hand.radius[:, None]
        d_cap = jnp.where(allow, jnp.where(own_pad, d_cap + own_pad_offset, jnp.inf), d_cap)
        return jnp.minimum(jnp.min(d_tab), jnp.min(d_cap))

    per = jax.vmap(lambda T7, o: jax.vmap(lambda Tk, Tp: one(Tk, o, Tp))(T7, T_world_part))(T_world_tcp, opening)
    return jnp.min(per, axis=1)
