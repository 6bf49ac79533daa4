"""Tracking initialisation on every studio demo's first frame, scored against ground truth.

For each object the studio scan and demo are made and the ObjectModel is built at the pipeline's
sizes (`PipelineConfig`, as `rsrd-jax demo` and the robot trials), then only the initialiser runs
on the demo's first frame (`rsrd_jax.track.initialize_demo`: locate the object by feature
contrast, per-seed distances, vmapped multi-seed optimisation, ROI refinement), with the studio's
hand masks and relative-depth oracle. Errors on frame 0, parts at rest:

- ADD (camera frame, mm): mean distance of the model's points under the estimated and the true pose;
- rotation error (degrees) of the object (its root part);
- centre error (pixels): the object centroid's projection, estimated against true;
- depth ratio: estimated / true distance of the centroid along the camera axis.

    python -m experiments.init_table [--objects frog bear ...] [--work DIR] [--out STEM] [--reuse]

Writes `<out>.md` and `<out>.json` (default `experiments/results/init_table`). Models are kept
in `--work` and reused with `--reuse` (a changed initialiser needs no rebuild).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import jax  # noqa: E402
import jaxlie  # noqa: E402
import numpy as np  # noqa: E402

from rsrd_jax.io import atomic_write_json, atomic_write_text, read_demo, read_demo_gt  # noqa: E402
from rsrd_jax.pipeline import PipelineConfig  # noqa: E402
from rsrd_jax.studio import StudioConfig, list_objects, make_object  # noqa: E402


def init_errors(T_est: np.ndarray, T_gt: np.ndarray, points: list[np.ndarray], K) -> dict:
    """Frame-0 errors of an estimated `T_cam_obj` (7,) against the true per-part poses `T_gt`
    (P, 7; each maps the part's scan-world points into the camera) for the model's points."""
    est = jaxlie.SE3(np.asarray(T_est, np.float64))
    add = []
    allp = np.concatenate(points)
    for k, p in enumerate(points):
        g = jaxlie.SE3(np.asarray(T_gt[k], np.float64))
        add.append(float(np.linalg.norm(np.asarray(est @ p) - np.asarray(g @ p), axis=-1).mean() * 1e3))
    g0 = jaxlie.SE3(np.asarray(T_gt[0], np.float64))
    rot = float(np.rad2deg(np.linalg.norm(np.asarray((g0.rotation().inverse() @ est.rotation()).log()))))
    c = allp.mean(0)
    ce, cg = np.asarray(est @ c), np.asarray(g0 @ c)
    uv = lambda x: np.array([K.fx * x[0] / x[2] + K.cx, K.fy * x[1] / x[2] + K.cy])  # noqa: E731
    return {"add_mm": float(np.mean(add)), "add_per_part_mm": [round(a, 2) for a in add], "rotation_deg": rot,
            "centre_px": float(np.linalg.norm(uv(ce) - uv(cg))), "depth_ratio": float(ce[2] / cg[2])}  # fmt: skip


def run(objects: list[str], cfg: PipelineConfig, work: Path, reuse: bool) -> dict:
    from rsrd_jax.parts import build_object_model, load_object_model, save_object_model
    from rsrd_jax.track import InitConfig, StudioDepthOracle, StudioHandMasks, initialize_demo

    rows = {}
    for name in objects:
        studio, model_dir = work / name / "studio", work / name / "model"
        if not (reuse and (studio / "demo" / "gt").is_dir()):
            make_object(name, studio, StudioConfig(seed=cfg.seed, scan_views=cfg.scan_views, scan_size=cfg.scan_size,
                                                   demo_frames=cfg.demo_frames, demo_size=cfg.demo_size,
                                                   parts=("scan", "demo")), overwrite=True)  # fmt: skip
        if not (reuse and (model_dir / "model.json").is_file()):
            save_object_model(build_object_model(studio / "scan", cfg.build_config(), progress=True), model_dir)
        model = load_object_model(model_dir)
        demo = read_demo(studio / "demo" / "demo.mp4")
        T, info = initialize_demo(model, demo, cfg.track_config(), InitConfig(iters=cfg.init_iters),
                                  StudioHandMasks(studio / "demo"), StudioDepthOracle(studio / "demo", seed=cfg.seed))  # fmt: skip
        gt = read_demo_gt(studio / "demo")
        pts = [np.asarray(model.part_points(k)) for k in range(model.num_parts)]
        err = init_errors(np.asarray(T.wxyz_xyz), gt["T_cam_world_part"][0], pts, demo.intrinsics)
        rows[name] = {**err, "init_s": round(info["init_s"], 2), "object_pixel": info.get("object_pixel"),
                      "region_cells": info.get("region_cells"), "best_seed": info.get("best_seed")}  # fmt: skip
        print(f"{name}: ADD {err['add_mm']:.1f} mm, rotation {err['rotation_deg']:.1f}°, centre {err['centre_px']:.1f} px, "
              f"depth ×{err['depth_ratio']:.2f}, {info['init_s']:.1f} s", flush=True)  # fmt: skip
        jax.clear_caches()
    return rows


def markdown(rows: dict, note: str = "") -> str:
    lines = ["| object | ADD (mm, camera frame) | rotation (°) | centre (px) | depth ratio | init (s) |",
             "|---|---|---|---|---|---|"]  # fmt: skip
    for n, r in rows.items():
        lines.append(f"| {n} | {r['add_mm']:.1f} | {r['rotation_deg']:.1f} | {r['centre_px']:.1f} | {r['depth_ratio']:.2f} | {r['init_s']:.1f} |")
    a = np.array([r["add_mm"] for r in rows.values()])
    rot = np.array([r["rotation_deg"] for r in rows.values()])
    lines.append(f"| **mean / median** | {a.mean():.1f} / {np.median(a):.1f} | {rot.mean():.1f} / {np.median(rot):.1f} | | | |")
    lines += ["", "Frame 0 of each studio demo, parts at rest; the studio's hand masks and relative-depth oracle; "
              "init times include each model size's compilation (the first object also pays the extractor's)."]  # fmt: skip
    if note:
        lines += ["", note]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    from rsrd_jax._cache import enable_compilation_cache

    enable_compilation_cache()
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--objects", nargs="+", default=None, help="studio objects (default: all)")
    ap.add_argument("--work", default="experiments/work/init_table", help="working directory (studios, models)")
    ap.add_argument("--out", default="experiments/results/init_table", help="output path stem (.md/.json)")
    ap.add_argument("--reuse", action="store_true", help="reuse the studios and models already in --work")
    ap.add_argument("--note", default="", help="a line appended to the Markdown table")
    a = ap.parse_args(argv)
    objects = a.objects or list_objects()
    unknown = sorted(set(objects) - set(list_objects()))
    if unknown:
        raise SystemExit(f"unknown studio objects {unknown}; known: {list_objects()}")
    cfg = PipelineConfig(demo_frames=None)
    t0 = time.perf_counter()
    rows = run(objects, cfg, Path(a.work), a.reuse)
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out.with_suffix(".json"), {"objects": rows, "time_s": round(time.perf_counter() - t0, 1)})
    atomic_write_text(out.with_suffix(".md"), markdown(rows, a.note))
    print(markdown(rows, a.note))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
