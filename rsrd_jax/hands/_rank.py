"""Which part(s) the demonstrator manipulated: fingertip contact ranking, with a motion-based
fallback that does not credit parts that only moved because their parent moved."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import scipy.spatial
from jaxtyping import Array, Bool, Float, Int

LEFT, RIGHT = 0, 1
"""Hand axis convention: index 0 = left hand, 1 = right hand (the demonstrator's)."""


@runtime_checkable
class HandKeypointSource(Protocol):
    """Anything that supplies per-frame fingertips in the object frame.

    The studio oracle (ground-truth keypoints) and a detector (e.g. MediaPipe / HaMeR lifted to
    3D with the tracked object pose) implement this; the ranking only sees the array.
    """

    def fingertips_obj(self) -> Float[np.ndarray, "t h 2 3"]:
        """Thumb tip (index 0) and index-finger tip (index 1) of each hand per frame, in the
        object frame, metres; hand axis ordered (left, right); NaN where not visible."""
        ...


class ArrayHandKeypoints(eqx.Module):
    """A HandKeypointSource holding a precomputed array (tests, studio oracle, caches)."""

    keypoints: Float[np.ndarray, "t h 2 3"]
    """Fingertips in the object frame, metres, NaN when not visible."""

    def fingertips_obj(self) -> Float[np.ndarray, "t h 2 3"]:
        return self.keypoints


def fingertips_cam_to_obj(
    fingertips_cam: Float[Array, "t h 2 3"], T_cam_obj: Float[Array, "t 7"]
) -> Float[Array, "t h 2 3"]:
    """Express camera-frame fingertips (metres, OpenCV axes) in the object frame using the
    tracked object pose per frame (wxyz_xyz). NaNs stay NaN."""
    T_obj_cam = jaxlie.SE3(T_cam_obj).inverse()
    return jax.vmap(lambda T, k: T.apply(k))(T_obj_cam, fingertips_cam.reshape(fingertips_cam.shape[0], -1, 3)).reshape(fingertips_cam.shape)


class RankConfig(eqx.Module):
    """Part ranking options."""

    contact_sigma: float = 0.01
    """Length scale (metres) of the contact kernel exp(-d² / 2σ²) on the fingertip-to-part
    distance d."""
    frame_chunk: int = 16
    """Frames processed together in the distance kernel (bounds memory to chunk × hands × 2 ×
    parts × points)."""
    min_visible_frames: int = 1
    """Below this many frames with a visible hand, fall back to motion ranking."""
    adjacency_points: int = 512
    """Points per part (deterministic subsample) used to find adjacent parts."""
    base_part: int | None = None
    """Index of the base part (root of the motion tree); None = the part that moves least in the
    object frame (ties within `base_motion_tol`: the largest by convex-hull volume)."""
    base_motion_tol: float = 0.002
    """Metres of time-averaged RMS motion within which parts count as equally still when the
    base is chosen."""


class PartRanking(eqx.Module):
    """Ranked parts and (left, right) part pairs."""

    method: str = eqx.field(static=True)
    """"hands" (fingertip contact) or "motion" (fallback)."""
    part_order: Int[Array, " p"]
    """Part indices, most likely manipulated first."""
    part_score: Float[Array, " p"]
    """Score per part index (higher = more likely): log contact score for "hands", relative
    motion in metres for "motion"."""
    pair_order: Int[Array, "k 2"]
    """(left-hand part, right-hand part) pairs of distinct parts, best first; k = p(p-1)."""
    pair_score: Float[Array, " k"]
    """Score of each pair in `pair_order` (sum of the two sides' scores)."""
    contact_distance: Float[Array, "h p"]
    """Soft contact distance per hand and part, metres: σ·sqrt(-2 log s), s = time-weighted mean
    contact kernel; ≈ 0 when touching throughout, inf for an unseen hand. (0, p) without hands."""
    mean_distance: Float[Array, "h p"]
    """Time-weighted mean fingertip-to-part distance (RSRD's cost), metres."""
    relative_motion: Float[Array, " p"]
    """Time-weighted mean RMS displacement of each part relative to its parent part, metres."""
    parent: Int[Array, " p"]
    """Parent of each part in the adjacency tree rooted at the base part (-1 for the base)."""


def pad_part_points(
    part_points: Sequence[Float[np.ndarray, "_n 3"]],
) -> tuple[Float[np.ndarray, "p n 3"], Bool[np.ndarray, "p n"]]:
    """Stack per-part point sets of different sizes into a padded array and a validity mask
    (padded to a power of two ≥ 64 points, so that similar objects share compilations)."""
    if len(part_points) == 0:
        raise ValueError("part_points: need at least one part")
    n = max(64, 1 << (max(len(p) for p in part_points) - 1).bit_length())
    pts = np.zeros((len(part_points), n, 3), np.float32)
    mask = np.zeros((len(part_points), n), bool)
    for i, p in enumerate(part_points):
        p = np.asarray(p, np.float32)
        if p.ndim != 2 or p.shape[1] != 3 or len(p) == 0:
            raise ValueError(f"part_points[{i}]: expected shape (n>0, 3), got {p.shape}")
        pts[i, : len(p)] = p
        pts[i, len(p) :] = p[0]  # padding repeats a real point: harmless for min distances
        mask[i, : len(p)] = True
    return pts, mask


def _fingertip_distances(
    points: Float[Array, "p n 3"],
    mask: Bool[Array, "p n"],
    T_obj_part: Float[Array, "t p 7"],
    tips: Float[Array, "t h 2 3"],
    chunk: int,
) -> Float[Array, "t h 2 p"]:
    """Distance from each fingertip to the nearest point of each part, per frame (NaN tips give
    NaN)."""

    pts2 = jnp.sum(points**2, axis=-1)  # p n

    def frame(args):
        T, k = args
        # Distance in the part frame (rigid motions preserve it): move the tips, not the points.
        T_part_obj = jaxlie.SE3(T).inverse()
        k_part = jax.vmap(lambda Tp: Tp.apply(k.reshape(-1, 3)))(T_part_obj)  # p m 3
        # |k - x|² = |k|² + |x|² - 2 k·x as a matmul over all points.
        cross = jnp.einsum("pmd,pnd->pmn", k_part, points)
        d2 = jnp.sum(k_part**2, axis=-1)[:, :, None] + pts2[:, None, :] - 2.0 * cross
        d2 = jnp.where(mask[:, None, :], d2, jnp.inf)
        d = jnp.sqrt(jnp.maximum(jnp.min(d2, axis=-1), 0.0))  # p m
        return d.T.reshape(k.shape[:-1] + (points.shape[0],))

    return jax.lax.map(frame, (T_obj_part, tips), batch_size=chunk)


@eqx.filter_jit
def _contact_scores(
    points: Float[Array, "p n 3"],
    mask: Bool[Array, "p n"],
    T_obj_part: Float[Array, "t p 7"],
    tips: Float[Array, "t h 2 3"],
    frame_weights: Float[Array, " t"],
    sigma: Float[Array, ""],
    chunk: int,
) -> tuple[Float[Array, "h p"], Float[Array, "h p"], Bool[Array, " h"]]:
    """(log contact score, mean distance, hand seen) per hand and part."""
    d = _fingertip_distances(points, mask, T_obj_part, tips, chunk)  # t h 2 p
    tip_ok = jnp.isfinite(d)
    n_tips = jnp.sum(tip_ok, axis=2)  # t h p
    # Mean over the visible tips of a hand (RSRD averages thumb and index).
    d_hand = jnp.sum(jnp.where(tip_ok, d, 0.0), axis=2) / jnp.maximum(n_tips, 1)
    w = frame_weights[:, None, None] * (n_tips > 0)  # t h p
    wsum = jnp.sum(w, axis=0)
    seen = wsum[:, 0] > 0
    logk = -0.5 * (d_hand / sigma) ** 2
    # log of the weighted mean kernel, stable for far hands (no underflow to 0).
    log_s = jax.nn.logsumexp(jnp.where(w > 0, logk, -jnp.inf), axis=0, b=jnp.where(w > 0, w, 1.0)) - jnp.log(
        jnp.maximum(wsum, 1e-30)
    )
    log_s = jnp.where(seen[:, None], log_s, -jnp.inf)
    mean_d = jnp.where(seen[:, None], jnp.sum(w * d_hand, axis=0) / jnp.maximum(wsum, 1e-30), jnp.inf)
    return log_s, mean_d, seen


@eqx.filter_jit
def _relative_motion(
    points: Float[Array, "p n 3"],
    mask: Bool[Array, "p n"],
    T_obj_part: Float[Array, "t p 7"],
    parent: Int[Array, " p"],
    frame_weights: Float[Array, " t"],
) -> Float[Array, " p"]:
    """Time-weighted mean RMS displacement of each part's points in its parent's frame relative
    to frame 0 (the object frame for the root)."""
    ident = jaxlie.SE3.identity((T_obj_part.shape[0],))

    def rel(p):
        q = parent[p]
        Tq = jaxlie.SE3(jnp.where(q >= 0, T_obj_part[:, jnp.maximum(q, 0)], ident.wxyz_xyz))
        Tp = jaxlie.SE3(T_obj_part[:, p])
        T_rel = Tq.inverse() @ Tp  # t
        # Displacement of x under T_rel(t) relative to T_rel(0): (R_t - R_0) x + (t_t - t_0).
        dR = T_rel.rotation().as_matrix() - T_rel.rotation().as_matrix()[:1]  # t 3 3
        dt = T_rel.translation() - T_rel.translation()[:1]  # t 3
        disp = jnp.einsum("tij,nj->tni", dR, points[p]) + dt[:, None, :]
        disp2 = jnp.sum(disp**2, axis=-1)  # t n
        rms = jnp.sqrt(jnp.sum(jnp.where(mask[p][None], disp2, 0.0), -1) / jnp.sum(mask[p]))
        return jnp.sum(frame_weights * rms) / jnp.sum(frame_weights)

    return jax.vmap(rel)(jnp.arange(points.shape[0]))


def _largest_part(points: np.ndarray, mask: np.ndarray, candidates: np.ndarray) -> int:
    """Index of the candidate part with the largest convex-hull volume (point counts depend on
    how the points were sampled; size does not)."""
    vols = np.full(len(points), -1.0)
    for p in np.nonzero(candidates)[0]:
        x = points[p][mask[p]].astype(np.float64)
        try:
            vols[p] = scipy.spatial.ConvexHull(x).volume
        except (scipy.spatial.QhullError, ValueError):  # flat or too few points
            vols[p] = 0.0
    return int(np.argmax(vols))


def _adjacency_tree(
    points: np.ndarray, mask: np.ndarray, T0: np.ndarray, base: int, max_points: int
) -> np.ndarray:
    """Parent of each part: Prim's tree over inter-part distances at frame 0, rooted at base
    (each part hangs from the nearest part already in the tree)."""
    P = len(points)
    rng = np.random.default_rng(0)
    world = []
    for p in range(P):
        x = points[p][mask[p]]
        if len(x) > max_points:
            x = x[rng.choice(len(x), max_points, replace=False)]
        world.append(np.asarray(jaxlie.SE3(jnp.asarray(T0[p])).apply(jnp.asarray(x))))
    trees = [scipy.spatial.cKDTree(x) for x in world]
    D = np.zeros((P, P))
    for p in range(P):
        for q in range(p + 1, P):
            D[p, q] = D[q, p] = trees[q].query(world[p], k=1)[0].min()
    parent = -np.ones(P, np.int64)
    in_tree = np.zeros(P, bool)
    in_tree[base] = True
    for _ in range(P - 1):
        cand = np.where(in_tree[None, :] & ~in_tree[:, None], D, np.inf)  # rows: outside parts
        p, q = np.unravel_index(np.argmin(cand), cand.shape)
        parent[p] = q
        in_tree[p] = True
    return parent


def _pairs(score: np.ndarray, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    P = len(score)
    pairs = np.array([(a, b) for a in range(P) for b in range(P) if a != b], np.int64).reshape(-1, 2)
    s = left[pairs[:, 0]] + right[pairs[:, 1]]
    order = np.lexsort((pairs[:, 1], pairs[:, 0], -s)) if len(pairs) else np.zeros(0, np.int64)
    return pairs[order], s[order]


def rank_parts(
    part_points: Sequence[Float[np.ndarray, "_n 3"]],
    T_obj_part: Float[np.ndarray, "t p 7"],
    hands: HandKeypointSource | Float[np.ndarray, "t h 2 3"] | None = None,
    frame_weights: Float[np.ndarray, " t"] | None = None,
    config: RankConfig = RankConfig(),
) -> PartRanking:
    """Rank the parts (and left/right part pairs) by how likely the demonstrator manipulated them.

    With hands: for every frame, hand and part, d = mean over the visible fingertips (thumb,
    index) of the distance to the part's nearest point (points moved by the part pose). The
    contact score of a hand and part is the time-weighted mean of exp(-d²/2σ²) over frames
    where the hand is seen (weights `frame_weights` × visibility); parts rank by the log of the
    sum over hands, pairs (left part, right part) by the sum of the left hand's log score on the
    left part and the right hand's on the right part. An unseen hand is uninformative (scores 0
    for every part). RSRD ranks by mean distance instead, which a long approach phase can
    dominate; `mean_distance` is returned too.

    Without hands (None, or fewer than `min_visible_frames` frames with a visible fingertip):
    rank by motion relative to the parent part. Parents come from an adjacency tree rooted at
    the base part: a part attached to a moving part moves with it, so measuring
    each part relative to the adjacent part it hangs from credits the part that really moved
    relative to its neighbour, not everything downstream of it. The base part is the one that
    moves least in the object frame (the largest among near-ties) unless `config.base_part`
    says otherwise; relative motion between two parts is symmetric, so this is what decides
    which of two jointed parts "moved". Pairs score the sum of both
    parts' motion, in both orders (left/right is unknown without hands).

    Args:
        part_points: P point sets (part frame, metres), e.g. Gaussian centres per part.
        T_obj_part: T×P×7 part poses in the object frame (wxyz_xyz).
        hands: HandKeypointSource, or its T×H×2×3 array (object frame, NaN = not visible; H = 1
            or 2, hand 0 left, 1 right; a single hand counts as the left one for pairs), or None.
        frame_weights: T non-negative frame weights (default all 1).
        config: options.

    Returns:
        PartRanking.
    """
    pts, mask = pad_part_points(part_points)
    T_np = np.asarray(T_obj_part, np.float32)
    P = len(pts)
    if T_np.ndim != 3 or T_np.shape[1:] != (P, 7):
        raise ValueError(f"T_obj_part: expected shape (t, {P}, 7), got {T_np.shape}")
    nT = T_np.shape[0]
    w = np.ones(nT, np.float32) if frame_weights is None else np.asarray(frame_weights, np.float32)
    if w.shape != (nT,) or np.any(w < 0) or not np.any(w > 0):
        raise ValueError(f"frame_weights: expected {nT} non-negative weights, not all zero")
    # Pad frames to a multiple of frame_chunk (repeated last pose, weight 0, no hands) so that
    # demos of similar length share compilations.
    nT_pad = -(-nT // config.frame_chunk) * config.frame_chunk
    T_np = np.concatenate([T_np, np.repeat(T_np[-1:], nT_pad - nT, axis=0)])
    w = np.concatenate([w, np.zeros(nT_pad - nT, np.float32)])
    args = (jnp.asarray(pts), jnp.asarray(mask), jnp.asarray(T_np))
    if config.base_part is None:
        # The base: the part that moves least in the object frame; among near-ties, the largest.
        absolute = np.asarray(_relative_motion(*args, jnp.full((P,), -1, jnp.int32), jnp.asarray(w)))
        still = absolute <= absolute.min() + config.base_motion_tol
        base = _largest_part(pts, mask, still)
    else:
        base = config.base_part
    if not 0 <= base < P:
        raise ValueError(f"config.base_part: {base} not in [0, {P})")

    parent = _adjacency_tree(pts, mask, T_np[0], base, config.adjacency_points)
    motion = _relative_motion(*args, jnp.asarray(parent, jnp.int32), jnp.asarray(w))
    motion_np = np.asarray(motion)

    tips = None
    if hands is not None:
        tips = np.asarray(hands.fingertips_obj() if isinstance(hands, HandKeypointSource) else hands, np.float32)
        if tips.ndim != 4 or tips.shape[0] != nT or tips.shape[2:] != (2, 3) or tips.shape[1] not in (1, 2):
            raise ValueError(f"hands: expected shape ({nT}, 1|2, 2, 3), got {tips.shape}")
        tips = np.concatenate([tips, np.full((nT_pad - nT,) + tips.shape[1:], np.nan, np.float32)])
        visible = np.isfinite(tips).all(-1).any(-1).any(-1) & (w > 0)
        if visible.sum() < config.min_visible_frames:
            tips = None

    if tips is None:
        order = np.lexsort((np.arange(P), -motion_np))
        pairs, pair_s = _pairs(motion_np, motion_np, motion_np)
        empty = jnp.zeros((0, P), jnp.float32)
        return PartRanking(
            "motion", jnp.asarray(order), motion, jnp.asarray(pairs), jnp.asarray(pair_s), empty, empty,
            motion, jnp.asarray(parent),
        )

    log_s, mean_d, seen = _contact_scores(
        jnp.asarray(pts), jnp.asarray(mask), jnp.asarray(T_np), jnp.asarray(tips), jnp.asarray(w),
        jnp.asarray(config.contact_sigma, jnp.float32), config.frame_chunk,
    )
    log_s_np = np.asarray(log_s)
    informative = np.where(np.asarray(seen)[:, None], log_s_np, 0.0)
    single = np.asarray(jax.nn.logsumexp(jnp.asarray(log_s_np), axis=0))
    # Ties (e.g. every part far from every fingertip) fall back to the RSRD mean distance.
    order = np.lexsort((np.arange(P), np.asarray(mean_d).min(0), -single))
    left = informative[LEFT]
    right = informative[RIGHT] if tips.shape[1] == 2 else np.zeros(P)
    pairs, pair_s = _pairs(single, left, right)
    contact_distance = config.contact_sigma * jnp.sqrt(-2.0 * jnp.minimum(log_s, 0.0))
    return PartRanking(
        "hands", jnp.asarray(order), jnp.asarray(single), jnp.asarray(pairs), jnp.asarray(pair_s),
        contact_distance, mean_d, motion, jnp.asarray(parent),
    )
