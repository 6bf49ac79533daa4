"""rsrd_jax: Robot See Robot Do in JAX.

Stages (each a subpackage, imports only point downstream -> upstream):
geometry, io -> studio, splat -> features -> parts -> track, hands -> grasp, robot -> plan -> sim.
"""

import os as _os

# MuJoCo renders offscreen through EGL on headless machines; it reads MUJOCO_GL when it is first
# imported, so set the default before any submodule imports mujoco (a user's choice wins).
_os.environ.setdefault("MUJOCO_GL", "egl")

__version__ = "0.1.0"
