"""Robot-view registration's seeds at the robot trials' table orientations, scored against truth.

For each object the studio scan is made and the ObjectModel built at the pipeline's sizes (as
`rsrd-jax demo` and the robot trials), then the object is registered from the robot view at the
robot trials' 10 table yaws with the pipeline's registration settings. Every seed's optimised
pose (`Registration.info["seed_poses_robot"]`, before ICP) is scored against the studio's true
pose, so that seed-selection rules can be compared offline; the table counts the flips (rotation
error > 10°) each rule would make:

- `total`: lowest total loss (`register_object` until session 44);
- `feature within X`: among the seeds whose total loss is within X of the lowest, the lowest
  feature loss (`track.select_seed`; the pipeline's registration since session 45 uses 5 %);
- `feature`: lowest feature loss.

    python -m experiments.registration_seeds [--objects usb_plug sunglasses ...] [--work DIR] [--out STEM]

Writes `<out>.md` and `<out>.json` (default `experiments/results/registration_seeds`); models
and robot views are kept in `--work`, an object already in `<out>.json` is not run again.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import jax  # noqa: E402
import numpy as np  # noqa: E402

from rsrd_jax.io import atomic_write_json, atomic_write_text  # noqa: E402
from rsrd_jax.parts import build_object_model, load_object_model, save_object_model  # noqa: E402
from rsrd_jax.pipeline import PipelineConfig  # noqa: E402
from rsrd_jax.plan import read_robot_object_pose  # noqa: E402
from rsrd_jax.studio import StudioConfig, list_objects, make_object  # noqa: E402
from rsrd_jax.track import read_robot_view, register_object, registration_error, select_seed  # noqa: E402

from experiments.robot_trials import table_yaws  # noqa: E402

FLIP_DEG = 10.0
"""A seed whose rotation error exceeds this is a flip (the pipeline's Init tolerance)."""
WINDOWS = (0.005, 0.02, 0.05, 0.1)
"""Total-loss windows (fractions of the lowest) of the `feature within` rules."""


def rules() -> dict:
    """Seed-selection rules: name -> f(total losses, feature losses) -> seed index."""
    out = {"total": lambda L, F: int(np.argmin(L))}
    for w in WINDOWS:
        out[f"feature within {w:.1%}"] = lambda L, F, w=w: select_seed(L, F, w)
    out["feature"] = lambda L, F: int(np.argmin(F))
    return out


def register_object_at_yaws(name: str, work: Path, cfg: PipelineConfig, yaws: int = 10) -> list[dict]:
    """Registers `name` at the robot trials' `yaws` table orientations; per orientation the
    seeds' losses, feature losses and pose errors."""
    odir = work / name
    studio = odir / "studio"
    if not (studio / "object.json").is_file():
        make_object(name, studio, StudioConfig(seed=cfg.seed, scan_views=cfg.scan_views, scan_size=cfg.scan_size,
                                               parts=("scan", "robot_view")), overwrite=True)  # fmt: skip
    if not (odir / "model" / "model.json").is_file():
        save_object_model(build_object_model(studio / "scan", cfg.build_config(), progress=True), odir / "model")
    model = load_object_model(odir / "model")
    pts = np.concatenate([np.asarray(model.part_points(k)) for k in range(model.num_parts)])
    yaw0 = float(json.loads((studio / "object.json").read_text())["products"]["robot_view"]["yaw_deg"])
    init = cfg.register_config()
    rows = []
    for k, yaw in enumerate(table_yaws(yaw0, yaws)):
        view_dir = studio if k == 0 else odir / f"yaw{k}"
        if k:
            make_object(name, view_dir, StudioConfig(seed=cfg.seed, robot_object_yaw_deg=yaw, parts=("robot_view",)),
                        overwrite=True)  # fmt: skip
        reg = register_object(model, read_robot_view(view_dir), init, feature_window=cfg.register_feature_window)
        T_gt = read_robot_object_pose(view_dir)
        seeds = [registration_error(np.asarray(T), T_gt, pts) for T in reg.info["seed_poses_robot"]]
        rows.append({"yaw_deg": round(yaw, 2), "final": registration_error(reg.T_robot_obj, T_gt, pts),
                     "best_seed": reg.info["best_seed"], "losses": reg.info["seed_losses"],
                     "feature_losses": reg.info["seed_feature_losses"], "seeds": seeds})  # fmt: skip
        print(f"{name} yaw {yaw:7.1f}: {rows[-1]['final']['rotation_deg']:.1f}° (seed {reg.info['best_seed']})", flush=True)
    return rows


def markdown(results: dict) -> str:
    rs = rules()
    lines = [f"Registration flips (seed rotation error > {FLIP_DEG:.0f}°, before ICP) per seed-selection rule, "
             "over the robot trials' 10 table orientations (see `experiments/registration_seeds.py`).", "",
             "| object | " + " | ".join(rs) + " |", "|---|" + "---|" * len(rs)]  # fmt: skip
    flips = []
    for name, rows in results.items():
        counts = []
        for rule in rs.values():
            counts.append(sum(r["seeds"][rule(r["losses"], r["feature_losses"])]["rotation_deg"] > FLIP_DEG for r in rows))
        lines.append(f"| {name} | " + " | ".join(str(c) for c in counts) + " |")
        for r in rows:
            L = np.asarray(r["losses"])
            if r["seeds"][int(np.argmin(L))]["rotation_deg"] > FLIP_DEG:
                top = [(int(i), round(float(L[i]), 4), round(float(r["feature_losses"][i]), 4),
                        round(r["seeds"][i]["rotation_deg"], 1)) for i in np.argsort(L)[:4]]  # fmt: skip
                right = [i for i, s in enumerate(r["seeds"]) if s["rotation_deg"] <= FLIP_DEG]
                best_right = min(right, key=lambda i: L[i]) if right else None
                flips.append(f"- {name} at table yaw {r['yaw_deg']}°: the 4 lowest totals (seed, total, feature, "
                             f"rotation error °) {top}; the right seed of lowest total: "
                             + (f"{best_right} (total {L[best_right]:.4f}, +{100 * (L[best_right] / L.min() - 1):.1f} %, "
                                f"feature {r['feature_losses'][best_right]:.4f})" if right else "none"))  # fmt: skip
    return "\n".join(lines + ["", "Flips of the `total` rule:", ""] + flips) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--objects", nargs="+", default=list_objects())
    ap.add_argument("--work", type=Path, default=Path("experiments/work/registration_seeds"))
    ap.add_argument("--out", default="experiments/results/registration_seeds")
    a = ap.parse_args()
    out = Path(a.out)
    js = out.with_suffix(".json")
    results = json.loads(js.read_text()) if js.is_file() else {}
    for name in a.objects:
        if name in results:
            continue
        results[name] = register_object_at_yaws(name, a.work, PipelineConfig())
        atomic_write_json(js, results)
        atomic_write_text(out.with_suffix(".md"), markdown(results))
        jax.clear_caches()
        gc.collect()
    atomic_write_text(out.with_suffix(".md"), markdown(results))
    print(markdown(results))


if __name__ == "__main__":
    main()
