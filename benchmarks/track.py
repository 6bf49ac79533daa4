"""4D-DPM tracking (issue 5): initialisation time, tracked frames per second, peak memory.

The studio object is scanned and built at the `rsrd-jax demo` sizes (16 views 160×120, the
pipeline's BuildConfig), then every case tracks its demo in a fresh process (so that its peak
RSS is the tracker's, not the build's): default `TrackConfig` on a 30-frame demo, twice in the
same process (cold: compiling; warm: the in-process compiled functions reused), with joint
discovery on the same demo, and default settings on a 120-frame demo. Studio hand masks and the
relative-depth ORACLE are the observation sources.

`median_ms` is the time per tracked frame without compilation (per-frame passes with observation
processing, plus smoothing, over the frames); `compile_s` is the per-frame solve's and the
smoothing step's compilation. `frames_per_second` is the same rate; `init_s` the initialisation's
wall time (its compilation included: `init_s` of the warm run is the compiled initialiser),
`init_compile_s` the part of it JAX spent compiling (`CompileClock`: tracing, lowering, XLA
compilation) and `init_run_s` the rest.
Quick mode: red_box, 8 views, 6 frames, short schedules.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

from benchmarks._util import record

NAME = "track"
_ROOT = Path(__file__).resolve().parent.parent


def _track_case(studio: str, model_dir: str, frames: int, repeat: int, cfg: dict, init_iters: int | None) -> dict:
    """Runs in the child process: tracks and reports timings, ADD and this process's peak RSS."""
    import resource

    import numpy as np

    from rsrd_jax.io import read_demo, read_demo_gt
    from rsrd_jax.parts import load_object_model
    from rsrd_jax.track import InitConfig, StudioDepthOracle, StudioHandMasks, TrackConfig, add_metrics, track_video

    model = load_object_model(model_dir)
    demo = read_demo(Path(studio) / "demo" / "demo.mp4", max_frames=frames)
    gt = read_demo_gt(Path(studio) / "demo")
    init = InitConfig() if init_iters is None else InitConfig(iters=init_iters, screen_iters=max(init_iters // 2, 1), refine_iters=init_iters // 2)
    runs = []
    for _ in range(repeat):
        traj = track_video(model, demo, TrackConfig(**cfg), init, StudioHandMasks(Path(studio) / "demo"),
                           StudioDepthOracle(Path(studio) / "demo"), progress=False)  # fmt: skip
        pts = [np.asarray(model.part_points(k)) for k in range(model.num_parts)]
        add = add_metrics(traj.T_cam_world_part, gt["T_cam_world_part"][: traj.num_frames], pts)
        t = traj.meta["timings_s"]
        runs.append({"frames": traj.num_frames, "timings_s": t, "frames_per_second": traj.meta["frames_per_second"],
                     "frames_per_second_with_compile": traj.meta["frames_per_second_with_compile"],
                     "add_obj_mm": add["add_obj_mm"], "mean_add_obj_mm": add["mean_add_obj_mm"],
                     "render_budgets": traj.meta["render_budgets"], "render_budget_growths": len(traj.meta["render_budget_growths"])})  # fmt: skip
    return {"runs": runs, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}


def _child(case: dict) -> dict:
    code = "import json, sys; from benchmarks.track import _track_case; print('RESULT', json.dumps(_track_case(**json.loads(sys.argv[1]))))"
    proc = subprocess.run([sys.executable, "-c", code, json.dumps(case)], cwd=_ROOT, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"tracking case {case} failed:\n{proc.stderr[-3000:]}")
    line = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")][-1]
    return json.loads(line[len("RESULT ") :])


def run(quick: bool) -> list[dict]:
    import os

    os.environ.setdefault("MUJOCO_GL", "egl")
    from rsrd_jax.parts import BuildConfig, FieldConfig, FitConfig, build_object_model, save_object_model
    from rsrd_jax.pipeline import PipelineConfig
    from rsrd_jax.studio import StudioConfig, make_object

    p = PipelineConfig()
    if quick:
        obj, demos = "red_box", {6: 6}
        scfg = dict(scan_views=8, scan_size=(128, 96), demo_size=(160, 120))
        bcfg = BuildConfig(init_gaussians=1500, fit=FitConfig(iterations=150, max_gaussians=2000), field=FieldConfig(iterations=60))
        cases = [("default", 6, 1, {"steps_per_frame": 10, "smooth_iters": 3, "roi_size": 128}, 8)]
    else:
        obj, demos = "stapler", {30: 30, 120: 120}
        scfg = dict(scan_views=p.scan_views, scan_size=p.scan_size, demo_size=p.demo_size)
        bcfg = p.build_config()
        cases = [("default (cold, warm)", 30, 2, {}, None), ("joint discovery", 30, 1, {"joints": True}, None),
                 ("default", 120, 1, {}, None)]  # fmt: skip
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        studios = {}
        for i, n in enumerate(demos):
            d = Path(tmp) / f"{obj}_{n}"
            make_object(obj, d, StudioConfig(demo_frames=n, parts=("scan", "demo") if i == 0 else ("demo",), **scfg))
            studios[n] = d
        first = studios[next(iter(demos))]
        model = build_object_model(first / "scan", bcfg, progress=False)
        save_object_model(model, Path(tmp) / "model")
        for label, n, repeat, cfg, init_iters in cases:
            res = _child({"studio": str(studios[n]), "model_dir": str(Path(tmp) / "model"), "frames": n,
                          "repeat": repeat, "cfg": cfg, "init_iters": init_iters})  # fmt: skip
            for k, r in enumerate(res["runs"]):
                t = r["timings_s"]
                run_label = label if repeat == 1 else f"{label.split(' (')[0]} ({'cold' if k == 0 else 'warm'})"
                case = {"object": obj, "frames": n, "gaussians": int(model.gaussians.num_gaussians), "tracking": run_label}
                compile_s = t.get("frame_compile_s", 0.0) + t.get("smooth_compile_s", 0.0)
                m = {"frames_per_second": r["frames_per_second"], "frames_per_second_with_compile": r["frames_per_second_with_compile"],
                     "init_s": t["init_s"], "init_compile_s": t.get("init_compile_s"),
                     "init_run_s": t["init_s"] - t.get("init_compile_s", 0.0), "add_obj_mm": r["add_obj_mm"], "mean_add_obj_mm": r["mean_add_obj_mm"],
                     "render_budget_growths": r["render_budget_growths"], **r["render_budgets"],
                     **{f"t_{k2}": v for k2, v in t.items()}}  # fmt: skip
                rec = record(NAME, case, 1e3 / max(r["frames_per_second"], 1e-9), compile_s, m)
                rec["peak_rss_mb"] = res["peak_rss_mb"]
                out.append(rec)
    return out
