"""robot: the ABB YuMi as an MJCF model, JAX forward kinematics and collision queries.

Owns: loading ``models/yumi_mjcf`` once on the host (:func:`load_yumi` -> :class:`YumiModel`,
MuJoCo C model + MJX copy + JAX arrays), the 16-DoF joint order and limits as named constants,
batched differentiable forward kinematics of links and TCPs, signed distances robot-self /
robot-table / robot-object (JAX capsule/box functions over explicit pair lists) and an MJX
penetration check, plus assembling a MuJoCo scene with a studio object.
Does not own: planning costs (``plan/``), simulation of a plan (``sim/``), object models.
"""

from ._collision import (
    CollisionResult,
    MJXContacts,
    ObjectGeometry,
    collision_distances,
    mjx_penetration,
    object_boxes_from_points,
    object_capsules_from_points,
)
from ._constants import (
    GRIPPER_JOINTS,
    GRIPPER_L,
    GRIPPER_R,
    HOME_Q,
    HOME_TCP_POSITIONS,
    JOINT_LOWER,
    JOINT_NAMES,
    JOINT_UPPER,
    LEFT_ARM,
    LEFT_ARM_JOINTS,
    LINK_NAMES,
    MODEL_DIR,
    NUM_JOINTS,
    NUM_LINKS,
    RIGHT_ARM,
    RIGHT_ARM_JOINTS,
    ROBOT_XML,
    SCENE_XML,
    SELF_COLLISION_IGNORE,
    TABLE_CENTER,
    TABLE_HALF_EXTENTS,
    TABLE_TOP_Z,
    TCP_SITES,
    VELOCITY_LIMIT,
)
from ._distance import box_sdf, capsule_box, capsule_capsule
from ._kinematics import FKResult, forward_kinematics, tcp_jacobian, tcp_poses
from ._model import Kinematics, RobotGeometry, YumiModel, load_yumi
from ._scene import build_scene_spec, build_scene_xml, servo_ctrl

__all__ = [
    "CollisionResult", "FKResult", "GRIPPER_JOINTS", "GRIPPER_L", "GRIPPER_R", "HOME_Q",
    "HOME_TCP_POSITIONS", "JOINT_LOWER", "JOINT_NAMES", "JOINT_UPPER", "Kinematics", "LEFT_ARM",
    "LEFT_ARM_JOINTS", "LINK_NAMES", "MJXContacts", "MODEL_DIR", "NUM_JOINTS", "NUM_LINKS",
    "ObjectGeometry", "RIGHT_ARM", "RIGHT_ARM_JOINTS", "ROBOT_XML", "RobotGeometry", "SCENE_XML",
    "SELF_COLLISION_IGNORE", "TABLE_CENTER", "TABLE_HALF_EXTENTS", "TABLE_TOP_Z", "TCP_SITES",
    "VELOCITY_LIMIT", "YumiModel", "box_sdf", "build_scene_spec", "build_scene_xml",
    "capsule_box", "capsule_capsule", "collision_distances", "forward_kinematics", "load_yumi",
    "mjx_penetration", "object_boxes_from_points", "object_capsules_from_points", "servo_ctrl", "tcp_jacobian",
    "tcp_poses",
]
