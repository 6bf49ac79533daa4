"""Studio: synthetic articulated objects rendered by MuJoCo, with ground truth.

Owns the object catalogue (MJCF stand-ins for the RSRD paper's objects and their scripted
demonstrations), the scan / demo video / robot-view generators and their ground truth. Renders
only with MuJoCo (`MUJOCO_GL=egl`), never with the project's rasterizer. Does not own file
formats (`io/`) or anything downstream.
"""

from ._catalog import get_object as get_object, list_objects as list_objects
from ._make import (
    ROBOT_CAMERA_EYE as ROBOT_CAMERA_EYE,
    ROBOT_CAMERA_TARGET as ROBOT_CAMERA_TARGET,
    TABLE_HEIGHT as TABLE_HEIGHT,
    StudioConfig as StudioConfig,
    make_demo as make_demo,
    make_object as make_object,
    make_robot_view as make_robot_view,
    make_scan as make_scan,
)
from ._scene import (
    HAND_LABEL as HAND_LABEL,
    SceneOptions as SceneOptions,
    StudioScene as StudioScene,
    build_scene as build_scene,
    part_surface_points as part_surface_points,
)
from ._spec import Contact as Contact, Geom as Geom, Part as Part, StudioObject as StudioObject, object_mjcf as object_mjcf
