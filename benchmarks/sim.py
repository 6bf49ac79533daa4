"""Simulated execution speed: simulated seconds per wall second for one plan (MuJoCo C, 2 ms steps).

Cases: a studio object made at small image sizes, its oracle plan (demo contacts + IK), then
``simulate_plan`` timed without video (setup = scene build, reported as ``compile_s``) and, in
full mode, with the 320×240 robot-view video. ``median_ms`` is one whole execution (settle,
approach, grip, motion, release, retreat); metrics hold the real-time factor, the simulated
time, the per-step cost and the outcome.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

from benchmarks._util import record


def run(quick: bool) -> list[dict]:
    from rsrd_jax.sim import SimConfig, build_sim_scene, load_sim_object, oracle_plan, simulate_plan
    from rsrd_jax.studio import StudioConfig, make_object

    objects = ("stapler",) if quick else ("stapler", "nerf_gun", "sunglasses")
    out = []
    with tempfile.TemporaryDirectory(prefix="bench_sim_") as tmp:
        for name in objects:
            small = (32, 24)
            make_object(name, Path(tmp) / name, StudioConfig(scan_views=1, demo_frames=30, scan_size=small,
                                                             demo_size=small, robot_size=small))  # fmt: skip
            obj = load_sim_object(Path(tmp) / name)
            plan = oracle_plan(obj)
            for video in (False,) if quick else (False, True):
                cfg = SimConfig()
                t0 = time.perf_counter()
                build_sim_scene(obj, cfg)
                setup_s = time.perf_counter() - t0
                walls, res = [], None
                for _ in range(1 if video else (2 if quick else 3)):
                    t0 = time.perf_counter()
                    res = simulate_plan(plan, obj, cfg, video=video, progress=False)
                    walls.append(time.perf_counter() - t0)
                wall = statistics.median(walls)
                mt = res.metrics
                out.append(record(
                    "sim", {"object": name, "video": video, "demo_frames": 30, "timestep_ms": 1000 * cfg.timestep},
                    1000 * wall, setup_s,
                    {"sim_time_s": mt.get("sim_time_s"), "realtime_factor": round(mt.get("sim_time_s", 0) / wall, 2),
                     "us_per_step": round(1e6 * wall / max(mt.get("steps", 1), 1), 1), "outcome": res.outcome_name,
                     "base_displacement_mm": mt.get("base_displacement_mm")},
                ))  # fmt: skip
    return out
