"""Pictures of a tracked demo: overlay video and rerun recording."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from ..geometry import Camera, project_points
from ..io import write_video
from ..splat import apply_part_poses, choose_config, render
from ._sheet import colorize_labels


def _posed_renders(gaussians, centroids, traj, K, colour_by_part: bool):
    g = gaussians
    if colour_by_part:
        pal = jnp.asarray(colorize_labels(np.arange(1, 65)[None])[0] / 255.0, jnp.float32)
        g = jax.tree_util.tree_map(lambda x: x, g)
        import equinox as eqx

        g = eqx.tree_at(lambda x: x.colours, g, pal[g.part_ids])
    T0 = jaxlie.SE3(jnp.asarray(traj.T_obj_part[0], jnp.float32))
    Tc0 = jaxlie.SE3(jnp.asarray(traj.T_cam_obj[0], jnp.float32))
    cfg = choose_config(apply_part_poses(g, T0, centroids), Camera(K, Tc0), headroom=2.0)

    @jax.jit
    def one(Tp, Tc):
        posed = apply_part_poses(g, jaxlie.SE3(Tp), centroids)
        out = render(posed, Camera(K, jaxlie.SE3(Tc)), cfg)
        return out.rgb, out.alpha

    for t in range(traj.num_frames):
        yield one(jnp.asarray(traj.T_obj_part[t], jnp.float32), jnp.asarray(traj.T_cam_obj[t], jnp.float32))


def hand_anchor_pixels(traj, K) -> np.ndarray:
    """Image positions (T×A×2 pixels, NaN before a hand's anchor frame) of the part points the
    tracker's hand term anchored (`traj.meta["hand_anchors"]`) at the tracked poses."""
    anchors = [a for a in traj.meta.get("hand_anchors", []) if a.get("part") is not None]
    out = np.full((traj.num_frames, len(anchors), 2), np.nan)
    for i, a in enumerate(anchors):
        T = jaxlie.SE3(jnp.asarray(traj.T_cam_obj, jnp.float32)) @ jaxlie.SE3(jnp.asarray(traj.T_obj_part[:, a["part"]], jnp.float32))
        uv, z = project_points(K, T @ jnp.asarray(np.asarray(a["point_mm"]) * 1e-3, jnp.float32))
        uv = np.where((np.asarray(z) > 0)[:, None], np.asarray(uv, np.float64), np.nan)
        out[a["frame"]:, i] = uv[a["frame"]:]
    return out


def overlay_frames(model, traj, demo, colour_by_part: bool = True, max_gaussians: int = 20000) -> np.ndarray:
    """The demo frames with the tracked model blended on top (T×H×W×3 uint8); the part points
    the hand term anchored are drawn as white circles."""
    import cv2

    g = model.gaussians
    if g.num_gaussians > max_gaussians:
        keep = np.sort(np.random.default_rng(0).choice(g.num_gaussians, max_gaussians, replace=False))
        g = jax.tree_util.tree_map(lambda x: x[keep], g)
    centroids = jnp.asarray(model.part_centroids, jnp.float32)
    out = np.zeros_like(demo.frames)
    for t, (rgb, alpha) in enumerate(_posed_renders(g, centroids, traj, demo.intrinsics, colour_by_part)):
        a = 0.6 * np.clip(np.asarray(alpha), 0, 1)[..., None]
        out[t] = np.clip(demo.frames[t] * (1 - a) + 255 * np.clip(np.asarray(rgb), 0, 1) * a, 0, 255).astype(np.uint8)
    for t, pts in enumerate(hand_anchor_pixels(traj, demo.intrinsics)):
        for u, v in pts[np.isfinite(pts).all(1)]:
            cv2.circle(out[t], (int(u), int(v)), max(2, demo.intrinsics.width // 120), (255, 255, 255), 1, cv2.LINE_AA)
    return out


def write_overlay_video(model, traj, demo, path: str | Path, **kw) -> Path:
    """Writes the overlay of the tracked model on the demo as an mp4."""
    return write_video(path, overlay_frames(model, traj, demo, **kw), demo.fps)


def log_tracking(model, traj, demo, rrd_path: str | Path, overlay: np.ndarray | None = None) -> Path:
    """Rerun recording: the video (with overlay), the camera, and the 3D parts over time."""
    import rerun as rr

    rrd_path = Path(rrd_path)
    tmp = rrd_path.with_name(f".{rrd_path.name}.tmp")
    rec = rr.RecordingStream("rsrd_jax_track")
    rec.save(str(tmp))
    K = demo.intrinsics
    rec.log("camera", rr.Pinhole(image_from_camera=np.asarray(K.K()), width=K.width, height=K.height,
                                 camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.05), static=True)  # fmt: skip
    means = np.asarray(model.gaussians.means)
    ids = np.asarray(model.gaussians.part_ids)
    pal = colorize_labels(np.arange(1, 65)[None])[0]
    cents = np.asarray(model.part_centroids)
    for k in range(traj.num_parts):
        pk = means[ids == k][:: max(1, (ids == k).sum() // 3000)]
        rec.log(f"camera/object/part{k}/points", rr.Points3D(pk - cents[k], colors=pal[k], radii=0.0008), static=True)
    for i, a in enumerate(traj.meta.get("hand_anchors", [])):
        if a.get("part") is not None:  # the part point a hand pinches (tracking's hand term)
            rec.log(f"camera/object/part{a['part']}/hand{i}", rr.Points3D([np.asarray(a["point_mm"]) * 1e-3], colors=[255, 255, 255],
                                                                          radii=0.003), static=True)  # fmt: skip
    for t in range(traj.num_frames):
        rec.set_time("frame", sequence=t)
        rec.log("camera/image", rr.Image(overlay[t] if overlay is not None else demo.frames[t]).compress())
        Tco = np.asarray(jaxlie.SE3(jnp.asarray(traj.T_cam_obj[t], jnp.float32)).as_matrix())
        rec.log("camera/object", rr.Transform3D(translation=Tco[:3, 3], mat3x3=Tco[:3, :3]))
        for k in range(traj.num_parts):
            T = np.asarray(jaxlie.SE3(jnp.asarray(traj.T_obj_part[t, k], jnp.float32)).as_matrix())
            rec.log(f"camera/object/part{k}", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
        rec.log("residual", rr.Scalars(traj.residual[t]))
    rec.flush()
    del rec
    tmp.replace(rrd_path)
    return rrd_path
