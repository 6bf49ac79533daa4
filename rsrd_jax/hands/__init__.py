"""Hand keypoints and hand-guided part ranking.

Owns: the `HandKeypointSource` interface (fingertips in the object frame; the studio oracle and
detectors implement it) and `rank_parts`, which turns fingertips and part trajectories into
ranked parts and (left, right) part pairs, falling back to motion relative to the parent part
when there are no hands. Does not own: hand detection itself, grasps (`rsrd_jax.grasp`) or
planning (`rsrd_jax.plan`).
"""

from ._rank import LEFT as LEFT
from ._rank import RIGHT as RIGHT
from ._rank import ArrayHandKeypoints as ArrayHandKeypoints
from ._rank import HandKeypointSource as HandKeypointSource
from ._rank import PartRanking as PartRanking
from ._rank import RankConfig as RankConfig
from ._rank import fingertips_cam_to_obj as fingertips_cam_to_obj
from ._rank import pad_part_points as pad_part_points
from ._rank import rank_parts as rank_parts

__all__ = [
    "LEFT",
    "RIGHT",
    "ArrayHandKeypoints",
    "HandKeypointSource",
    "PartRanking",
    "RankConfig",
    "fingertips_cam_to_obj",
    "pad_part_points",
    "rank_parts",
]
