"""rsrd_jax: Robot See Robot Do in JAX.

Stages (each a subpackage, imports only point downstream -> upstream):
geometry, io -> studio, splat -> features -> parts -> track, hands -> grasp, robot -> plan -> sim.
"""

__version__ = "0.1.0"
