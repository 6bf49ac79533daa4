"""Pictures of a studio object: contact sheet and rerun recording."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..geometry import backproject_depth, se3_from_wxyz_xyz
from ..io import read_capture, read_demo, read_demo_gt, read_depth_png, read_image_rgb, read_json
from ._sheet import colorize_depth, colorize_labels, save_contact_sheet


def studio_contact_sheet(root: str | Path, out_png: str | Path, scan_views: int = 6, demo_frames: int = 6) -> Path:
    """A PNG of scan views (RGB, depth, part labels), demo frames and the robot view of a studio object."""
    root = Path(root)
    images, labels = [], []
    if (root / "scan").is_dir():
        cap = read_capture(root / "scan")
        for i in map(int, np.linspace(0, len(cap) - 1, scan_views)):
            images += [cap.image(i), colorize_depth(cap.depth(i)), colorize_labels(cap.part_mask(i))]
            labels += [f"scan {i}", f"depth {i}", f"parts {i}"]
    if (root / "demo").is_dir():
        demo = read_demo(root / "demo" / "demo.mp4")
        for t in map(int, np.linspace(0, demo.num_frames - 1, demo_frames)):
            images.append(demo.frames[t])
            labels.append(f"demo t={t}")
    if (root / "robot_view").is_dir():
        images += [read_image_rgb(root / "robot_view" / "rgb.png"), colorize_depth(read_depth_png(root / "robot_view" / "depth.png"))]
        labels += ["robot view", "robot depth"]
    return save_contact_sheet(out_png, images, labels)


def log_studio(root: str | Path, rrd_path: str | Path, max_points: int = 20000) -> Path:
    """Writes a rerun recording of a studio object: scan cameras and images, fused depth point
    cloud, the demo video and the ground-truth part poses over time."""
    import rerun as rr

    root = Path(root)
    meta = read_json(root / "object.json", "studio object.json")
    rec = rr.RecordingStream(f"rsrd_jax_studio_{meta['name']}")
    rrd_path = Path(rrd_path)
    tmp = rrd_path.with_name(f".{rrd_path.name}.tmp")
    rec.save(str(tmp))
    rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rng = np.random.default_rng(0)
    if (root / "scan").is_dir():
        cap = read_capture(root / "scan")
        K = np.asarray(cap.intrinsics.K())
        pts_all, col_all = [], []
        for i in range(len(cap)):
            T_wc = np.linalg.inv(cap.frames[i].T_cam_world)
            path = f"scan/cam{i:03d}"
            rec.log(path, rr.Transform3D(translation=T_wc[:3, 3], mat3x3=T_wc[:3, :3]), static=True)
            rec.log(path, rr.Pinhole(image_from_camera=K, width=cap.intrinsics.width, height=cap.intrinsics.height,
                                     camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.03), static=True)  # fmt: skip
            if i % 8 == 0:
                rec.log(f"{path}/image", rr.Image(cap.image(i)).compress(), static=True)
            d = cap.depth(i)
            m = (d > 0) & (cap.part_mask(i) > 0)
            p_cam = np.asarray(backproject_depth(cap.intrinsics, d))[m]
            pts_all.append(p_cam @ T_wc[:3, :3].T + T_wc[:3, 3])
            col_all.append(cap.image(i)[m])
        pts, cols = np.concatenate(pts_all), np.concatenate(col_all)
        keep = rng.choice(len(pts), min(max_points, len(pts)), replace=False)
        rec.log("scan/points", rr.Points3D(pts[keep], colors=cols[keep], radii=0.0008), static=True)
    if (root / "demo").is_dir():
        demo = read_demo(root / "demo" / "demo.mp4")
        gt = read_demo_gt(root / "demo")
        with np.load(root / "scan" / "gt" / "scan_gt.npz") as z:
            part_pts, part_ids = z["part_points"], z["part_point_ids"]
        T_wp = np.asarray(se3_from_wxyz_xyz(gt["T_world_part"]).as_matrix())
        T_cw = np.asarray(se3_from_wxyz_xyz(gt["T_cam_world"]).as_matrix())
        T_wc = np.linalg.inv(T_cw)
        rec.log("demo/camera", rr.Transform3D(translation=T_wc[:3, 3], mat3x3=T_wc[:3, :3]), static=True)
        rec.log("demo/camera", rr.Pinhole(image_from_camera=np.asarray(demo.intrinsics.K()), width=demo.intrinsics.width,
                                          height=demo.intrinsics.height, camera_xyz=rr.ViewCoordinates.RDF,
                                          image_plane_distance=0.05), static=True)  # fmt: skip
        palette = colorize_labels(np.arange(1, 64)[None])[0]
        for t in range(demo.num_frames):
            rec.set_time("frame", sequence=t)
            rec.log("demo/camera/image", rr.Image(demo.frames[t]).compress())
            for k in range(T_wp.shape[1]):
                rec.log(f"demo/parts/{k}", rr.Transform3D(translation=T_wp[t, k, :3, 3], mat3x3=T_wp[t, k, :3, :3]))
                if t == 0:
                    pk = part_pts[part_ids == k]
                    rec.log(f"demo/parts/{k}/points", rr.Points3D(pk, colors=palette[k], radii=0.0008), static=True)
            kp = gt["keypoints_world"][t].reshape(-1, 3)
            rec.log("demo/fingertips", rr.Points3D(kp, colors=[255, 60, 60], radii=0.004))
    rec.flush()
    del rec
    tmp.replace(rrd_path)
    return rrd_path
