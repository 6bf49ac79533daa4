"""Planning: sparse Levenberg–Marquardt trajectory solver (trajectory costs, candidate search and
approach motions come later).

Owns the generic block-banded least-squares solver used for keyframed joint trajectories. It does
not own robot kinematics (``rsrd_jax.robot``) or grasp sampling (``rsrd_jax.grasp``).
"""

from ._banded import banded_cholesky, banded_cholesky_solve, banded_matvec, banded_solve, banded_to_dense
from ._lm import (
    BandedProblem,
    Cost,
    LMResult,
    LMSolution,
    SolverConfig,
    TerminationConfig,
    TrustRegionConfig,
    solve_lm,
)

__all__ = [
    "BandedProblem",
    "Cost",
    "LMResult",
    "LMSolution",
    "SolverConfig",
    "TerminationConfig",
    "TrustRegionConfig",
    "banded_cholesky",
    "banded_cholesky_solve",
    "banded_matvec",
    "banded_solve",
    "banded_to_dense",
    "solve_lm",
]
