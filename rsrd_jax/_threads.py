"""One small thread pool for running independent jitted calls at once.

XLA's CPU runtime runs the calls of one Python thread in order and spreads one call over only
part of the machine (a tracking solve keeps about 1.5 of 2 cores busy); two threads each
calling a compiled function overlap them (8 tracking solves: 3.3 s in turn, 2.1–2.3 s on two
threads). Calls must already be compiled: two threads tracing the same function at once would
compile it twice.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

_POOL: ThreadPoolExecutor | None = None


def worker_pool() -> ThreadPoolExecutor:
    """The process's two worker threads (created on first use)."""
    global _POOL
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=2, thread_name_prefix="rsrd-jax")
    return _POOL
