"""Joint discovery for tracking (`TrackConfig.joints`): a first per-frame pass with weak robust
ARAP on the parts' whole contact band, a fit of each moving part's joint point from that pass's
motion, and a second pass in which the parts are tied only at those points (a ball joint: two
invisible, coincident Gaussians per joint whose ARAP pair has rest length 0).

Why: pair-distance ARAP on Gaussians a few millimetres off a hinge's axis resists the hinge's
rotation (the stapler's 17 contact pairs, 1–10 mm from its axis, hold the arm at 1–2° of its
28.6°), while without pairs nothing keeps the parts together and the base drifts (18 mm). The
band's pairs at 1/40 of the ARAP weight and a saturating loss let the arm turn, and its motion
fixes the joint (fitted point within 3–6 mm of the true hinge axis on the stapler).

Slides have no joint point: the first pass turns a slide by a few degrees about a point far from
the contact, and a second pass tied there tracks a turn (nerf_gun's slide 37 mm off). Such parts
(`is_slide_candidate`) are re-tracked on a slide joint along each of their principal axes and
the level direction away from their neighbour (`slide_directions`, `prismatic_loss`);
`track_video` keeps the hypothesis with the lowest data loss.
"""

from __future__ import annotations

import copy

import equinox as eqx
import jax.numpy as jnp
import jaxlie
import numpy as np
from scipy.spatial import cKDTree

JOINT_OPACITY_LOGIT = -40.0
"""Opacity logit marking the invisible joint Gaussians (opacity ≈ 4e-18: they never render)."""


def contact_band_pairs(means: np.ndarray, labels: np.ndarray, radius: float, near: float) -> np.ndarray:
    """Cross-part pairs over the whole contact of every two touching parts: for each part pair
    whose closest Gaussians are within `near` metres, each Gaussian of the smaller-index part
    whose nearest Gaussian of the other part is within (closest distance + `radius`) is paired
    with it. (M×2, i < j.)"""
    out = []
    P = int(labels.max()) + 1
    for a in range(P):
        ia = np.flatnonzero(labels == a)
        for b in range(a + 1, P):
            ib = np.flatnonzero(labels == b)
            if len(ia) == 0 or len(ib) == 0:
                continue
            d, j = cKDTree(means[ib]).query(means[ia])
            if d.min() > near:
                continue
            sel = d <= d.min() + radius
            out.append(np.sort(np.stack([ia[sel], ib[j[sel]]], 1), axis=1))
    if not out:
        return np.zeros((0, 2), np.int64)
    return np.unique(np.concatenate(out), axis=0)


def contact_tree(labels: np.ndarray, band: np.ndarray, num_parts: int, root: int) -> dict[int, int]:
    """Each part's parent in the maximum spanning tree of the contact graph (edge weight: the
    two parts' contact-band pairs), grown from `root`; a part not connected to it hangs from the
    largest part of its own component (that part has no parent). Every part is tied to one other
    at most once: a "most-touching neighbour" can make two parts each other's neighbour (a bear's
    torso touching its arm more than its head, the root), and two joints between the same parts
    lock them together."""
    C = np.zeros((num_parts, num_parts))
    np.add.at(C, (labels[band[:, 0]], labels[band[:, 1]]), 1.0)
    C = C + C.T
    size = np.bincount(labels, minlength=num_parts)
    parent: dict[int, int] = {}
    done = np.zeros(num_parts, bool)
    done[root] = True
    while not done.all():
        w = np.where(done[:, None] & ~done[None, :], C, 0.0)
        if w.max() > 0:
            a, b = np.unravel_index(int(np.argmax(w)), w.shape)
            parent[int(b)] = int(a)
            done[b] = True
        else:  # no contact with the tree so far: a new component, rooted at its largest part
            done[int(np.argmax(np.where(done, -1, size)))] = True
    return parent


def with_joint_slots(model, radius: float, near: float):
    """The model with contact-band ARAP pairs and, for every part that touches another, two
    invisible Gaussians (the part's and its parent's) at the centre of their contact, paired
    with each other. Parents: `contact_tree` from the largest part (the tracker's root), which
    gets no slot of its own. Returns (model, neighbour: dict part -> parent part)."""
    g = model.gaussians
    means = np.asarray(g.means, np.float64)
    labels = np.asarray(g.part_ids)
    P = model.num_parts
    band = contact_band_pairs(means, labels, radius, near)
    root = int(np.argmax(np.bincount(labels, minlength=P)))
    neighbour = contact_tree(labels, band, P, root)
    centres, ids = [], []
    for k, nb in sorted(neighbour.items()):
        mine = band[((labels[band[:, 0]] == k) & (labels[band[:, 1]] == nb)) | ((labels[band[:, 1]] == k) & (labels[band[:, 0]] == nb))]
        centres += [0.5 * (means[mine[:, 0]] + means[mine[:, 1]]).mean(0)] * 2
        ids += [k, nb]
    n, m = g.num_gaussians, len(ids)
    if m:
        extra = {
            "means": np.asarray(centres), "quats": np.tile([1.0, 0.0, 0.0, 0.0], (m, 1)),
            "log_scales": np.full((m, 3), -9.0), "opacity_logits": np.full(m, JOINT_OPACITY_LOGIT),
            "colours": np.zeros((m, 3)), "features": np.zeros((m, g.features.shape[1])), "part_ids": np.asarray(ids),
        }  # fmt: skip
        fields = ("means", "quats", "log_scales", "opacity_logits", "colours", "features", "part_ids")
        g = type(g)(*[jnp.concatenate([getattr(g, f), jnp.asarray(extra[f], getattr(g, f).dtype)]) for f in fields])
    pairs = np.concatenate([band, np.arange(n, n + m).reshape(-1, 2)]) if m else band
    new = (g, jnp.asarray(pairs, jnp.int32).reshape(-1, 2))
    if isinstance(model, eqx.Module):
        model = eqx.tree_at(lambda x: (x.gaussians, x.arap_pairs), model, new)
    else:  # any object with these attributes (e.g. a namespace built in tests)
        model = copy.copy(model)
        model.gaussians, model.arap_pairs = new
    return model, neighbour


def joint_slots(tm) -> dict[int, tuple[int, int, int]]:
    """In a TrackModel made from `with_joint_slots`' model: part -> (its joint Gaussian, the
    neighbour's joint Gaussian, index of their ARAP pair)."""
    op = np.asarray(tm.gaussians.opacity_logits)
    ids = np.asarray(tm.gaussians.part_ids)
    pairs = np.asarray(tm.arap_pairs)
    out = {}
    for p, (i, j) in enumerate(pairs):
        if op[i] <= JOINT_OPACITY_LOGIT + 1 and op[j] <= JOINT_OPACITY_LOGIT + 1:
            out[int(ids[i])] = (int(i), int(j), p)
    return out


def fit_joint_point(T_obj_part: np.ndarray, centroids: np.ndarray, k: int, nb: int, x0: np.ndarray,
                    min_angle_deg: float, reg: float = 1e-2) -> np.ndarray | None:
    """The point of part k (object frame at rest) that moved least relative to part `nb`.

    A joint point X (object frame at rest; x = X − c_k in k's part frame) satisfies
    T_k(t)·x = T_nb(t)·(X − c_nb) for every frame: (R_k − R_nb)·X = R_k c_k − R_nb c_nb + t_nb − t_k.
    Solved by least squares with a pull `reg` (relative to the system's scale) towards `x0`,
    which fixes the position along a hinge's axis. None when part k never turned more than
    `min_angle_deg` relative to `nb` (a slide or a still part: no point is defined).

    Args:
        T_obj_part: F×P×7 part poses (wxyz_xyz, object frame). centroids: P×3 rest centroids.
    """
    if relative_turn_deg(T_obj_part, k, nb).max() < min_angle_deg:
        return None
    T = np.asarray(jaxlie.SE3(jnp.asarray(T_obj_part, jnp.float32)).as_matrix(), np.float64)
    Rk, tk, Rn, tn = T[:, k, :3, :3], T[:, k, :3, 3], T[:, nb, :3, :3], T[:, nb, :3, 3]
    A = (Rk - Rn).reshape(-1, 3)
    b = (np.einsum("fij,j->fi", Rk, centroids[k]) - np.einsum("fij,j->fi", Rn, centroids[nb]) + tn - tk).reshape(-1)
    lam = reg * max(float(np.trace(A.T @ A)) / 3, 1e-12)
    return np.linalg.solve(A.T @ A + lam * np.eye(3), A.T @ b + lam * np.asarray(x0, np.float64))



def relative_turn_deg(T_obj_part: np.ndarray, k: int, nb: int) -> np.ndarray:
    """F: the angle (degrees) by which part k is turned relative to part `nb` in each frame of
    the pass `T_obj_part` (F×P×7), from their rest orientations."""
    R = np.asarray(jaxlie.SO3(jnp.asarray(np.asarray(T_obj_part)[..., :4], jnp.float32)).as_matrix(), np.float64)
    rel = np.einsum("fji,fjk->fik", R[:, nb], R[:, k])
    return np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))


def relative_displacement(T_obj_part: np.ndarray, centroids: np.ndarray, k: int, nb: int) -> np.ndarray:
    """F×3: part k's centroid relative to part `nb`, in `nb`'s frame (object axes at rest), minus
    its rest offset."""
    T = np.asarray(jaxlie.SE3(jnp.asarray(T_obj_part, jnp.float32)).as_matrix(), np.float64)
    t = np.einsum("fji,fj->fi", T[:, nb, :3, :3], T[:, k, :3, 3] - T[:, nb, :3, 3])
    return t - (centroids[k] - centroids[nb])


def is_slide_candidate(T_obj_part: np.ndarray, centroids: np.ndarray, point: np.ndarray | None, contact: np.ndarray,
                       k: int, nb: int, radius: float, min_m: float, point_ratio: float) -> bool:  # fmt: skip
    """Whether part k may be on a slide joint relative to `nb`, from the pass `T_obj_part`
    (F×P×7): with a fitted joint `point`, when it lies more than `point_ratio` × the part's
    `radius` from the parts' `contact` (a slide's first pass turns it by a few degrees about a
    point far from where the parts touch; on the session-7 builds: nerf_gun's slide 0.57,
    toy_drawer's drawer 0.71, hinges 0.02–0.59); without one (it did not turn), when it moved by
    more than `min_m`."""
    if point is not None:
        return float(np.linalg.norm(np.asarray(point) - contact)) > point_ratio * radius
    return float(np.linalg.norm(relative_displacement(T_obj_part, centroids, k, nb), axis=1).max()) > min_m


def slide_axes(points: np.ndarray) -> np.ndarray:
    """3×3: candidate slide directions of a part (rows, object frame): its principal axes. A
    slide's direction is usually one of them (a slide or plug along its length, a drawer along
    its front panel's normal)."""
    _, _, Vt = np.linalg.svd(points - points.mean(0), full_matrices=False)
    return Vt


def slide_directions(points: np.ndarray, offset: np.ndarray, up: np.ndarray | None = None,
                     min_angle_deg: float = 15.0) -> np.ndarray:
    """C×3: the slide directions a part is tried along (rows, object frame): its principal axes
    (`slide_axes`), then the direction of `offset` (from its neighbour's centroid to its own)
    made level (its component along the support normal `up` removed, when known) unless it lies
    within `min_angle_deg` of one of them. A part usually slides out of its neighbour along the
    line between them, while a near-square part's principal axes are arbitrary in its plane:
    the studio toy_drawer's drawer (80 × 90 mm bottom) has its diagonals as axes; on the robot
    trials' build only the level offset direction beat the joint point (drawer ADD 23.3 → 6.2
    mm)."""
    axes = slide_axes(points)
    d = np.asarray(offset, np.float64)
    if up is not None:
        u = np.asarray(up, np.float64) / np.linalg.norm(up)
        d = d - (d @ u) * u
    n = float(np.linalg.norm(d))
    if n < 1e-9 or (np.abs(axes @ (d / n)) > np.cos(np.radians(min_angle_deg))).any():
        return axes
    return np.concatenate([axes, (d / n)[None]])


def hinge_axis(T_obj_part: np.ndarray, centroids: np.ndarray, k: int, nb: int, point: np.ndarray,
               points: np.ndarray, candidates: np.ndarray, prefer_last: float = 0.0,
               hand_px: np.ndarray | None = None, refine_deg: float | None = None) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The hinge axis of part k relative to `nb` among `candidates` (C×3 directions, object frame
    at rest): the one about which turns through `point` explain the pass's motion of k's
    `points` (N×3, object frame at rest) best. For each axis and frame the best angle is the 2D
    Procrustes solution in the plane normal to the axis; the score is the RMS point residual.
    A thin part's roll about its own length barely moves its points, so the tracked rotation's
    own axis (which includes that roll) is not a candidate: the residual is measured on points.
    `prefer_last`: the last candidate (the support plane's normal) wins when its residual is within
    this fraction of the lowest: a round part's (a capsule limb's) two minor principal axes are
    arbitrary directions in its cross-section, and one of them can tie with the table normal on a
    noisy pass. `hand_px`: the candidates' pixel residuals against a hand's pinch track
    (`hand_hinge_residual`) when a hand held the part or its neighbour; each candidate is then
    scored by the mean of its point residual and its hand residual, each relative to its lowest
    (and `prefer_last` applies to that score): the pass's points alone can favour the axis of a
    turn the pass made up (see `hand_hinge_residual`), the pinch track alone cannot tell axes
    apart along a short arc (the studio scissors' blade: 2.3 px for a wrong axis, 3.4 px for the
    true one, whose point residual is 2.3× lower). `refine_deg`: the chosen candidate is then
    turned, by at most this angle (degrees), to the direction of lowest point residual (a hinge
    need not lie along a principal axis of the part's points: the studio led_light's panel, with
    its tab and knobs, has its first axis 5° off the hinge).

    Returns:
        (the chosen unit axis, C RMS residuals in metres, of the candidates as given).
    """
    T = np.asarray(jaxlie.SE3(jnp.asarray(T_obj_part, jnp.float32)).as_matrix(), np.float64)
    Rk, tk, Rn, tn = T[:, k, :3, :3], T[:, k, :3, 3], T[:, nb, :3, :3], T[:, nb, :3, 3]
    pk = np.asarray(points, np.float64) - centroids[k]
    world = np.einsum("fij,nj->fni", Rk, pk) + tk[:, None]  # T_obj_part: part frame (origin c_k) -> object
    # into nb's frame at rest (object axes), relative to the joint point
    q = np.einsum("fji,fnj->fni", Rn, world - tn[:, None]) + centroids[nb] - point
    p = np.asarray(points, np.float64) - point
    def axis_rms(a: np.ndarray) -> float:
        a = a / np.linalg.norm(a)
        pp = p - np.outer(p @ a, a)
        qp = q - (q @ a)[..., None] * a
        th = np.arctan2(np.einsum("nj,fnj->f", np.cross(a, pp), qp), np.einsum("nj,fnj->f", pp, qp))
        # p turned about a by th (Rodrigues) against the pass's points
        c, s_ = np.cos(th)[:, None, None], np.sin(th)[:, None, None]
        rot = p[None] * c + np.cross(a, p)[None] * s_ + np.outer(p @ a, a)[None] * (1 - c)
        return float(np.sqrt(np.mean(np.sum((rot - q) ** 2, -1))))

    rms = np.asarray([axis_rms(a) for a in np.asarray(candidates, np.float64)])
    score = rms / max(float(rms.min()), 1e-12)
    if hand_px is not None:
        score = 0.5 * (score + np.asarray(hand_px) / max(float(np.min(hand_px)), 1e-9))
    i = int(np.argmin(score))
    if prefer_last > 0 and score[-1] <= (1.0 + prefer_last) * score[i]:
        i = len(rms) - 1
    best = np.asarray(candidates, np.float64)[i]
    best = best / np.linalg.norm(best)
    if refine_deg is not None and refine_deg > 0:
        best = _refine_axis(axis_rms, best, float(refine_deg))
    return best, rms


def _refine_axis(axis_rms, a0: np.ndarray, max_deg: float) -> np.ndarray:
    """The unit axis within `max_deg` of `a0` that minimises `axis_rms`: a Nelder–Mead search over
    the two tilts of `a0`, whose first simplex vertex is `a0` itself (the search returns its
    best vertex, so never a direction with a higher residual than `a0`)."""
    from scipy.optimize import minimize

    u = np.cross(a0, [1.0, 0.0, 0.0] if abs(a0[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(a0, u)
    lim = np.tan(np.radians(max_deg))

    def axis(x: np.ndarray) -> np.ndarray:
        x = x * min(1.0, lim / max(float(np.linalg.norm(x)), 1e-12))  # onto the cone of max_deg
        a = a0 + x[0] * u + x[1] * v
        return a / np.linalg.norm(a)

    res = minimize(lambda x: axis_rms(axis(x)), np.zeros(2), method="Nelder-Mead",
                   options=dict(xatol=1e-4, fatol=1e-8, maxiter=200, initial_simplex=[[0, 0], [lim / 4, 0], [0, lim / 4]]))  # fmt: skip
    return axis(res.x)



def _hand_path_residual(T_obj_part: np.ndarray, centroids: np.ndarray, other: int, paths: np.ndarray,
                        T_cam_obj: np.ndarray, intrinsics, pinch_uv: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """C RMS pixel distances: for each candidate path (`paths`, C×A×3: A positions of a held
    point, object frame at rest, fixed to part `other`), per frame the path position whose
    projection lies closest to that frame's pinch point, its distance's RMS over `frames`."""
    T = np.asarray(jaxlie.SE3(jnp.asarray(T_obj_part, jnp.float32)).as_matrix(), np.float64)[frames]
    M = np.asarray(jaxlie.SE3(jnp.asarray(T_cam_obj, jnp.float32)).as_matrix(), np.float64)
    R = np.einsum("ij,fjk->fik", M[:3, :3], T[:, other, :3, :3])  # part `other`'s frame -> camera
    t = np.einsum("ij,fj->fi", M[:3, :3], T[:, other, :3, 3]) + M[:3, 3]
    f = np.array([float(intrinsics.fx), float(intrinsics.fy)])
    c = np.array([float(intrinsics.cx), float(intrinsics.cy)])
    out = []
    for path in np.asarray(paths, np.float64):
        cam = np.einsum("fij,aj->fai", R, path - centroids[other]) + t[:, None]
        uv = f * cam[..., :2] / np.maximum(cam[..., 2:3], 1e-6) + c
        d = np.linalg.norm(uv - pinch_uv[frames, None], axis=-1).min(1)
        out.append(float(np.sqrt(np.mean(d**2))))
    return np.asarray(out)


def hand_hinge_residual(T_obj_part: np.ndarray, centroids: np.ndarray, held: int, other: int, point: np.ndarray,
                        anchor: np.ndarray, T_cam_obj: np.ndarray, intrinsics, pinch_uv: np.ndarray, frames: np.ndarray,
                        candidates: np.ndarray, step_deg: float = 1.0) -> np.ndarray:  # fmt: skip
    """How well a hand's 2D pinch track fits a hinge: C RMS pixel distances between the pinch
    point of `frames` and the hand's `anchor` (object frame at rest, on part `held`) turned about
    each candidate axis through the joint `point` relative to part `other`, at the best angle per
    frame (sampled every `step_deg`). `other`'s poses come from the pass `T_obj_part` (F×P×7), the
    camera from `T_cam_obj` (7,) and `intrinsics`; `pinch_uv` is F×2 full-frame pixels.

    The hand moves with the part it holds, also where it hides the part from the feature loss:
    over a video its pinch point traces the projection of a circle about the hinge, which rules
    out axes a first pass settled on when it fell behind a fast, occluded turn (the studio bear's
    waving arm: the pass turned it about an oblique axis that explains its points best, 3.6 mm,
    while the true axis fits them at 12.4 mm; the pinch track gives 0.8 px for the true axis,
    5.0 and 21.9 px for the other two principal directions)."""
    v0 = np.asarray(anchor, np.float64) - point
    th = np.radians(np.arange(-180.0, 180.0, step_deg))[:, None]
    paths = []
    for a in np.asarray(candidates, np.float64):
        a = a / np.linalg.norm(a)
        paths.append(point + v0 * np.cos(th) + np.cross(a, v0) * np.sin(th) + (v0 @ a) * a * (1 - np.cos(th)))
    return _hand_path_residual(T_obj_part, centroids, other, np.stack(paths), T_cam_obj, intrinsics, pinch_uv, frames)


def hand_slide_residual(T_obj_part: np.ndarray, centroids: np.ndarray, held: int, other: int, anchor: np.ndarray,
                        T_cam_obj: np.ndarray, intrinsics, pinch_uv: np.ndarray, frames: np.ndarray, directions: np.ndarray,
                        reach: float = 0.2, step: float = 0.001) -> np.ndarray:  # fmt: skip
    """As `hand_hinge_residual` for slides: the `anchor` moved along each of `directions` (C×3)
    by up to `reach` metres either way (every `step`) relative to part `other`."""
    s = np.arange(-reach, reach + step / 2, step)[:, None]
    dirs = np.asarray(directions, np.float64)
    dirs = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    paths = np.asarray(anchor, np.float64) + s[None] * dirs[:, None]
    return _hand_path_residual(T_obj_part, centroids, other, paths, T_cam_obj, intrinsics, pinch_uv, frames)
