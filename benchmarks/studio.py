"""Studio rendering speed: one view (RGB + depth + part labels) and whole objects."""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks._util import record


def _render_case(size: tuple[int, int], hands: bool, repeat: int) -> dict:
    from rsrd_jax.geometry import look_at
    from rsrd_jax.studio import SceneOptions, build_scene, get_object

    obj = get_object("frog")
    with build_scene(obj, np.eye(4), SceneOptions(size[0], size[1], 50.0, 0, hands=hands)) as scene:
        scene.set_configuration(0.5)
        scene.set_camera(np.asarray(look_at([0.25, -0.2, 0.2], [0, 0, 0.02]).as_matrix(), np.float64))
        t0 = time.perf_counter()
        scene.render()
        first = time.perf_counter() - t0
        times = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            scene.render()
            times.append((time.perf_counter() - t0) * 1e3)
    return record("studio", {"what": "render rgb+depth+labels", "size": f"{size[0]}x{size[1]}", "hands": hands},
                  statistics.median(times), first)  # fmt: skip


def _make_case(name: str, quick: bool) -> dict:
    from rsrd_jax.studio import StudioConfig, make_object

    cfg = StudioConfig(scan_views=8, demo_frames=10) if quick else StudioConfig()
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        meta = make_object(name, Path(tmp) / name, cfg)
        total = time.perf_counter() - t0
    t = meta["timings_s"]
    return record(
        "studio",
        {"what": "make_object", "object": name, "views": cfg.scan_views, "frames": meta["products"]["demo"]["frames"]},
        total * 1e3,
        0.0,
        {k: round(v, 2) for k, v in t.items()},
    )


def run(quick: bool) -> list[dict]:
    out = [_render_case((320, 240), False, 10 if quick else 50)]
    if not quick:
        out.append(_render_case((640, 480), True, 30))
        from rsrd_jax.studio import list_objects

        out += [_make_case(n, quick) for n in list_objects()]
    else:
        out.append(_make_case("red_box", quick))
    return out
