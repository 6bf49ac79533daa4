"""Top-down grasps from a part's footprint on the table: antipodal pinches across its outline,
approached from above.

Why a second sampler. :func:`sample_antipodal_grasps` draws first contacts area-weighted from a
decimated alpha-shape mesh of Gaussian centres. On a part lying flat (a scissor blade, a folded
temple, a panel's tab) almost all of that area faces up or down, so almost every grasp pinches
across the part's thickness, and its rolls approach from the side, through the table. The walls
a jaw coming from above would pinch are a few millimetres tall, a handful of faces after
decimation or none at all (on the studio scissors' ground-truth geometry 1 of 128 base grasps
can be approached from above; the tracked led_light model's tab has no face facing sideways). Here the part's points are projected along the
table normal into a footprint image, and pairs of its outline points whose outward normals
oppose each other across the part are the contacts: the grasp axis is level, the approach is
straight down (plus a few tilts about the axis), and the grasp centre sits at the middle of the
part's height at the two contacts. The planner backs the gripper off along the approach until it
clears the table and the other parts (``PlanConfig.grasp_depths``), as for the mesh grasps.

Host numpy + scipy (like the planner's signed-distance grids); the result is a
:class:`~rsrd_jax.grasp.PartGrasps` that :func:`~rsrd_jax.grasp.merge_grasps` combines with the
mesh grasps.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Float

from ._antipodal import GraspResult, PartGrasps


class TopDownConfig(eqx.Module):
    """Options of :func:`sample_topdown_grasps`."""

    num_grasps: int = 32
    """Base grasps kept (best first; padded rows are invalid)."""
    num_samples: int = 600
    """Outline cells drawn as first contacts."""
    cell: float = 0.001
    """Footprint image cell (m)."""
    close_radius: float = 0.002
    """Gaps in the projected points up to about twice this (m) are closed (morphological closing);
    the footprint is the union of discs of ``point_radius`` around the points plus those gaps."""
    point_radius: float | None = None
    """Disc radius around each projected point (m); None = half the median 3D nearest-neighbour
    spacing (at least 0.5 mm), the ball radius the planner's signed-distance grids use."""
    normal_smoothing: float = 0.0015
    """Gaussian smoothing (m) of the footprint's signed distance before its gradient gives the
    outline normals (a pad presses on a patch, not a pixel)."""
    min_width: float = 0.002
    """Smallest contact separation (m)."""
    max_width: float = 0.05
    """Largest contact separation (m): the YuMi jaw opens 50 mm."""
    friction_angle_deg: float = 30.0
    """Both outline normals must lie within this angle of the grasp axis."""
    min_separation: float = 0.004
    """Non-maximum suppression: a grasp is dropped when both contacts lie within this distance (m)
    of the contacts of a better kept grasp."""
    centre_weight: float = 0.5
    """Score weight of centredness (1 at the footprint's centroid or ``near`` point, 0 at the
    farthest outline point); antipodality has weight 1 (as ``GraspConfig``)."""
    min_hole_radius: float = 0.004
    """Holes in the footprint that no disc of this radius (m) fits into are filled: a finger pad
    (8 mm thick) cannot enter them, and sparse Gaussians leave such gaps inside a plate."""
    tilts_deg: tuple[float, ...] = (0.0, 20.0, -20.0)
    """Rolls about the grasp axis: 0 = straight down; the others tilt the approach sideways (the
    arm may not reach a vertical approach everywhere)."""


def _basis(down: np.ndarray) -> np.ndarray:
    """(3, 3) rows e1, e2, up: a right-handed frame whose third axis is ``-down``."""
    up = -down / np.linalg.norm(down)
    helper = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(helper, up)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(up, e1), up])


def _disc(r: int) -> np.ndarray:
    y, x = np.mgrid[-r : r + 1, -r : r + 1]
    return x * x + y * y <= r * r


def sample_topdown_grasps(
    points: Float[np.ndarray, "n 3"],
    down: Float[np.ndarray, "3"],
    seed: int = 0,
    config: TopDownConfig = TopDownConfig(),
    near: tuple[Float[np.ndarray, "3"], float] | None = None,
) -> PartGrasps:
    """Level pinches across the footprint of a part seen from above.

    Args:
        points: (n, 3) the part's surface points (e.g. Gaussian centres) in its part frame (m).
        down: (3,) the table's downward normal in the part frame (where the part lies when it is
            grasped), any length > 0.
        seed: seed of the outline samples.
        config: options.
        near: optional (point (3,), radius): first contacts only within ``radius`` (m, in the
            footprint plane) of ``point``, and centredness measured from it.

    Returns:
        :class:`PartGrasps` with ``num_grasps × 2 × len(tilts_deg)`` rows (base grasp, axis sign,
        tilt), approach (grasp z) along ``down`` for tilt 0.

    Raises:
        ValueError: on points that are not (n ≥ 1, 3), a zero or non-finite ``down``, or bad options.
    """
    from scipy import ndimage
    from scipy.spatial import cKDTree

    pts = np.asarray(points, np.float64)
    down = np.asarray(down, np.float64).reshape(-1)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0 or not np.all(np.isfinite(pts)):
        raise ValueError(f"points: expected finite (n ≥ 1, 3) points, got shape {pts.shape}")
    if down.shape != (3,) or not np.all(np.isfinite(down)) or not np.linalg.norm(down) > 0:
        raise ValueError(f"down: expected a finite non-zero 3-vector, got {down}")
    c = config
    if not (c.cell > 0 and c.close_radius >= 0 and c.max_width > c.min_width >= 0 and 0 < c.friction_angle_deg < 90
            and c.num_grasps > 0 and c.num_samples > 0 and len(c.tilts_deg) > 0):  # fmt: skip
        raise ValueError(f"config: invalid options {c}")
    B = _basis(down)
    uvh = pts @ B.T  # (n, 3): footprint coordinates u, v and height h above the part frame's origin
    if c.point_radius is None:
        nn = cKDTree(pts).query(pts, k=2)[0][:, 1] if len(pts) > 1 else np.zeros(1)
        r_pt = max(0.5 * float(np.median(nn)), 0.0005)
    else:
        r_pt = float(c.point_radius)
    h = c.cell
    pad = int(np.ceil((r_pt + 2 * c.close_radius) / h)) + 3
    lo = uvh[:, :2].min(0) - pad * h
    shape = tuple(np.ceil((uvh[:, :2].max(0) + pad * h - lo) / h).astype(int) + 1)
    ij = np.round((uvh[:, :2] - lo) / h).astype(int)
    hit = np.zeros(shape, bool)
    hit[ij[:, 0], ij[:, 1]] = True
    top = np.full(shape, -np.inf)
    bot = np.full(shape, np.inf)
    np.maximum.at(top, (ij[:, 0], ij[:, 1]), uvh[:, 2])
    np.minimum.at(bot, (ij[:, 0], ij[:, 1]), uvh[:, 2])
    # footprint: discs of r_pt around the points, gaps up to ~2 close_radius closed
    rc = int(round((r_pt + c.close_radius) / h))
    occ = ndimage.binary_erosion(ndimage.binary_dilation(hit, _disc(rc)), _disc(max(rc - int(round(r_pt / h)), 0)))
    holes, n_holes = ndimage.label(ndimage.binary_fill_holes(occ) & ~occ)
    if n_holes:
        roomy = ndimage.binary_erosion(holes > 0, _disc(int(round(c.min_hole_radius / h))))
        keep = np.zeros(n_holes + 1, bool)
        keep[np.unique(holes[roomy])] = True
        keep[0] = True
        occ |= ~keep[holes]
    # the part's height range near each cell (for the grasp centre's height)
    win = _disc(int(round(max(2 * c.close_radius, 2 * r_pt) / h)) + 1)
    top = ndimage.maximum_filter(np.where(hit, top, -np.inf), footprint=win, mode="constant", cval=-np.inf)
    bot = -ndimage.maximum_filter(np.where(hit, -bot, -np.inf), footprint=win, mode="constant", cval=-np.inf)
    # outline normals: gradient of the smoothed signed distance (outside positive)
    sd = (ndimage.distance_transform_edt(~occ) - ndimage.distance_transform_edt(occ)) * h
    sd = ndimage.gaussian_filter(sd, max(c.normal_smoothing / h, 1e-6))
    gx, gy = np.gradient(sd)
    gn = np.hypot(gx, gy)
    nrm = np.stack([gx, gy], -1) / np.maximum(gn, 1e-12)[..., None]
    edge = occ & ~ndimage.binary_erosion(occ, np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], bool), border_value=0)
    cand = np.argwhere(edge)
    centre_uv = (lo + h * np.argwhere(occ).mean(0)) if near is None else (np.asarray(near[0], np.float64) @ B.T)[:2]
    if near is not None:
        cand = cand[np.linalg.norm(lo + h * cand - centre_uv, axis=1) <= float(near[1])]
    n_g, tilts = int(c.num_grasps), np.deg2rad(np.asarray(c.tilts_deg, np.float64))
    cos_cone = float(np.cos(np.deg2rad(c.friction_angle_deg)))
    rng = np.random.default_rng(int(seed))
    if len(cand) > c.num_samples:
        cand = cand[rng.choice(len(cand), c.num_samples, replace=False)]
    # march inward from each outline cell; every exit from the footprint within max_width is a contact
    steps = np.arange(1, int(np.ceil(c.max_width / (0.5 * h))) + 2) * 0.5 * h  # (m,)
    p1 = lo + h * cand  # (s, 2)
    d = -nrm[cand[:, 0], cand[:, 1]]  # inward
    q = p1[:, None] + steps[None, :, None] * d[:, None]  # (s, m, 2)
    qi = np.clip(np.round((q - lo) / h).astype(int), 0, np.array(shape) - 1)
    inside = occ[qi[..., 0], qi[..., 1]]
    exits = inside[:, :-1] & ~inside[:, 1:]  # inside at step k, outside at k+1
    si, ki = np.nonzero(exits)
    n_hit = int(len(cand))  # every inward ray leaves a bounded footprint somewhere
    t = steps[ki] + 0.25 * h  # the outline lies between the two samples
    ok_w = (t >= c.min_width) & (t <= c.max_width)
    si, ki, t = si[ok_w], ki[ok_w], t[ok_w]
    n_width = int(len(si))
    e = qi[si, ki]  # last inside cell at the exit
    n2 = nrm[e[:, 0], e[:, 1]]
    cos2 = np.sum(n2 * d[si], -1)
    n1 = nrm[cand[si, 0], cand[si, 1]]
    cos1 = np.sum(-n1 * d[si], -1)  # 1 up to the grid's rounding
    # both contacts need height: a cell with no point near it has no height band
    c1c = cand[si]
    band = lambda a: (bot[a[:, 0], a[:, 1]], top[a[:, 0], a[:, 1]])  # noqa: E731
    (b1, t1), (b2, t2) = band(c1c), band(e)
    good = (cos1 >= cos_cone) & (cos2 >= cos_cone) & np.isfinite(t1) & np.isfinite(t2)
    si, t, cos1, cos2, b1, t1, b2, t2 = (x[good] for x in (si, t, cos1, cos2, b1, t1, b2, t2))
    n_anti = int(len(si))
    P1 = p1[si]
    P2 = P1 + t[:, None] * d[si]
    hc = 0.25 * (b1 + t1 + b2 + t2)  # middle of the part's height at the two contacts
    mid = 0.5 * (P1 + P2)
    radius = max(float(np.linalg.norm(lo + h * np.argwhere(edge) - centre_uv, axis=1).max()), 1e-9) if near is None \
        else float(near[1])  # fmt: skip
    anti = (0.5 * (cos1 + cos2) - cos_cone) / (1.0 - cos_cone)
    score = anti + c.centre_weight * (1.0 - np.clip(np.linalg.norm(mid - centre_uv, axis=1) / radius, 0.0, 1.0))
    to3 = lambda uv, hh: np.concatenate([uv, hh[:, None]], -1) @ B  # noqa: E731
    C1, C2 = to3(P1, hc), to3(P2, hc)
    kept: list[int] = []
    for j in np.argsort(-score, kind="stable"):
        if len(kept) == n_g:
            break
        if kept:
            k1, k2 = C1[kept], C2[kept]
            same = np.maximum(np.linalg.norm(k1 - C1[j], axis=1), np.linalg.norm(k2 - C2[j], axis=1))
            swap = np.maximum(np.linalg.norm(k1 - C2[j], axis=1), np.linalg.norm(k2 - C1[j], axis=1))
            if np.min(np.minimum(same, swap)) < c.min_separation:
                continue
        kept.append(int(j))
    g = len(kept)
    base_valid = np.zeros(n_g, bool)
    base_valid[:g] = True
    contacts = np.zeros((n_g, 2, 3))
    widths = np.zeros(n_g)
    scores = np.full(n_g, -np.inf)
    R = np.tile(np.eye(3), (n_g, 2, len(tilts), 1, 1))
    centre = np.zeros((n_g, 2, len(tilts), 3))
    if g:
        kk = np.asarray(kept)
        contacts[:g] = np.stack([C1[kk], C2[kk]], 1)
        widths[:g], scores[:g] = t[kk], score[kk]
        x = contacts[:g, 1] - contacts[:g, 0]
        x /= np.linalg.norm(x, axis=1, keepdims=True)
        z = np.broadcast_to(B[2] * -1.0, x.shape)  # approach: down
        R0 = np.stack([x, np.cross(z, x), z], -1)  # columns x, y, z
        flip = np.diag([-1.0, -1.0, 1.0])  # axis sign: π about z
        for s, Rs in enumerate((R0, R0 @ flip)):
            for r, a in enumerate(tilts):
                R[:g, s, r] = Rs @ np.asarray(jaxlie.SO3.from_x_radians(float(a)).as_matrix(), np.float64)
        centre[:g] = contacts[:g].mean(1)[:, None, None]
    n = n_g * 2 * len(tilts)
    rep = lambda v: np.broadcast_to(v[:, None, None], (n_g, 2, len(tilts))).reshape(n)  # noqa: E731
    result = (GraspResult.success if g else GraspResult.no_opposite_surface if n_hit == 0
              else GraspResult.width_out_of_range if n_width == 0 else GraspResult.outside_friction_cone)  # fmt: skip
    return PartGrasps(
        T_part_grasp=jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.from_matrix(jnp.asarray(R.reshape(n, 3, 3), jnp.float32)),
                                                           jnp.asarray(centre.reshape(n, 3), jnp.float32)).wxyz_xyz,
        width=jnp.asarray(rep(widths), jnp.float32), score=jnp.asarray(rep(scores), jnp.float32),
        valid=jnp.asarray(rep(base_valid)), base_index=jnp.asarray(rep(np.arange(n_g)), jnp.int32),
        contacts=jnp.asarray(contacts, jnp.float32), base_valid=jnp.asarray(base_valid), result=result,
        num_hit=jnp.asarray(n_hit, jnp.int32), num_width_ok=jnp.asarray(n_width, jnp.int32),
        num_antipodal=jnp.asarray(n_anti, jnp.int32),
    )
