"""Gaussian splatting: the Gaussians pytree, part posing, EWA projection and a differentiable tile
rasterizer (RGB, features, depth, alpha in one pass) following gsplat's rules and constants.

Owns rendering of Gaussians. Does not own fitting them to images (3DGS fitting), feature fields
(`features/`) or part grouping (`parts/`).
"""

from ._composite import ChunkLayout as ChunkLayout, composite as composite
from ._gaussians import (
    PAD_OPACITY_LOGIT as PAD_OPACITY_LOGIT,
    Gaussians as Gaussians,
    apply_part_poses as apply_part_poses,
    rest_part_poses as rest_part_poses,
)
from ._project import (
    ALPHA_THRESHOLD as ALPHA_THRESHOLD,
    EPS2D as EPS2D,
    FAR_PLANE as FAR_PLANE,
    GAUSSIAN_EXTEND as GAUSSIAN_EXTEND,
    MAX_ALPHA as MAX_ALPHA,
    NEAR_PLANE as NEAR_PLANE,
    TRANSMITTANCE_THRESHOLD as TRANSMITTANCE_THRESHOLD,
    Projected as Projected,
    blend_weights as blend_weights,
    project_gaussians as project_gaussians,
)
from ._raster import (
    RenderConfig as RenderConfig,
    RenderOutput as RenderOutput,
    Bins as Bins,
    bin_gaussians as bin_gaussians,
    bins_for as bins_for,
    choose_config as choose_config,
    render as render,
)
from ._fit import (
    FitConfig as FitConfig,
    FitResult as FitResult,
    fit_gaussians as fit_gaussians,
    init_from_points as init_from_points,
    points_from_depth as points_from_depth,
    points_in_frustums as points_in_frustums,
    psnr as psnr,
    refined_camera as refined_camera,
    scene_extent as scene_extent,
    size_render_config as size_render_config,
    ssim as ssim,
)
