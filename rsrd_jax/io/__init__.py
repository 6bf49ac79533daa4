"""Readers and writers of every artefact (DESIGN.md), validated and atomic.

Owns file formats: scan captures (nerfstudio `transforms.json`), demo videos + `camera.json`,
depth/label PNGs, and atomic writes. Every reader names the file and field it rejects.
Does not own the in-memory types of later stages beyond plain arrays.
"""

from ._atomic import (
    ArtefactError as ArtefactError,
    atomic_replace_dir as atomic_replace_dir,
    atomic_write_bytes as atomic_write_bytes,
    atomic_write_image as atomic_write_image,
    atomic_write_json as atomic_write_json,
    atomic_write_npz as atomic_write_npz,
    atomic_write_text as atomic_write_text,
    read_json as read_json,
    require as require,
)
from ._capture import (
    Capture as Capture,
    CaptureFrame as CaptureFrame,
    read_capture as read_capture,
    write_transforms as write_transforms,
)
from ._demo import (
    Demo as Demo,
    read_camera_json as read_camera_json,
    read_demo as read_demo,
    read_demo_gt as read_demo_gt,
    write_camera_json as write_camera_json,
)
from ._images import (
    DEPTH_PNG_SCALE as DEPTH_PNG_SCALE,
    read_depth_png as read_depth_png,
    read_image_rgb as read_image_rgb,
    read_label_png as read_label_png,
    read_video as read_video,
    write_depth_png as write_depth_png,
    write_label_png as write_label_png,
    write_video as write_video,
)
from ._trajectory import (
    TRAJECTORY_FORMAT as TRAJECTORY_FORMAT,
    PartTrajectory as PartTrajectory,
    load_trajectory as load_trajectory,
    save_trajectory as save_trajectory,
)
from ._plan import (
    PLAN_FORMAT as PLAN_FORMAT,
    PlanArtefact as PlanArtefact,
    load_plan as load_plan,
    save_plan as save_plan,
)
