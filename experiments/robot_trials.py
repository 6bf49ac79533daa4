"""Simulated robot trials (the paper's Table 1): every studio object × table orientations.

For each object the scan and the demo video are made once, the ObjectModel is built from the scan
and the demo is tracked once (from the video, not from ground truth). Then for each of `--yaws`
table orientations (evenly over 360°, starting from the studio's random yaw for the seed; the
offset to the demo's own yaw is recorded, and half of the trials are flipped by more than 90°) a new robot view is rendered and the object is registered, planned for and
executed in MuJoCo. Success per stage: Init (registration error ≤ thresholds), Traj (a feasible
plan), Grasp (held when the motion starts, no slip), Exec (the object's joints end where the demo's
did and moved the same way).

    python -m experiments.robot_trials [--objects red_box nerf_gun ...] [--yaws 10] [--frames N] [--resume]
    python -m experiments.robot_trials --merge A.json B.json ... --out STEM   # one table from several runs

The demo is tracked at the object's own frame count (90–120 frames; `--frames N` renders the same
motion in N frames). `rsrd-jax demo` uses 30 frames to stay within its time budget; on the studio
led_light that subsampling alone took the panel's tracking error from 8.8 to 32.3 mm.

Writes `experiments/results/robot_trials.{md,json,png}` (a `total` entry holds each stage's rate
and `end_to_end`). The hand keypoints (demo camera frame) and hand masks are studio oracles.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import shutil
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import jax  # noqa: E402
import numpy as np  # noqa: E402

from rsrd_jax.io import atomic_write_bytes, atomic_write_json, atomic_write_text  # noqa: E402
from rsrd_jax.pipeline import PipelineConfig, run_pipeline  # noqa: E402
from rsrd_jax.studio import StudioConfig, list_objects, make_object  # noqa: E402

STAGES = ("init", "traj", "grasp", "exec")
DEFAULT_BUILD_SIZES = dict(scan_views=48, scan_size=(320, 240), fit_iterations=1000, field_iterations=600, max_gaussians=12288)
"""`--build-size default`: the scan and build sizes of `rsrd-jax build`'s defaults (`BuildConfig()`)."""


def trial_studio(base: Path, out: Path, name: str, seed: int, yaw_deg: float) -> Path:
    """A studio directory sharing `base`'s scan and demo, with a new robot view at `yaw_deg`."""
    if out.exists():
        shutil.rmtree(out)
    make_object(name, out, StudioConfig(seed=seed, robot_object_yaw_deg=yaw_deg, parts=("robot_view",)))
    for sub in ("scan", "demo"):
        (out / sub).symlink_to((base / sub).resolve(), target_is_directory=True)
    return out


def table_yaws(yaw0: float, yaws: int) -> list[float]:
    """The trials' `yaws` table orientations (degrees in [-180, 180)): evenly over 360° from the
    studio's robot-view yaw `yaw0` (trial 0)."""
    return [(yaw0 + 360.0 * k / yaws + 180.0) % 360.0 - 180.0 for k in range(yaws)]


def first_failure(stages: dict) -> str | None:
    for k in STAGES:
        if not stages.get(k):
            return k
    return None


def reusable(yaw0: Path, cfg: PipelineConfig) -> dict:
    """The studio / model / track artefacts of an earlier trial 0 in `yaw0` that `--resume` may
    reuse: each must be complete, and the trajectory must have been tracked with this
    configuration's `TrackConfig` (its stored config is compared)."""
    from rsrd_jax.track._track import _config_dict

    out = {}
    if (yaw0 / "studio" / "object.json").is_file() and (yaw0 / "studio" / "robot_view").is_dir():
        out["studio_dir"] = yaw0 / "studio"
        if (yaw0 / "model" / "model.json").is_file():
            out["model_dir"] = yaw0 / "model"
            tj = yaw0 / "track" / "trajectory.json"
            want = json.loads(json.dumps(_config_dict(cfg.track_config())))  # as trajectory.json stores it
            if tj.is_file() and json.loads(tj.read_text()).get("config") == want:
                out["track_dir"] = yaw0 / "track"
    return out


def run(objects: list[str], yaws: int, cfg: PipelineConfig, work: Path, resume: bool = False) -> dict:
    results: dict = {"objects": {}, "config": {"yaws": yaws, "resume": resume, **{k: v for k, v in vars(cfg).items()}}}
    for name in objects:
        t0 = time.perf_counter()
        odir = work / name
        # trial 0 runs every stage (studio, build, track, ...); later trials reuse model + track
        reuse = reusable(odir / "yaw0", cfg) if resume else {}
        if reuse:
            print(f"{name}: reusing {', '.join(str(p) for p in reuse.values())}", flush=True)
        base = run_pipeline(name, odir / "yaw0", cfg, log=lambda m: print(f"{name}: {m}", flush=True), **reuse)
        studio = odir / "yaw0" / "studio"
        products = json.loads((studio / "object.json").read_text())["products"]
        demo_yaw, yaw0 = float(products["demo"]["yaw_deg"]), float(products["robot_view"]["yaw_deg"])
        wrap = lambda x: (x + 180.0) % 360.0 - 180.0  # noqa: E731
        trials = [dict(yaw_offset_deg=wrap(yaw0 - demo_yaw), **_trial(base))]
        for k, yaw in enumerate(table_yaws(yaw0, yaws)[1:], 1):
            off = wrap(yaw - demo_yaw)
            tdir = odir / f"yaw{k}"
            sd = trial_studio(studio, tdir / "studio", name, cfg.seed, yaw)
            try:
                rep = run_pipeline(name, tdir, cfg, log=lambda m: print(f"{name} yaw {yaw:.0f}: {m}", flush=True),
                                   studio_dir=sd, model_dir=odir / "yaw0" / "model", track_dir=odir / "yaw0" / "track")  # fmt: skip
                trials.append(dict(yaw_offset_deg=off, **_trial(rep)))
            except Exception as e:  # a crash is a failed trial with its reason, not a lost experiment
                trials.append(dict(yaw_offset_deg=off, stages={s: False for s in STAGES}, end_to_end=False,
                                   failure="crash", reason=f"{type(e).__name__}: {e}"))  # fmt: skip
        n = len(trials)
        rates = stage_rates(trials)
        results["objects"][name] = {
            "trials": trials, "rates": rates, "tracking_add_obj_mm": base["track"]["add_obj_mean_mm"],
            "tracking_add_obj_per_part_mm": base["track"]["add_obj_mm"], "reused": sorted(reuse),
            "time_s": round(time.perf_counter() - t0, 1),
        }  # fmt: skip
        atomic_write_json(work / "partial.json", results)
        # every object compiles its own shapes: drop the compiled executables between objects (a
        # run over all objects in one process once died in LLVM's JIT: "Cannot allocate memory")
        jax.clear_caches()
        gc.collect()
    return summarise(results)


def reached(stages: dict, s: str) -> bool:
    """Cumulative, as the paper's Table 1: stage `s` and every stage before it passed (the
    simulator still scores Exec after a Grasp failure, e.g. a part that turned in the jaw but
    ended where the demo did; such a trial does not count at Exec)."""
    return all(bool(stages.get(x)) for x in STAGES[: STAGES.index(s) + 1])


def stage_rates(trials: list[dict]) -> dict:
    """Cumulative rate of each stage and the end-to-end rate over `trials`."""
    n = max(len(trials), 1)
    rates = {s: sum(reached(t["stages"], s) for t in trials) / n for s in STAGES}
    rates["end_to_end"] = sum(t["end_to_end"] for t in trials) / n
    return rates


def summarise(results: dict) -> dict:
    """(Re)computes every object's stage rates, the `total` rates and `failure_causes`."""
    for o in results["objects"].values():
        o["rates"] = stage_rates(o["trials"])
    allt = [t for o in results["objects"].values() for t in o["trials"]]
    total = stage_rates(allt)
    total["trials"] = len(allt)
    causes: dict[str, int] = {}
    for t in allt:
        if t["failure"]:
            causes[t["failure"]] = causes.get(t["failure"], 0) + 1
    results["total"] = total
    results["failure_causes"] = causes
    return results


def _trial(rep: dict) -> dict:
    st = rep["stages"]
    f = first_failure(st)
    reason = ""
    if f == "init":
        reason = rep["register"].get("summary", "")
    elif f is not None:
        reason = rep["simulate"].get("reasons", {}).get(f, "") or rep["plan"].get("message", "")
    return {"stages": st, "end_to_end": rep["end_to_end"], "failure": f, "reason": reason,
            "register_error": rep["register"].get("error"), "plan": rep["plan"].get("result")}  # fmt: skip


def markdown(res: dict) -> str:
    lines = ["| object | Init | Traj | Grasp | Exec | end-to-end | tracking ADD (mm) |", "|---|---|---|---|---|---|---|"]
    for name, o in res["objects"].items():
        n = len(o["trials"])
        c = {s: sum(reached(t["stages"], s) for t in o["trials"]) for s in STAGES}
        e = sum(t["end_to_end"] for t in o["trials"])
        lines.append(f"| {name} | {c['init']}/{n} | {c['traj']}/{n} | {c['grasp']}/{n} | {c['exec']}/{n} | {e}/{n} | {o['tracking_add_obj_mm']:.1f} |")
    t = res["total"]
    lines.append(f"| **total** | {t['init']:.0%} | {t['traj']:.0%} | {t['grasp']:.0%} | {t['exec']:.0%} | **{t['end_to_end']:.0%}** | |")
    lines.append("")
    lines.append("Stage counts are cumulative as in the paper: a trial counts at a stage only if it passed it "
                 "(a stage after a failure is not attempted or fails).")
    lines.append("")
    lines.append("Failure causes (first failing stage): " + (", ".join(f"{k}: {v}" for k, v in res["failure_causes"].items()) or "none"))
    lines.append("")
    if any("source" in o for o in res["objects"].values()):
        lines.append("Sources (merged runs): " + "; ".join(f"{n}: `{o['source']}`" for n, o in res["objects"].items()))
        lines.append("")
    lines.append("Oracles: hand masks and hand keypoints (demo camera frame) come from the studio; mono-depth is "
                 "the studio's relative-depth oracle. Everything else comes from the scan, the video and the robot view.")
    return "\n".join(lines) + "\n"


def figure(res: dict, path: Path) -> None:
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(res["objects"])
    fig, ax = plt.subplots(figsize=(max(6, 1.1 * len(names) + 2), 3.5))
    w = 0.18
    for i, s in enumerate((*STAGES, "end_to_end")):
        vals = [res["objects"][n]["rates"][s] for n in names]
        ax.bar(np.arange(len(names)) + (i - 2) * w, vals, w, label=s)
    ax.set_xticks(np.arange(len(names)), names, rotation=30, ha="right")
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("success rate")
    ax.set_title(f"simulated robot trials: end-to-end {res['total']['end_to_end']:.0%} over {res['total']['trials']} trials")
    ax.legend(ncol=5, fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.35))
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())


def merge(paths: list[Path]) -> dict:
    """One table from earlier runs' JSONs (e.g. one run per object): each object's entry is taken
    from the last file that has it, its source file (and that run's commit, if recorded) kept."""
    res: dict = {"objects": {}, "config": {"merged": []}}
    for p in paths:
        r = json.loads(Path(p).read_text())
        res["config"]["merged"].append({"file": str(p), "commit": r.get("config", {}).get("commit"),
                                        "objects": list(r.get("objects", {}))})  # fmt: skip
        for name, o in r.get("objects", {}).items():
            res["objects"][name] = {**o, "source": str(p)}
    if not res["objects"]:
        raise SystemExit(f"--merge: no object results in {', '.join(map(str, paths))}")
    return summarise(res)


def _commit(root: Path | None = None) -> str | None:
    """The commit of the code a run imports (``git rev-parse HEAD`` of ``root``, the repository
    holding this file by default), with ``-dirty`` when tracked files of ``rsrd_jax/`` or this
    script differ from it; None outside a git checkout."""
    import subprocess

    root = Path(__file__).resolve().parent.parent if root is None else Path(root)
    try:
        git = lambda *a: subprocess.run(["git", *a], capture_output=True, text=True, check=True,  # noqa: E731
                                        cwd=root).stdout.strip()  # fmt: skip
        dirty = git("status", "--porcelain", "--untracked-files=no", "--", "rsrd_jax", "experiments/robot_trials.py")
        return git("rev-parse", "HEAD") + ("-dirty" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return None


def main(argv=None) -> int:
    from rsrd_jax._cache import enable_compilation_cache

    enable_compilation_cache()
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--objects", nargs="+", default=None, help="studio objects (default: all)")
    ap.add_argument("--yaws", type=int, default=10, help="table orientations per object")
    ap.add_argument("--frames", type=int, default=None,
                    help="demo frames (default: the object's own 90–120, as filmed; fewer frames mean larger "
                         "motions between frames, which tracking follows worse)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--work", default="experiments/work/robot_trials", help="working directory (artefacts)")
    ap.add_argument("--out", default="experiments/results/robot_trials", help="output path stem (.md/.json/.png)")
    ap.add_argument("--no-rerun", action="store_true", help="skip rerun recordings and videos (faster)")
    ap.add_argument("--resume", action="store_true",
                    help="reuse each object's trial-0 studio, model and track in --work when complete (the track only "
                         "if made with this configuration); recorded per object as 'reused'")  # fmt: skip
    ap.add_argument("--extent-meshes", action="store_true",
                    help="grasp meshes from the Gaussians' extents (PipelineConfig.plan_extent_meshes)")
    ap.add_argument("--hand-grasps", action=argparse.BooleanOptionalAction, default=PipelineConfig.plan_hand_grasps,
                    help="also sample grasps where the tracker anchored each hand (PipelineConfig.plan_hand_grasps; off "
                         "by default)")  # fmt: skip
    ap.add_argument("--root-still", action=argparse.BooleanOptionalAction, default=PipelineConfig.plan_root_still,
                    help="plan the parts' motion relative to the root held still (PipelineConfig.plan_root_still; off "
                         "by default)")  # fmt: skip
    ap.add_argument("--grasp-keyframe-weight", type=float, default=PipelineConfig.plan_grasp_keyframe_weight,
                    help="PipelineConfig.plan_grasp_keyframe_weight (the grasp keyframe's pose rows)")
    ap.add_argument("--scan-surface", action="store_true",
                    help="plan on the part surfaces from the scan's depth (PipelineConfig.plan_scan_surface)")
    ap.add_argument("--square-grasps", action=argparse.BooleanOptionalAction, default=PipelineConfig.plan_square_grasps,
                    help="PipelineConfig.plan_square_grasps (prefer square pinches; on by default)")
    ap.add_argument("--square-cone", type=float, default=PipelineConfig.plan_square_cone_deg, metavar="DEG",
                    help="PipelineConfig.plan_square_cone_deg: the friction cone of --square-grasps (degrees)")
    ap.add_argument("--build-size", choices=("pipeline", "default"), default="pipeline",
                    help="scan and ObjectModel sizes: the pipeline's (16 views 160×120, 400 fit + 300 field iterations, "
                         "6000 Gaussians, as `rsrd-jax demo`) or the library's defaults (48 views 320×240, 1000 + 600, "
                         "12288 Gaussians, as `rsrd-jax build`)")  # fmt: skip
    ap.add_argument("--merge", nargs="+", default=None, metavar="JSON",
                    help="run nothing: assemble one table from earlier runs' JSONs (each object from the last file "
                         "that has it) and write it to --out")  # fmt: skip
    a = ap.parse_args(argv)
    if a.merge:
        missing = [p for p in a.merge if not Path(p).is_file()]
        if missing:
            raise SystemExit(f"--merge: no such file(s): {', '.join(missing)}")
        res = merge([Path(p) for p in a.merge])
    else:
        objects = a.objects or list_objects()
        sizes = {} if a.build_size == "pipeline" else DEFAULT_BUILD_SIZES
        cfg = PipelineConfig(seed=a.seed, demo_frames=a.frames, rerun=not a.no_rerun, sim_video=not a.no_rerun,
                             plan_extent_meshes=a.extent_meshes, plan_grasp_keyframe_weight=a.grasp_keyframe_weight,
                             plan_hand_grasps=a.hand_grasps, plan_root_still=a.root_still, plan_square_grasps=a.square_grasps,
                             plan_square_cone_deg=a.square_cone, plan_scan_surface=a.scan_surface, **sizes)  # fmt: skip
        commit = _commit()  # the code this run imports (before it runs: a commit may land meanwhile)
        res = run(objects, a.yaws, cfg, Path(a.work), a.resume)
        res["config"]["commit"] = commit
    out = Path(a.out)
    atomic_write_json(out.with_suffix(".json"), res)
    atomic_write_text(out.with_suffix(".md"), markdown(res))
    figure(res, out.with_suffix(".png"))
    print(markdown(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
