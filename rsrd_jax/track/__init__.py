"""Tracking (4D-DPM): recover every part's 3D motion from a monocular demo video.

Owns frame observations (ROI crops, features, occluder masks, mono-depth sources), the loss terms
(features, depth ranking, ARAP with Barron's loss, smoothness), the per-frame Adam solve, joint
temporal smoothing, the multi-seed pose initialisation (also used for registration) and ADD
evaluation. Does not own the object model (`parts/`) or rendering (`splat/`).
"""

from ._config import InitConfig as InitConfig, LossWeights as LossWeights, TrackConfig as TrackConfig
from ._dpm import (
    FrameObs as FrameObs,
    TrackModel as TrackModel,
    Weights as Weights,
    frame_objective as frame_objective,
    render_posed as render_posed,
    solve_frame as solve_frame,
)
from ._eval import add_metrics as add_metrics, kabsch as kabsch
from ._init import initialize_pose as initialize_pose, seed_rotations as seed_rotations
from ._losses import (
    arap_loss as arap_loss,
    touch_loss as touch_loss,
    barron_loss as barron_loss,
    depth_ranking_loss as depth_ranking_loss,
    feature_loss as feature_loss,
    hand_depth_loss as hand_depth_loss,
    hand_loss as hand_loss,
    pose_smoothness as pose_smoothness,
    prismatic_loss as prismatic_loss,
    revolute_loss as revolute_loss,
    support_loss as support_loss,
)
from ._observe import (
    MonoDepthSource as MonoDepthSource,
    FingertipSource as FingertipSource,
    NoFingertips as NoFingertips,
    NoMonoDepth as NoMonoDepth,
    NoOccluder as NoOccluder,
    Observer as Observer,
    OccluderSource as OccluderSource,
    OnnxDepthAnything as OnnxDepthAnything,
    StudioDepthOracle as StudioDepthOracle,
    StudioFingertips as StudioFingertips,
    StudioHandMasks as StudioHandMasks,
    box_intrinsics as box_intrinsics,
    crop as crop,
    roi_box as roi_box,
)
from ._register import (
    Registration as Registration,
    RegistrationError as RegistrationError,
    RegistrationStatus as RegistrationStatus,
    RegWeights as RegWeights,
    RobotView as RobotView,
    icp_refine as icp_refine,
    read_robot_view as read_robot_view,
    register_object as register_object,
    registration_error as registration_error,
    select_seed as select_seed,
)
from ._track import initialize_demo as initialize_demo, track_video as track_video
