"""Test configuration: fixed PRNG keys, offscreen MuJoCo, small shared fixtures.

jaxtyping's runtime shape checks (with beartype) are enabled for `rsrd_jax` through pytest's
`--jaxtyping-packages` option in pyproject.toml; warnings are errors there, with named exceptions.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
os.environ.setdefault("RSRD_JAX_NO_COMPILE_CACHE", "1")  # CLI tests in-process: no ~/.cache writes

import rsrd_jax._typecheck  # noqa: E402,F401  (the checker pyproject's --jaxtyping-packages names)
import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402


@pytest.fixture
def key() -> jax.Array:
    """A fixed PRNG key: tests are deterministic."""
    return jax.random.key(0)


@pytest.fixture
def rng() -> np.random.Generator:
    """A fixed numpy generator."""
    return np.random.default_rng(0)


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_code():
    """Drops JAX's in-memory compilation caches after each test module. Every compiled XLA CPU
    executable keeps memory mappings; the suite in one process compiles thousands of programs
    (each test size and render budget is its own), and in session 36 it crashed twice inside
    XLA compilation (an abort, then a segmentation fault) in a late test of test_track.py that
    passed on its own, most likely at the kernel's limit of 65530 mappings per process
    (vm.max_map_count): with this fixture the most any module reached was 28.7k (whole default
    run), and the run passes."""
    yield
    jax.clear_caches()
