"""Persistent XLA compilation cache for the command line and experiments.

The tracker, the initialiser and the planner each compile a few large functions (8–12 s each on
a 2-core CPU); with the cache a later process with the same shapes loads them instead (tracing
still runs). The library never turns it on by itself: `rsrd-jax` does, unless
`RSRD_JAX_NO_COMPILE_CACHE=1`; benchmarks leave it off so that they report cold compile times.
"""

from __future__ import annotations

import os
from pathlib import Path


def default_cache_dir() -> Path:
    """`$JAX_COMPILATION_CACHE_DIR`, else `$XDG_CACHE_HOME/rsrd_jax/xla` (`~/.cache/...`)."""
    if os.environ.get("JAX_COMPILATION_CACHE_DIR"):
        return Path(os.environ["JAX_COMPILATION_CACHE_DIR"])
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "rsrd_jax" / "xla"


def enable_compilation_cache(path: str | Path | None = None, min_compile_time_s: float = 0.0) -> Path | None:
    """Points JAX's persistent compilation cache at `path` (default `default_cache_dir()`);
    functions that took at least `min_compile_time_s` to compile are stored. Default: all of
    them (JAX's own default, 1 s, leaves the many small ones of array operations outside jit to
    compile in every process: the tracking initialisation on nerf_gun in a fresh process with
    the cache filled took 15.2 s, 7.4 of them compiling, with 1 s and 11.1 s, 3.5 compiling,
    with 0).

    Returns the directory, or None when `RSRD_JAX_NO_COMPILE_CACHE` is set or the directory
    cannot be created (the cache is an optimisation; nothing depends on it)."""
    if os.environ.get("RSRD_JAX_NO_COMPILE_CACHE", "") not in ("", "0"):
        return None
    import jax

    d = Path(path) if path is not None else default_cache_dir()
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    jax.config.update("jax_compilation_cache_dir", str(d))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", float(min_compile_time_s))
    return d


_COMPILE_EVENTS = "/jax/core/compile/"
"""Prefix of JAX's duration events for tracing, lowering and XLA compilation (the last includes
a load from the persistent cache)."""


class CompileClock:
    """Seconds JAX spends compiling (tracing, lowering to MLIR, XLA compilation or loading from
    the persistent cache) while the block runs, from JAX's monitoring events: a stage's run time
    can be reported apart from its one-off compilation.

    >>> with CompileClock() as clock:
    ...     f(x)
    >>> clock.seconds
    """

    def __init__(self):
        self.seconds = 0.0

    def _on_event(self, name: str, duration: float, **_) -> None:
        if name.startswith(_COMPILE_EVENTS):
            self.seconds += float(duration)

    def __enter__(self) -> "CompileClock":
        import jax.monitoring

        jax.monitoring.register_event_duration_secs_listener(self._on_event)
        return self

    def __exit__(self, *exc) -> None:
        import jax.monitoring

        jax.monitoring.unregister_event_duration_listener(self._on_event)
