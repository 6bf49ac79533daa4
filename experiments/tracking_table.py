"""Tracking ADD on studio objects, with the paper's ablations (Table 2 layout).

For each object: make the studio scan + demo, build the ObjectModel from the scan, track the demo
(default pipeline and ablations), evaluate ADD against the studio's ground truth. Writes
`experiments/results/tracking_table.{md,json}`.

    python -m experiments.tracking_table [--objects red_box frog ...] [--frames 90] [--quick]
        (results so far: WORK/NAME.partial.json, after each object; a rerun skips the objects in it,
        so one process per object (`--objects X`) and a last run over them all writes the full table)
    python -m experiments.tracking_table --size pipeline --frames 0 --name tracking_pipeline \
        --ablations "pipeline" "pipeline − hands" "pipeline − motion prior" "pipeline − both"
    python -m experiments.tracking_table ... --track-set seed=1 --track-set slide_max_turn_deg=null --track-set weights.support=1
        (TrackConfig fields, or LossWeights fields as weights.X, set in every row, values as JSON; recorded as `track_overrides`)

Mono-depth is the studio's relative-depth ORACLE and hand masks are the studio's ground truth;
both are labelled in the table, as are the studio's 2D fingertips (the "+ hands" rows).
`--frames 0` tracks each demo at its object's own frame count (90–120).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

from rsrd_jax.io import atomic_write_json, atomic_write_text, read_demo, read_demo_gt  # noqa: E402
from rsrd_jax.parts import BuildConfig, build_object_model, load_object_model, save_object_model  # noqa: E402
from rsrd_jax.pipeline import PipelineConfig, studio_separable  # noqa: E402
from rsrd_jax.studio import StudioConfig, list_objects, make_object  # noqa: E402
from rsrd_jax.track import (  # noqa: E402
    InitConfig,
    LossWeights,
    StudioDepthOracle,
    StudioFingertips,
    StudioHandMasks,
    TrackConfig,
    add_metrics,
    track_video,
)

_PIPE = PipelineConfig()
ABLATIONS = {
    "RSRD (ours)": {"weights": LossWeights()},
    "+ joint discovery": {"weights": LossWeights(), "joints": True},
    "+ hands": {"weights": LossWeights(), "hands": True},
    "no depth": {"weights": LossWeights(depth_rank=0.0)},
    "no ARAP": {"weights": LossWeights(arap=0.0)},
    "photometric only": {"weights": LossWeights(feature=0.0, depth_rank=0.0, arap=0.0, rgb=1.0)},
    "pipeline": {"pipeline": True, "hands": _PIPE.track_hands},
    "pipeline − hands": {"pipeline": True},
    "pipeline − motion prior": {"pipeline": True, "weights": LossWeights(), "hands": _PIPE.track_hands},
    "pipeline − both": {"pipeline": True, "weights": LossWeights()},
}
"""TrackConfig options of each row (the rest at their defaults); "hands": the hand term with the
studio's 2D fingertips (oracle); "pipeline": start from the tracking of `rsrd-jax demo` and the
robot trials (`PipelineConfig.track_config()`: joint discovery, lr 1e-2, motion prior; with the
hand term) instead of the library defaults, and the rows below it without the hand term, the
motion prior or both."""
DEFAULT_ABLATIONS = ["RSRD (ours)", "+ joint discovery", "+ hands", "no depth", "no ARAP", "photometric only"]


def row_config(ablation: str, quick: bool = False, overrides: dict | None = None) -> tuple[TrackConfig, bool]:
    """The TrackConfig of an `ABLATIONS` row and whether it uses the studio's fingertips;
    `overrides`: TrackConfig fields set on top of the row's (`--track-set`)."""
    opts = dict(ABLATIONS[ablation])
    hands = bool(opts.pop("hands", False))
    base = _PIPE.track_config() if opts.pop("pipeline", False) else TrackConfig()
    overrides = dict(overrides or {})
    weights = {k.removeprefix("weights."): overrides.pop(k) for k in list(overrides) if k.startswith("weights.")}
    opts.update(overrides)
    cfg = dataclasses.replace(base, **{"smooth_iters": 10 if quick else base.smooth_iters, **opts})
    return (dataclasses.replace(cfg, weights=dataclasses.replace(cfg.weights, **weights)) if weights else cfg), hands


def run(objects: list[str], frames: int, quick: bool, work: Path, ablations: list[str], size: str = "default",
        partial: Path | None = None, overrides: dict | None = None) -> dict:  # fmt: skip
    """Track each object with each ablation. `partial`: a JSON of the results so far, rewritten
    after each object; objects whose every ablation is in it are not tracked again (a long run
    that died, e.g. XLA's CPU compiler running out of code memory after many objects in one
    process, resumes where it stopped)."""
    results: dict = json.loads(partial.read_text()) if partial is not None and partial.is_file() else {}
    results = {o: r for o, r in results.items() if all(ab in r for ab in ablations)}
    pipe = PipelineConfig()
    for name in objects:
        if name in results:
            print(name, "already in", partial, flush=True)
            continue
        root = work / name
        if not (root / "demo" / "demo.mp4").is_file():
            if size == "pipeline":
                cfg = StudioConfig(demo_frames=frames or None, scan_views=pipe.scan_views, scan_size=pipe.scan_size, parts=("scan", "demo"))
            else:
                cfg = StudioConfig(demo_frames=frames or None, scan_views=24 if quick else 48, parts=("scan", "demo"))
            make_object(name, root, cfg, overwrite=True)
        mdir = root / "model"
        if (mdir / "model.json").is_file():
            model = load_object_model(mdir)
        else:
            bcfg = pipe.build_config() if size == "pipeline" else BuildConfig()  # pipeline: the `rsrd-jax demo` build
            model = build_object_model(root / "scan", bcfg)
            save_object_model(model, mdir)
        demo = read_demo(root / "demo" / "demo.mp4", max_frames=frames or None)
        gt = read_demo_gt(root / "demo")
        pts = [model.part_points(k) for k in range(model.num_parts)]
        results[name] = {}
        for ab in ablations:
            cfg, hands = row_config(ab, quick, overrides)
            tips = StudioFingertips(root / "demo") if hands else None
            init = InitConfig(iters=pipe.init_iters) if size == "pipeline" else InitConfig()
            t0 = time.perf_counter()
            traj = track_video(model, demo, cfg, init, StudioHandMasks(root / "demo"), StudioDepthOracle(root / "demo"),
                               separable=studio_separable(root), fingertips=tips)  # fmt: skip
            m = add_metrics(traj.T_cam_world_part, gt["T_cam_world_part"][: traj.num_frames], pts)
            results[name][ab] = {
                "add_obj_mm": m["mean_add_obj_mm"],
                "add_cam_mm": m["mean_add_mm"],
                "per_part_add_obj_mm": m["add_obj_mm"],
                "seconds": time.perf_counter() - t0,
                "frames_per_second": traj.meta["frames_per_second"],
                "timings_s": traj.meta["timings_s"],
                "fingertips": traj.meta["fingertips"],
                "hand_anchors": traj.meta["hand_anchors"],
                "frames": traj.num_frames,
                "slide_hypotheses": traj.meta["joints"].get("slide_hypotheses", []),
                "track_overrides": overrides or {},
            }
            print(name, ab, f"ADD(obj) {m['mean_add_obj_mm']:.2f} mm, ADD(cam) {m['mean_add_mm']:.2f} mm", flush=True)
        if partial is not None:
            atomic_write_json(partial, results)
    return {o: results[o] for o in objects if o in results}


def table(results: dict, ablations: list[str]) -> str:
    lines = [
        "Tracking ADD (mm, object-frame alignment on frame 0; camera-frame ADD in brackets). "
        "Mono-depth: studio relative-depth ORACLE; hand masks: studio ground truth; "
        "\"+ hands\" rows: the studio's 2D fingertips (ORACLE for a 2D hand detector).",
        "",
        "| method | " + " | ".join(results) + " | mean |",
        "|---|" + "---|" * (len(results) + 1),
    ]
    for ab in ablations:
        vals = [results[o][ab]["add_obj_mm"] for o in results]
        cams = [results[o][ab]["add_cam_mm"] for o in results]
        cells = [f"{v:.2f} ({c:.1f})" for v, c in zip(vals, cams)]
        lines.append(f"| {ab} | " + " | ".join(cells) + f" | {np.mean(vals):.2f} |")
    lines += ["", "Per part (object-frame ADD, mm), tracking rate (frames/s, compilation excluded) and the initialisation's "
              "time (s; in brackets the part of it JAX spent compiling, where recorded):", "",
              "| object | method | per part | frames/s | init |", "|---|---|---|---|---|"]  # fmt: skip
    for o in results:
        for ab in ablations:
            r = results[o][ab]
            parts = " / ".join(f"{v:.1f}" for v in r["per_part_add_obj_mm"])
            t = r.get("timings_s", {})
            init = "—" if "init_s" not in t else f"{t['init_s']:.1f}" + (f" ({t['init_compile_s']:.1f})" if "init_compile_s" in t else "")
            lines.append(f"| {o} | {ab} | {parts} | {r['frames_per_second']:.2f} | {init} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    from rsrd_jax._cache import enable_compilation_cache

    enable_compilation_cache()
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--objects", nargs="+", default=list_objects())
    p.add_argument("--frames", type=int, default=90, help="demo frames (0: each object's own 90–120)")
    p.add_argument("--ablations", nargs="+", default=DEFAULT_ABLATIONS, choices=list(ABLATIONS))
    p.add_argument("--name", default="tracking_table", help="results file name (experiments/results/NAME.md/.json)")
    p.add_argument("--quick", action="store_true", help="fewer views and smoothing iterations")
    p.add_argument("--size", choices=("default", "pipeline"), default="default",
                   help="scan and build: default (48 views 320×240, BuildConfig()) or the `rsrd-jax demo` sizes")  # fmt: skip
    p.add_argument("--work", type=Path, default=Path("experiments/work/tracking"))
    p.add_argument("--track-set", action="append", default=[], metavar="FIELD=JSON",
                   help="set a TrackConfig field (or weights.X, a LossWeights field) in every row, e.g. slide_max_turn_deg=null (repeatable)")
    a = p.parse_args()
    overrides = {}
    for item in a.track_set:
        field, sep, value = item.partition("=")
        known = {f.name for f in dataclasses.fields(TrackConfig)} | {f"weights.{f.name}" for f in dataclasses.fields(LossWeights)}
        if not sep or field not in known:
            p.error(f"--track-set {item!r}: expected FIELD=JSON with FIELD a TrackConfig field or weights.<LossWeights field>")
        try:
            overrides[field] = json.loads(value)
        except json.JSONDecodeError as e:
            p.error(f"--track-set {item!r}: the value is not JSON ({e})")
    out = Path(__file__).resolve().parent / "results"
    res = run(a.objects, a.frames, a.quick, a.work, a.ablations, a.size, a.work / f"{a.name}.partial.json", overrides)
    atomic_write_json(out / f"{a.name}.json", res)
    atomic_write_text(out / f"{a.name}.md", table(res, a.ablations))
    print(table(res, a.ablations))
    print(json.dumps({o: {k: round(v["add_obj_mm"], 2) for k, v in r.items()} for o, r in res.items()}))


if __name__ == "__main__":
    main()
