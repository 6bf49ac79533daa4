"""Geometry: cameras (intrinsics, projection, OpenGL↔OpenCV) and SE(3) helpers over jaxlie.

Owns frame conventions (see `_se3.py`'s docstring) and camera maths. Does not own rendering
(`splat/`, `studio/`) or file formats (`io/`).
"""

from ._camera import (
    Camera as Camera,
    Intrinsics as Intrinsics,
    T_cam_world_to_opengl_c2w as T_cam_world_to_opengl_c2w,
    backproject_depth as backproject_depth,
    opengl_c2w_to_T_cam_world as opengl_c2w_to_T_cam_world,
    pixel_directions as pixel_directions,
    project_points as project_points,
)
from ._roi import (
    box_intrinsics as box_intrinsics,
    crop as crop,
    full_frame_box as full_frame_box,
    roi_box as roi_box,
)
from ._se3 import (
    look_at as look_at,
    pose_error as pose_error,
    se3_from_rt as se3_from_rt,
    se3_from_wxyz_xyz as se3_from_wxyz_xyz,
    yaw_rotation as yaw_rotation,
)
