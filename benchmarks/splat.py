"""Tile rasterizer: forward and forward+backward times (compile apart), memory, contributor stats.

Scene (as in ../shared/notes/rasterizer.md §3): N Gaussians uniformly in the view frustum 3–5 m
in front of an identity camera with f = W pixels, scales log-uniform 1–5 cm, random rotations,
opacity 0.1–0.9, random colours and C − 3 feature channels. Loss for the backward: a weighted sum
of RGB, features, accumulated depth and alpha (all channels in one pass, as tracking uses them).
Budgets come from `choose_config(..., headroom=1.0)` (exact for this view, no truncation).
`cpu_ms` is the median process CPU time per call (both threads): on a shared machine it is a
steadier number than wall time; `load_1min` is the load average before and after the timing and
`temp_mib` XLA's temporary arena per call.
"""

from __future__ import annotations

import dataclasses
import os
import statistics
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from benchmarks._util import measure, record
from rsrd_jax.geometry import Camera, Intrinsics
from rsrd_jax.splat import Gaussians, choose_config, render


def make_scene(n: int, channels: int, aspect: float = 1.0, seed: int = 0) -> Gaussians:
    """The benchmark scene; `channels` counts RGB plus features (C = 3 means no features)."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(3.0, 5.0, n)
    means = np.stack([rng.uniform(-0.5, 0.5, n) * z, rng.uniform(-0.5, 0.5, n) * aspect * z, z], -1)
    o = rng.uniform(0.1, 0.9, n)
    return Gaussians.create(
        means=means,
        quats=rng.normal(size=(n, 4)),
        log_scales=rng.uniform(np.log(0.01), np.log(0.05), (n, 3)),
        opacity_logits=np.log(o / (1 - o)),
        colours=rng.uniform(0, 1, (n, 3)),
        features=rng.normal(size=(n, channels - 3)),
    )


def _case(n: int, width: int, height: int, channels: int, repeat: int) -> list[dict]:
    g = make_scene(n, channels, height / width)
    intr = Intrinsics.create(width, width, width / 2, height / 2, width, height)
    T = jaxlie.SE3.identity()
    cam = Camera(intr, T)
    t0 = time.perf_counter()
    cfg = choose_config(g, [cam], headroom=1.0)
    choose_s = time.perf_counter() - t0
    stats = render(g, cam, dataclasses.replace(cfg, stats=True))
    n_contrib = np.asarray(stats.n_contrib)
    counts = np.asarray(stats.tile_counts)
    metrics = {
        "capacity": cfg.capacity,
        "max_chunks": cfg.max_chunks,
        "max_pairs": cfg.max_pairs,
        "contrib_per_px_mean": float(n_contrib.mean()),
        "contrib_per_px_max": int(n_contrib.max()),
        "tile_count_mean": float(counts.mean()),
        "tile_count_max": int(counts.max()),
        "alpha_gt_0.5": float((np.asarray(stats.alpha) > 0.5).mean()),
        "choose_config_s": choose_s,
    }

    @eqx.filter_jit
    def fwd(g, T):
        o = render(g, Camera(intr, T), cfg)
        return o.rgb, o.features, o.depth, o.alpha

    @eqx.filter_jit
    def fwd_bwd(g, T):
        def loss(args):
            o = render(args[0], Camera(intr, args[1]), cfg)
            return (
                jnp.sum(o.rgb)
                + 0.1 * jnp.sum(o.features)
                + jnp.sum(o.depth_accum)
                + jnp.sum(o.alpha)
            )

        return eqx.filter_grad(loss)((g, T))

    case = {"n": n, "width": width, "height": height, "channels": channels}
    out = []
    for mode, fn in (("fwd", fwd), ("fwd+bwd", fwd_bwd)):
        load = os.getloadavg()[0]
        compile_s, median_ms = measure(fn, g, T, repeat=repeat)
        cpu = []
        for _ in range(repeat):
            c0 = time.process_time()
            jax.block_until_ready(fn(g, T))
            cpu.append((time.process_time() - c0) * 1e3)
        temp = jax.jit(lambda g, T: fn(g, T)).lower(g, T).compile().memory_analysis()
        extra = {
            "cpu_ms": statistics.median(cpu),
            "cpu_ms_min": min(cpu),
            # Machine load (1-min average, both cores) around the timing: >1 means other jobs.
            "load_1min": [load, os.getloadavg()[0]],
            # XLA's temporary arena per call; above 32 MiB glibc maps it afresh on every call.
            "temp_mib": temp.temp_size_in_bytes / 2**20 if temp is not None else None,
        }
        out.append(record("splat", {**case, "mode": mode}, median_ms, compile_s, {**metrics, **extra}))
    return out


def run(quick: bool) -> list[dict]:
    if quick:
        return _case(10_000, 128, 128, 32, repeat=10)
    records = []
    for n in (1_000, 10_000, 50_000):
        for width, height in ((128, 128), (256, 192)):
            for channels in (3, 32, 64):
                records += _case(n, width, height, channels, repeat=10)
    return records


if __name__ == "__main__":
    for r in run(quick=True):
        print(r)
