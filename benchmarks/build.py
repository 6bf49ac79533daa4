"""ObjectModel build (issue 4): studio object → 3DGS fit, feature field, part labels.

Per object: held-out PSNR / SSIM (every 8th view; object composited on black, plus PSNR over
object pixels only), decoded-feature cosine similarity to the extractor's PCA features on held-out
object cells, part-label accuracy vs the studio's ground truth (nearest GT surface point's part),
Gaussian count, wall and CPU time per stage. A build runs once: `median_ms` is the whole build's
wall time (compile included, one sample) and `compile_s` is 0 (compilation is inside the stages).
Quick mode: one small red_box scan (16 views, 160×120) with short schedules.
"""

from __future__ import annotations

import resource
import tempfile
import time
from pathlib import Path

from benchmarks._util import peak_rss_mb, record

NAME = "build"


def _cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def run(quick: bool) -> list[dict]:
    import os

    os.environ.setdefault("MUJOCO_GL", "egl")
    from rsrd_jax.parts import BuildConfig, FieldConfig, FitConfig, build_object_model
    from rsrd_jax.studio import StudioConfig, make_object

    if quick:
        cases = [("red_box", StudioConfig(parts=("scan",), scan_views=16, scan_size=(160, 120)),
                  BuildConfig(fit=FitConfig(iterations=300), field=FieldConfig(iterations=200)))]  # fmt: skip
    else:
        cases = [(name, StudioConfig(parts=("scan",)), BuildConfig()) for name in ("red_box", "frog")]
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, scfg, bcfg in cases:
            d = Path(tmp) / name
            make_object(name, d, scfg)
            c0, t0 = _cpu_s(), time.perf_counter()
            model = build_object_model(d / "scan", bcfg, progress=False)
            wall, cpu = time.perf_counter() - t0, _cpu_s() - c0
            m = dict(model.meta["metrics"])
            m.update({f"stage_{k}": v for k, v in model.meta["stage_times_s"].items()})
            m.update({"build_wall_s": wall, "build_cpu_s": cpu, "num_parts": model.num_parts})
            case = {"object": name, "views": scfg.scan_views, "size": list(scfg.scan_size),
                    "fit_iterations": bcfg.fit.iterations, "field_iterations": bcfg.field.iterations}  # fmt: skip
            out.append(record(NAME, case, wall * 1e3, 0.0, m))
            out[-1]["peak_rss_mb"] = peak_rss_mb()
    return out
