"""Hand anchors: which part point each demonstrator's hand pinches, for the tracker's hand term.

A hand moves with the part it pinches, and it is what hides that part from the feature loss
(the occluder mask removes hand pixels). The pinch point of a hand is the midpoint of its
detected thumb and index tips: the fingers sit on either side of the pinched part, so the
midpoint is the image of a point inside it (a fingertip alone is a finger radius or more off
the surface, in depth too, which biases the part's rotation as it turns: on the studio red box a
per-fingertip anchor took the lid from 14 to 24 mm). A hand is anchored on the first frame where
the render about its pinch point is at least half opaque (at the pinch point or at one of six
points around it, half `radius` feature cells out: a thin part seen a little off, as a
sunglasses arm, covers only some of them): the part the render shows there (its share of the
blend weights summed over the seven points) holds it, and the held point is the
opacity-weighted mean of that part's Gaussians projecting within `radius` cells (part frame: the
centre of the part's cross-section along the ray, since a 2D detection does not give the
depth). Judged by the Gaussians projecting near the pinch point instead
(`TrackConfig.hand_anchor_by="opacity"`), a dense part behind the pinched one can outweigh it: on
a rebuilt usb_plug model the plug's hand went to the brick. From the next frame
on the hand term (`hand_loss`) pulls that point's projection onto the pinch point. Anchors are
kept for the rest of the video: a release (the hand letting go) is not detected; the robust loss
bounds the pull of a hand that moved away.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from ..geometry import Camera, project_points
from ..splat import apply_part_poses, blend_weights, project_gaussians
from ._dpm import FrameObs


@dataclasses.dataclass
class HandAnchors:
    """Host-side anchor state of a video's hands (k = hands per frame)."""

    part: np.ndarray
    """(k,) held part (−1: not anchored)."""
    point: np.ndarray
    """(k, 3) held point in the part's frame, metres."""
    frame: np.ndarray
    """(k,) frame on which each hand was anchored (−1: not anchored)."""
    surface: np.ndarray | None = None
    """(k, 3) the held part's visible surface at the pinch point, in the part's frame (metres):
    the nearest quarter of the anchoring Gaussians. The hand depth term (`hand_depth_loss`)
    places it at the depth the mono-depth gives the pinch point, which sees the part's surface
    between the fingers, not the held point inside it. None: `point`."""

    @staticmethod
    def empty(k: int) -> HandAnchors:
        return HandAnchors(-np.ones(k, np.int64), np.zeros((k, 3)), -np.ones(k, np.int64), np.zeros((k, 3)))

    @property
    def anchored(self) -> np.ndarray:
        return self.part >= 0

    def summary(self) -> list[dict]:
        """Per hand: part, frame and point (mm) of its anchor, for the trajectory's metadata."""
        return [
            {"part": int(p), "frame": int(f), "point_mm": [round(float(v) * 1e3, 2) for v in x]} if p >= 0 else {"part": None}
            for p, f, x in zip(self.part, self.frame, self.point)
        ]


def with_hand_anchors(obs: FrameObs, anchors: HandAnchors) -> FrameObs:
    """`obs` with the anchors' parts and points and the hand term's weights (detected in this
    frame and anchored)."""
    a = anchors.anchored
    surface = anchors.point if anchors.surface is None else anchors.surface
    return eqx.tree_at(lambda o: (o.hand_part, o.hand_point, o.hand_surface, o.hand_weight), obs,
                       (jnp.asarray(np.where(a, anchors.part, 0), jnp.int32), jnp.asarray(anchors.point, jnp.float32),
                        jnp.asarray(surface, jnp.float32), jnp.asarray(np.asarray(obs.hand_seen) * a, jnp.float32)))  # fmt: skip


def update_hand_anchors(
    anchors: HandAnchors,
    tm,
    T_obj_part: jaxlie.SE3,
    T_cam_obj: jaxlie.SE3,
    obs: FrameObs,
    t: int,
    radius_cells: float,
    min_gaussians: int = 3,
    anchor_by: str = "visible",
    min_alpha: float = 0.5,
) -> HandAnchors:
    """Anchors every hand detected in `obs` that has no anchor yet, at the solved part poses
    `T_obj_part` of frame `t` (see the module docstring). `tm` is a `TrackModel` (its
    `gaussians`, `part_centroids` and `num_parts` are used). Returns a new `HandAnchors`."""
    if anchor_by not in ("visible", "opacity"):
        raise ValueError(f"anchor_by must be 'visible' or 'opacity', got {anchor_by!r}")
    seen = np.asarray(obs.hand_seen) > 0
    todo = seen & ~anchors.anchored
    if not todo.any():
        return anchors
    posed = apply_part_poses(tm.gaussians, T_obj_part, tm.part_centroids)
    uv, z = project_points(obs.intrinsics, T_cam_obj @ posed.means)
    uv, z = np.asarray(uv, np.float64), np.asarray(z)
    ids = np.asarray(tm.gaussians.part_ids)
    op = np.asarray(jax.nn.sigmoid(tm.gaussians.opacity_logits), np.float64)
    local = np.asarray(tm.gaussians.means, np.float64) - np.asarray(tm.part_centroids, np.float64)[ids]
    tips = np.asarray(obs.hand_uv, np.float64)
    if anchor_by == "visible":
        # what the render shows under each pinch point: blend weights at the point and at six
        # around it, half the radius out (a pinch detection is a point of a few pixels' accuracy)
        ring = 0.5 * radius_cells * np.stack([np.cos(np.arange(6) * np.pi / 3), np.sin(np.arange(6) * np.pi / 3)], -1)
        spots = np.concatenate([np.zeros((1, 2)), ring])
        proj = project_gaussians(posed, Camera(obs.intrinsics, T_cam_obj))
    surface = anchors.point.copy() if anchors.surface is None else anchors.surface.copy()
    out = HandAnchors(anchors.part.copy(), anchors.point.copy(), anchors.frame.copy(), surface)
    for k in np.flatnonzero(todo):
        if anchor_by == "visible":
            w = blend_weights(proj, tips[k] + spots)
            if w.sum(1).max() < min_alpha:  # the render is not half opaque anywhere about the pinch
                continue
            share = np.bincount(ids, weights=w.sum(0), minlength=tm.num_parts)
        near = (np.linalg.norm(uv - tips[k], axis=1) < radius_cells) & (z > 0) & (op > 0.05)
        if near.sum() < min_gaussians:
            continue
        if anchor_by == "opacity":
            share = np.bincount(ids[near], weights=op[near], minlength=tm.num_parts)
        p = int(np.argmax(share))
        sel = near & (ids == p)
        if not sel.any():
            continue
        out.part[k] = p
        out.point[k] = np.average(local[sel], axis=0, weights=op[sel])
        front = sel & (z <= np.quantile(z[sel], 0.25))
        out.surface[k] = np.average(local[front], axis=0, weights=op[front])
        out.frame[k] = t
    return out


def surface_depths(tm, T_obj_part: jaxlie.SE3, T_cam_obj: jaxlie.SE3, anchors: HandAnchors) -> np.ndarray:
    """(k,) camera depth (m) of each anchored hand's surface point (`HandAnchors.surface`) at the
    part poses `T_obj_part`; NaN for hands not anchored."""
    surface = anchors.point if anchors.surface is None else anchors.surface
    parts = np.where(anchors.anchored, anchors.part, 0)
    T = jaxlie.SE3(jnp.asarray(T_obj_part.wxyz_xyz)[parts])
    z = np.asarray((T_cam_obj @ (T @ jnp.asarray(surface, jnp.float32)))[:, 2], np.float64)
    return np.where(anchors.anchored, z, np.nan)


def with_hand_depth_offset(obs: FrameObs, offset: np.ndarray) -> FrameObs:
    """`obs` with each hand's depth read off the table (`Observer.hand_depths`) shifted by that
    hand's `offset` (m; see `track_video`'s hand depth calibration), and unknown where the offset
    is (NaN)."""
    known = np.isfinite(offset)
    return eqx.tree_at(lambda o: (o.hand_depth, o.hand_depth_seen), obs,
                       (obs.hand_depth + jnp.asarray(np.where(known, offset, 0.0), jnp.float32),
                        obs.hand_depth_seen * jnp.asarray(known, jnp.float32)))  # fmt: skip
