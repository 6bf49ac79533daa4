"""Named constants of the YuMi model: joint order, links, limits, home pose, files."""

from __future__ import annotations

from pathlib import Path

import numpy as np

MODEL_DIR = Path(__file__).resolve().parents[2] / "models" / "yumi_mjcf"
"""Directory holding ``yumi.xml`` (robot), ``scene.xml`` (robot + table) and the JSON facts."""
ROBOT_XML = MODEL_DIR / "yumi.xml"
SCENE_XML = MODEL_DIR / "scene.xml"
FACTS_JSON = MODEL_DIR / "yumi_kinematics.json"

TABLE_TOP_Z = 0.0
"""Height of the table top in the world (= robot base_link) frame, metres (= studio TABLE_HEIGHT)."""
TABLE_CENTER = (0.25, 0.0, -0.05)
"""Centre of the table box in the world frame (m)."""
TABLE_HALF_EXTENTS = (0.7, 0.8, 0.05)
"""Half extents of the table box (m)."""

_ARM_PHYSICAL = ("1", "2", "7", "3", "4", "5", "6")
RIGHT_ARM_JOINTS = tuple(f"yumi_joint_{k}_r" for k in _ARM_PHYSICAL)
"""Right-arm joints in physical order (body outwards): ABB joints 1, 2, 7, 3, 4, 5, 6."""
LEFT_ARM_JOINTS = tuple(f"yumi_joint_{k}_l" for k in _ARM_PHYSICAL)
"""Left-arm joints in physical order."""
GRIPPER_JOINTS = ("gripper_r_joint", "gripper_l_joint")
"""Finger travel of each gripper (m, 0..0.025 per finger; jaw = 2 q)."""
JOINT_NAMES = RIGHT_ARM_JOINTS + LEFT_ARM_JOINTS + GRIPPER_JOINTS
"""The 16-DoF joint order used everywhere (same as yourdfpy/jaxmp/RSRD's URDF order)."""
NUM_JOINTS = 16
RIGHT_ARM = slice(0, 7)
"""Slice of the right arm in a 16-vector."""
LEFT_ARM = slice(7, 14)
"""Slice of the left arm in a 16-vector."""
GRIPPER_R = 14
"""Index of the right gripper in a 16-vector."""
GRIPPER_L = 15
"""Index of the left gripper in a 16-vector."""

_ARM_LINKS = ("yumi_link_1", "yumi_link_2", "yumi_link_3", "yumi_link_4", "yumi_link_5",
              "yumi_link_6", "yumi_link_7")
LINK_NAMES = ("base_link",) + tuple(
    name
    for s in ("r", "l")
    for name in tuple(f"{lk}_{s}" for lk in _ARM_LINKS)
    + (f"gripper_{s}_base", f"gripper_{s}_finger_r", f"gripper_{s}_finger_l")
)
"""The 21 link (MuJoCo body) names in the order forward kinematics returns them."""
NUM_LINKS = len(LINK_NAMES)
TCP_SITES = ("tcp_r", "tcp_l")
"""MJCF sites of the two TCPs (URDF right_dummy_point / left_dummy_point, 0.13 m past link 7)."""

JOINT_LOWER = np.array(
    [-2.94087978961, -2.50454747661, -2.94087978961, -2.15548162621, -5.06145483078,
     -1.53588974176, -3.99680398707] * 2 + [0.0, 0.0])
"""Lower joint limits (rad; m for grippers) in JOINT_NAMES order."""
JOINT_UPPER = np.array(
    [2.94087978961, 0.759218224618, 2.94087978961, 1.3962634016, 5.06145483078,
     2.40855436775, 3.99680398707] * 2 + [0.025, 0.025])
"""Upper joint limits in JOINT_NAMES order."""
VELOCITY_LIMIT = np.array([np.pi] * 4 + [6.98131700798] * 3 + [np.pi] * 4 + [6.98131700798] * 3
                          + [0.02, 0.02])
"""Velocity limits (rad/s; m/s for grippers) in JOINT_NAMES order (URDF)."""
HOME_Q = np.array([1.21442839, -1.03205606, -1.10072738, 0.2987352, -1.85257716, 1.25363652,
                   -2.42181893, -1.24839656, -1.09802876, 1.06634394, 0.31386161, 1.90125141,
                   1.3205139, 2.43563939, 0.025, 0.025])
"""RSRD's YUMI_REST_POSE in JOINT_NAMES order: both TCPs at (0.5, -/+0.2, 0.133), pointing down."""
HOME_TCP_POSITIONS = np.array([[0.5, -0.2, 0.133], [0.5, 0.2, 0.133]])
"""TCP positions (m, world) at HOME_Q recorded in the JSON (right, left)."""

# Self-collision link pairs that are never checked. Union of (a) parent-child links, (b) RSRD's
# cuRobo `self_collision_ignore` (data/yumi.yml @ 4f0f48d, copied in the JSON; symmetrised, and its
# finger typo fixed so the two fingers of a hand ignore each other): body vs links 1-5 of both arms;
# inside an arm only links 1-2 are checked against link 6, link 7, gripper base and fingers; links
# 1/2 of one arm are not checked against link 1 of the other. At the home pose some of the ignored
# non-adjacent pairs overlap by a few mm (link 5 vs link 7), which is why cuRobo ignores them.
def _ignore_pairs() -> frozenset[frozenset[str]]:
    pairs = set()
    for s in ("r", "l"):
        chain = ["base_link"] + [f"{lk}_{s}" for lk in _ARM_LINKS] + [f"gripper_{s}_base"]
        for a, b in zip(chain[:-1], chain[1:]):
            pairs.add(frozenset((a, b)))
        hand = [f"gripper_{s}_base", f"gripper_{s}_finger_r", f"gripper_{s}_finger_l"]
        distal = [f"{lk}_{s}" for lk in _ARM_LINKS[2:]] + hand
        for a in distal:
            for b in distal:
                if a != b:
                    pairs.add(frozenset((a, b)))
        for lk in _ARM_LINKS[:5]:
            pairs.add(frozenset(("base_link", f"{lk}_{s}")))
        pairs.add(frozenset((f"yumi_link_1_{s}", f"yumi_link_2_{s}")))
        for lk in _ARM_LINKS[1:5]:
            pairs.add(frozenset((f"yumi_link_1_{s}", f"{lk}_{s}")))
            pairs.add(frozenset((f"yumi_link_2_{s}", f"{lk}_{s}")))
    pairs.add(frozenset(("yumi_link_1_r", "yumi_link_1_l")))
    pairs.add(frozenset(("yumi_link_2_r", "yumi_link_1_l")))
    pairs.add(frozenset(("yumi_link_1_r", "yumi_link_2_l")))
    return frozenset(p for p in pairs if len(p) == 2)


SELF_COLLISION_IGNORE = _ignore_pairs()
"""Unordered link-name pairs excluded from self-collision queries (see comment above)."""
