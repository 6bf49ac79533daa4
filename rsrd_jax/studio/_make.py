"""Generates a studio object's scan, demo video and robot view, with ground truth.

Output layout of `make_object(name, out)`:
    object.json              what was made: parts, joints, contacts, sizes, config, timings
    mjcf/object.xml (+ PNGs) the object's MJCF (real joints) for simulation
    scan/transforms.json     nerfstudio capture: images/, depth/ (16-bit mm), masks/ (255 = object,
                             0 = ignore), part_masks/ (0 background, k+1 = part k)
    scan/gt/scan_gt.npz      true T_cam_world (V×4×4, before pose noise), T_world_part (P×7 rest),
                             part surface points (part frame) + their part ids
    demo/demo.mp4, camera.json
    demo/gt/part_poses.npz   T_obj_part, T_world_part, T_cam_world_part (T×P×7 wxyz_xyz),
                             T_cam_world (7, demo camera), T_demo_scan (7: scan world -> demo world)
    demo/gt/depth/, hand_mask/, part_mask/ (per-frame PNGs), hand_keypoints.npz
    robot_view/rgb.png, depth.png, camera.json (intrinsics + T_robot_cam), gt.json
"""

from __future__ import annotations

import time
from pathlib import Path

import equinox as eqx
import jaxlie
import numpy as np
from tqdm.auto import tqdm

from ..geometry import Intrinsics, look_at
from ..io import (
    atomic_replace_dir,
    atomic_write_bytes,
    atomic_write_image,
    atomic_write_json,
    atomic_write_npz,
    atomic_write_text,
    write_camera_json,
    write_depth_png,
    write_label_png,
    write_transforms,
    write_video,
)
from ._catalog import get_object
from ._scene import HAND_LABEL, FINGER_RADIUS, SceneOptions, StudioScene, build_scene, part_surface_points
from ._spec import StudioObject, object_mjcf

ROBOT_CAMERA_EYE = (0.85, 0.0, 0.42)
"""Robot-view camera position in the robot base frame (metres): in front of the YuMi, facing it."""
ROBOT_CAMERA_TARGET = (0.45, 0.0, 0.03)
"""Point the robot-view camera looks at (robot base frame)."""
TABLE_HEIGHT = 0.0
"""Table top height in the robot base frame: the YuMi stands on the table (z = 0)."""


class StudioConfig(eqx.Module):
    """Options of `make_object`; everything is deterministic for a seed."""

    seed: int = 0
    """Seed for textures, camera jitter, placements and clutter."""
    scan_views: int = 48
    """Number of scan views on the hemisphere around the object."""
    scan_size: tuple[int, int] = (320, 240)
    """Scan image width, height in pixels."""
    scan_fovy_deg: float = 50.0
    """Scan camera vertical field of view, degrees."""
    pose_noise_deg: float = 0.0
    """Std of the rotation noise added to the written scan poses (degrees), like a phone scan."""
    pose_noise_m: float = 0.0
    """Std of the translation noise added to the written scan poses (metres)."""
    demo_frames: int | None = None
    """Frames of the demo video (default: the object's own, 90–120)."""
    demo_size: tuple[int, int] = (320, 240)
    """Demo video width, height in pixels."""
    demo_fovy_deg: float = 50.0
    """Demo camera vertical field of view, degrees."""
    demo_yaw_deg: float | None = None
    """Object yaw in the demo scene relative to the scan (default: seeded, within ±60°)."""
    fps: float = 30.0
    """Demo frame rate."""
    robot_size: tuple[int, int] = (640, 360)
    """Robot-view (ZED-like) image width, height."""
    robot_fovy_deg: float = 50.0
    """Robot-view camera vertical field of view, degrees."""
    robot_object_xy: tuple[float, float] = (0.45, 0.0)
    """Object root position on the table in the robot base frame (metres)."""
    robot_object_yaw_deg: float | None = None
    """Object yaw on the table (default: seeded, full circle)."""
    clutter: bool = False
    """Scatter distractor boxes around the object."""
    lighting: float = 1.0
    """Light intensity multiplier."""
    parts: tuple[str, ...] = ("scan", "demo", "robot_view")
    """Which products to make."""


def _placement(obj: StudioObject, seed: int) -> np.ndarray:
    """Root pose that puts the object's lowest point at rest on z = 0."""
    with build_scene(obj, np.eye(4), SceneOptions(32, 32, 45.0, seed)) as sc:
        pts = _world_points(sc, 200)
    T = np.eye(4)
    T[2, 3] = -pts[:, 2].min()
    return T


def _world_points(scene: StudioScene, n: int) -> np.ndarray:
    T = scene.part_poses()
    out = []
    for k, b in enumerate(scene.body_ids):
        p = part_surface_points(scene.model, b, n, k)
        out.append(p @ T[k, :3, :3].T + T[k, :3, 3])
    return np.concatenate(out)


def _wxyz_xyz(T: np.ndarray) -> np.ndarray:
    T = np.asarray(T, np.float64)
    return np.asarray(jaxlie.SE3.from_matrix(T.astype(np.float32)).wxyz_xyz, np.float64)


def _to7(T: np.ndarray) -> np.ndarray:
    """…×4×4 -> …×7 wxyz_xyz (float64, via MuJoCo's exact conversion)."""
    import mujoco

    T = np.asarray(T, np.float64)
    flat = T.reshape(-1, 4, 4)
    out = np.zeros((len(flat), 7))
    for i, M in enumerate(flat):
        mujoco.mju_mat2Quat(out[i, :4], M[:3, :3].reshape(9))
        out[i, 4:] = M[:3, 3]
    return out.reshape(T.shape[:-2] + (7,))


def _intrinsics(size: tuple[int, int], fovy_deg: float) -> Intrinsics:
    return Intrinsics.from_fov(np.deg2rad(fovy_deg), int(size[0]), int(size[1]))


def _look(eye, target) -> np.ndarray:
    return np.asarray(look_at(eye, target).as_matrix(), np.float64)


def make_scan(obj: StudioObject, out: Path, cfg: StudioConfig, T_world_root: np.ndarray) -> dict:
    """Renders the multi-view scan at the object's start configuration into `out`."""
    K = _intrinsics(cfg.scan_size, cfg.scan_fovy_deg)
    opts = SceneOptions(K.width, K.height, cfg.scan_fovy_deg, cfg.seed, clutter=cfg.clutter, lighting=cfg.lighting)
    rng = np.random.default_rng(cfg.seed + 1)
    with build_scene(obj, T_world_root, opts) as scene:
        scene.set_configuration(0.0)
        pts = _world_points(scene, 400)
        centre = 0.5 * (pts.min(0) + pts.max(0))
        radius = float(np.linalg.norm(pts - centre, axis=1).max())
        dist = radius / (0.72 * np.tan(np.deg2rad(cfg.scan_fovy_deg) / 2))
        golden = np.pi * (3 - np.sqrt(5))
        lo, hi = np.sin(np.deg2rad(12)), np.sin(np.deg2rad(75))
        T_true, T_noisy, files = [], [], []
        for i in tqdm(range(cfg.scan_views), desc=f"{obj.name}: scan", leave=False):
            el = np.arcsin(lo + (hi - lo) * (i + 0.5) / cfg.scan_views)
            az = i * golden
            eye = centre + dist * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
            T = _look(eye, centre + rng.normal(0, 0.05 * radius, 3))
            scene.set_camera(T)
            rgb, depth, labels = scene.render()
            name = f"{i:05d}.png"
            atomic_write_image(out / "images" / name, rgb)
            write_depth_png(out / "depth" / name, depth)
            write_label_png(out / "masks" / name, np.where(labels > 0, 255, 0).astype(np.uint8))
            write_label_png(out / "part_masks" / name, labels)
            files.append({
                "file_path": f"images/{name}", "depth_file_path": f"depth/{name}",
                "mask_path": f"masks/{name}", "part_mask_path": f"part_masks/{name}",
            })  # fmt: skip
            T_true.append(T)
            noise = np.concatenate([rng.normal(0, cfg.pose_noise_m, 3), rng.normal(0, np.deg2rad(cfg.pose_noise_deg), 3)])
            T_noisy.append(np.asarray(jaxlie.SE3.exp(noise.astype(np.float32)).as_matrix(), np.float64) @ T)
        T_wp = scene.part_poses()
        # ground-truth surface samples: only the visible hull (a leg's capsule end buried in the
        # body would otherwise claim the body's surface next to it for the leg)
        pts_part = scene.exterior_part_points(1500, cfg.seed)
        ids = [np.full(len(p), k, np.int32) for k, p in enumerate(pts_part)]
    write_transforms(
        out, K, np.stack(T_noisy), files,
        extra={"studio_object": obj.name, "applied_transform": np.eye(4)[:3].tolist(), "units": "metres"},
    )  # fmt: skip
    atomic_write_npz(
        out / "gt" / "scan_gt.npz",
        T_cam_world=np.stack(T_true),
        T_world_part=_to7(T_wp),
        part_points=np.concatenate(pts_part),
        part_point_ids=np.concatenate(ids),
    )
    return {"views": cfg.scan_views, "size": list(cfg.scan_size), "camera_distance_m": round(float(dist), 4), "object_radius_m": round(radius, 4)}


def make_demo(obj: StudioObject, out: Path, cfg: StudioConfig, T_world_root: np.ndarray) -> dict:
    """Renders the demonstration video (proxy hands, static camera) with ground truth into `out`."""
    K = _intrinsics(cfg.demo_size, cfg.demo_fovy_deg)
    rng = np.random.default_rng(cfg.seed + 2)
    yaw = np.deg2rad(cfg.demo_yaw_deg) if cfg.demo_yaw_deg is not None else rng.uniform(-np.pi / 3, np.pi / 3)
    T_demo_scan = np.eye(4)
    T_demo_scan[:3, :3] = np.asarray(jaxlie.SO3.from_z_radians(float(yaw)).as_matrix(), np.float64)
    T_demo_scan[:2, 3] = rng.uniform(-0.05, 0.05, 2)
    T_demo_root = T_demo_scan @ T_world_root
    n = cfg.demo_frames or obj.num_frames
    opts = SceneOptions(K.width, K.height, cfg.demo_fovy_deg, cfg.seed, hands=True, clutter=cfg.clutter, lighting=cfg.lighting)
    with build_scene(obj, T_demo_root, opts) as scene:
        scene.set_configuration(0.0)
        T_world_part_rest = scene.part_poses()  # at the scan configuration, in the demo world
        # frame the whole motion: object points over the demo
        pts = []
        for s in np.linspace(0, 1, 7):
            scene.set_configuration(float(s))
            pts.append(_world_points(scene, 80))
        pts = np.concatenate(pts)
        centre = 0.5 * (pts.min(0) + pts.max(0))
        radius = float(np.linalg.norm(pts - centre, axis=1).max())
        dist = radius / (0.55 * np.tan(np.deg2rad(cfg.demo_fovy_deg) / 2))
        az = -np.pi / 2 + yaw + rng.uniform(-0.5, 0.5)  # roughly facing the object's front (−y)
        el = np.deg2rad(rng.uniform(28, 42))
        eye = centre + dist * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        T_cam_world = _look(eye, centre)
        scene.set_camera(T_cam_world)
        frames = np.zeros((n, K.height, K.width, 3), np.uint8)
        T_world_part = np.zeros((n, obj.num_parts, 4, 4))
        tips_w = np.zeros((n, len(obj.contacts), 2, 3))
        for t in tqdm(range(n), desc=f"{obj.name}: demo", leave=False):
            scene.set_configuration(t / max(n - 1, 1))
            rgb, depth, labels = scene.render()
            frames[t] = rgb
            T_world_part[t] = scene.part_poses()
            tips_w[t] = scene.fingertips()
            name = f"{t:05d}.png"
            write_depth_png(out / "gt" / "depth" / name, depth)
            write_label_png(out / "gt" / "hand_mask" / name, np.where(labels == HAND_LABEL, 255, 0).astype(np.uint8))
            write_label_png(out / "gt" / "part_mask" / name, np.where(labels == HAND_LABEL, 0, labels).astype(np.uint8))
            uv = _project(K, T_cam_world, tips_w[t].reshape(-1, 3))
            z = (tips_w[t].reshape(-1, 3) @ T_cam_world[:3, :3].T + T_cam_world[:3, 3])[:, 2]
            vis = np.zeros(len(uv), bool)
            for j, ((u, v), zj) in enumerate(zip(uv, z)):
                if 0 <= u < K.width and 0 <= v < K.height and zj > 0:
                    d = depth[int(v), int(u)]
                    vis[j] = d > 0 and d > zj - FINGER_RADIUS - 0.01
            if t == 0:
                kp_uv = np.zeros((n, len(obj.contacts), 2, 2))
                kp_vis = np.zeros((n, len(obj.contacts), 2), bool)
            kp_uv[t] = uv.reshape(-1, 2, 2)
            kp_vis[t] = vis.reshape(-1, 2)
    write_video(out / "demo.mp4", frames, cfg.fps)
    write_camera_json(out / "camera.json", K, extra={"fps": cfg.fps, "num_frames": n})
    T_obj = T_demo_root  # object frame = root part frame at the scan configuration
    T_obj_part = np.linalg.inv(T_obj)[None, None] @ T_world_part
    T_cam_world_part = T_cam_world[None, None] @ T_world_part @ np.linalg.inv(T_world_part_rest)[None] @ T_demo_scan[None, None]
    atomic_write_npz(
        out / "gt" / "part_poses.npz",
        T_obj_part=_to7(T_obj_part),
        T_world_part=_to7(T_world_part),
        T_cam_world_part=_to7(T_cam_world_part),
        T_cam_world=_to7(T_cam_world),
        T_world_obj=_to7(T_obj),
        T_demo_scan=_to7(T_demo_scan),
    )
    atomic_write_npz(
        out / "gt" / "hand_keypoints.npz",
        keypoints_world=tips_w,
        keypoints_uv=kp_uv,
        keypoints_visible=kp_vis,
        contact_parts=np.array([c.part for c in obj.contacts], np.int32),
    )
    return {"frames": n, "size": list(cfg.demo_size), "yaw_deg": round(float(np.rad2deg(yaw)), 2), "camera_distance_m": round(float(dist), 4)}


def make_robot_view(obj: StudioObject, out: Path, cfg: StudioConfig, T_world_root: np.ndarray) -> dict:
    """Renders the object on the table in front of the YuMi from the fixed ZED-like camera."""
    K = _intrinsics(cfg.robot_size, cfg.robot_fovy_deg)
    rng = np.random.default_rng(cfg.seed + 3)
    yaw = np.deg2rad(cfg.robot_object_yaw_deg) if cfg.robot_object_yaw_deg is not None else rng.uniform(-np.pi, np.pi)
    T_robot_root = np.eye(4)
    T_robot_root[:3, :3] = np.asarray(jaxlie.SO3.from_z_radians(float(yaw)).as_matrix(), np.float64)
    T_robot_root[:3, 3] = [cfg.robot_object_xy[0], cfg.robot_object_xy[1], TABLE_HEIGHT + T_world_root[2, 3]]
    T_robot_world = T_robot_root @ np.linalg.inv(T_world_root)
    opts = SceneOptions(K.width, K.height, cfg.robot_fovy_deg, cfg.seed, clutter=cfg.clutter, lighting=cfg.lighting, ground="table")
    T_cam_robot = _look(ROBOT_CAMERA_EYE, ROBOT_CAMERA_TARGET)
    with build_scene(obj, T_robot_root, opts) as scene:
        scene.set_configuration(0.0)
        scene.set_camera(T_cam_robot)
        rgb, depth, labels = scene.render()
    atomic_write_image(out / "rgb.png", rgb)
    write_depth_png(out / "depth.png", depth)
    write_label_png(out / "part_mask.png", labels)
    write_camera_json(
        out / "camera.json", K,
        extra={"T_robot_cam": _to7(np.linalg.inv(T_cam_robot)).tolist(), "T_robot_cam_matrix": np.linalg.inv(T_cam_robot).tolist(),
               "note": "T_robot_cam maps OpenCV camera-frame points into the robot base frame (wxyz_xyz)"},
    )  # fmt: skip
    atomic_write_json(
        out / "gt.json",
        {
            "T_robot_world": _to7(T_robot_world).tolist(),
            "T_robot_world_matrix": T_robot_world.tolist(),
            "T_robot_root": _to7(T_robot_root).tolist(),
            "yaw_deg": float(np.rad2deg(yaw)),
            "table_height_m": TABLE_HEIGHT,
            "note": "T_robot_world maps points of the scan's world frame into the robot base frame",
        },
    )
    return {"size": list(cfg.robot_size), "yaw_deg": round(float(np.rad2deg(yaw)), 2)}


def _project(K: Intrinsics, T_cam_world: np.ndarray, pts: np.ndarray) -> np.ndarray:
    pc = pts @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    z = np.where(np.abs(pc[:, 2]) < 1e-9, 1e-9, pc[:, 2])
    return np.stack([float(K.fx) * pc[:, 0] / z + float(K.cx), float(K.fy) * pc[:, 1] / z + float(K.cy)], 1)


def make_object(name: str, out: str | Path, cfg: StudioConfig = StudioConfig(), overwrite: bool = False) -> dict:
    """Makes a studio object's scan, demo and robot view (per `cfg.parts`) into directory `out`.

    The directory is built next to `out` and swapped in when complete. An existing `out` is
    replaced only with `overwrite=True`.

    Returns:
        The metadata written to `object.json` (parts, sizes, timings in seconds).
    """
    obj = get_object(name)  # KeyError naming the known objects
    out = Path(out)
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} exists; pass overwrite=True (CLI: --overwrite) to replace it")
    unknown = set(cfg.parts) - {"scan", "demo", "robot_view"}
    if unknown:
        raise ValueError(f"unknown studio products {sorted(unknown)}; expected scan, demo, robot_view")
    if cfg.scan_views < 1 or (cfg.demo_frames is not None and cfg.demo_frames < 2):
        raise ValueError("need scan_views ≥ 1 and demo_frames ≥ 2")
    meta: dict = {}

    def fill(tmp: Path) -> None:
        t0 = time.perf_counter()
        T_world_root = _placement(obj, cfg.seed)
        timings = {}
        products = {}
        makers = {"scan": make_scan, "demo": make_demo, "robot_view": make_robot_view}
        for product in cfg.parts:
            t = time.perf_counter()
            products[product] = makers[product](obj, tmp / product, cfg, T_world_root)
            timings[product] = time.perf_counter() - t
        asset_xml, body_xml, files = object_mjcf(obj, np.eye(4), cfg.seed)
        for fname, data in files.items():
            atomic_write_bytes(tmp / "mjcf" / fname, data)
        atomic_write_text(
            tmp / "mjcf" / "object.xml",
            f'<mujoco model="{obj.name}">\n  <compiler angle="radian"/>\n  <asset>\n    {asset_xml}\n  </asset>\n'
            f"  <worldbody>\n{body_xml}\n  </worldbody>\n</mujoco>\n",
        )
        timings["total"] = time.perf_counter() - t0
        meta.update(
            {
                "format": "rsrd_jax.studio/1",
                "name": obj.name,
                "description": obj.description,
                "seed": cfg.seed,
                "bimanual": obj.bimanual,
                "separable": obj.separable,
                "T_world_root": T_world_root.tolist(),
                "parts": [
                    {"index": k, "label": k + 1, "name": p.name, "joint": p.joint, "parent": p.parent,
                     "axis": list(p.axis), "range": list(p.range) if p.range else None}
                    for k, p in enumerate(obj.parts)
                ],  # fmt: skip
                "moving_parts": sorted(int(k) for k in obj.keyframes),
                "contacts": [{"part": c.part, "width_m": c.width} for c in obj.contacts],
                "config": {k: getattr(cfg, k) for k in cfg.__dataclass_fields__},
                "products": products,
                "timings_s": timings,
            }
        )
        atomic_write_json(tmp / "object.json", meta)

    atomic_replace_dir(out, fill)
    return meta
