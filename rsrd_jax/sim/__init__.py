"""sim: MuJoCo execution of a RobotPlan with the studio object, and success per stage.

Owns the simulation scene (YuMi position servos + table + the object with its real joints at
the true pose; the root rests free on the table when it is stable there, else it is welded), the
execution sequence (approach, close the grippers until they stall, follow the time-scaled joint
trajectory, release, retreat; parts move only through finger contacts and friction), the
paper's per-stage success tests (Traj, Grasp, Exec; Init is filled in by the caller) and the
``sim.json`` / ``sim.npz`` / ``sim.mp4`` / ``sim.rrd`` outputs, plus oracle plans (the demo's
contacts + IK) for tests and benchmarks. Host-side MuJoCo C, not JAX: one physics rollout is
sequential and contact-rich. Does not own planning (``plan/``) or registration.
"""

from ._config import SimConfig, SuccessConfig
from ._execute import PHASES, SIM_FORMAT, STAGE_NAMES, SimOutcome, SimResult, simulate_plan, stage_summary, with_init
from ._ik import tcp_ik
from ._oracle import contact_grasp, oracle_plan
from ._output import log_sim_rerun, save_sim_result
from ._scene import OBJECT_PREFIX, PAD_GEOMS, ROBOT_CAMERA, SimObject, SimScene, build_sim_scene, load_sim_object

__all__ = [
    "OBJECT_PREFIX", "PAD_GEOMS", "PHASES", "ROBOT_CAMERA", "SIM_FORMAT", "STAGE_NAMES", "SimConfig",
    "SimObject", "SimOutcome", "SimResult", "SimScene", "SuccessConfig", "build_sim_scene", "contact_grasp",
    "load_sim_object", "log_sim_rerun", "oracle_plan", "save_sim_result", "simulate_plan", "stage_summary",
    "tcp_ik", "with_init",
]
