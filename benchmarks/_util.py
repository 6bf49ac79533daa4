"""Shared timing helpers for the benchmark modules (compile time apart from run time)."""

from __future__ import annotations

import resource
import statistics
import time
from collections.abc import Callable
from typing import Any

import jax


def measure(fn: Callable[..., Any], *args: Any, repeat: int = 10) -> tuple[float, float]:
    """Times `fn(*args)`.

    The first call (trace + compile + one run) is reported apart as `compile_s`; then `repeat`
    calls are timed with `jax.block_until_ready` and their median is returned in milliseconds.

    Returns:
        (compile_s, median_ms)
    """
    t0 = time.perf_counter()
    jax.block_until_ready(fn(*args))
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(max(1, repeat)):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append((time.perf_counter() - t0) * 1e3)
    return compile_s, statistics.median(times)


def peak_rss_mb() -> float:
    """Peak resident set size of this process so far, in MiB."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def record(
    bench: str,
    case: dict,
    median_ms: float,
    compile_s: float,
    metrics: dict | None = None,
) -> dict:
    """One benchmark record in the runner's JSON format (versions/device are added by the runner)."""
    return {
        "bench": bench,
        "case": case,
        "median_ms": float(median_ms),
        "compile_s": float(compile_s),
        "peak_rss_mb": peak_rss_mb(),
        "metrics": metrics or {},
    }
