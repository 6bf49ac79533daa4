"""Planning: sparse Levenberg–Marquardt trajectory solver, YuMi trajectory costs, grasp candidate
search with rejection counts, approach motions and the RobotPlan (``plan_robot``), with the
collision proxies its checks use (signed-distance grids of the parts from their points, the
robot as capsules with finger-pad capsules: ``part_sdf``, ``robot_proxy``) and a rerun recording
of a plan (``log_plan``).

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

from ._costs import (
    CollisionData,
    CostParams,
    CostWeights,
    PoseData,
    problem_data,
    strip_robot,
    tcp_errors,
    trajectory_problem,
)
from ._search import (
    ARM_NAMES,
    STAGES,
    PlanConfig,
    PlanResult,
    RobotPlan,
    grasp_targets,
    keyframe_indices,
    object_geometry,
    plan_config_from_dict,
    plan_robot,
    resample_keyframes,
    root_still_trajectory,
)
from ._proxy import PartSDF, RobotProxy, part_sdf, robot_proxy, sdf_distance
from ._rerun import log_plan
from ._studio import StudioPlanInputs, read_robot_object_pose, studio_plan_inputs

__all__ += [
    "ARM_NAMES",
    "STAGES",
    "CollisionData",
    "CostParams",
    "CostWeights",
    "PlanConfig",
    "PartSDF",
    "PlanResult",
    "PoseData",
    "RobotPlan",
    "RobotProxy",
    "StudioPlanInputs",
    "grasp_targets",
    "keyframe_indices",
    "log_plan",
    "object_geometry",
    "part_sdf",
    "plan_config_from_dict",
    "plan_robot",
    "problem_data",
    "read_robot_object_pose",
    "resample_keyframes",
    "robot_proxy",
    "root_still_trajectory",
    "sdf_distance",
    "strip_robot",
    "studio_plan_inputs",
    "tcp_errors",
    "trajectory_problem",
]
