"""Parts: the ObjectModel (Gaussians + feature field + parts) built from a scan capture (issue 4).

Owns: building an ObjectModel from a capture (3DGS fit via `splat._fit`, the per-Gaussian
feature field and its decoder, part labels by multi-view mask voting with visibility or automatic
grouping, part centroids, ARAP boundary pairs), its files (`model.safetensors` + `model.json`),
rebuilding its feature extractor, and the parts' surfaces as the scan's depth saw them (the
planner's geometry). Does not own rendering (`splat/`) or feature extraction
networks (`features/`).
"""

from ._build import BuildConfig as BuildConfig, build_object_model as build_object_model, log_object_model as log_object_model
from ._build import support_plane as support_plane
from ._field import (
    FieldConfig as FieldConfig,
    fit_feature_field as fit_feature_field,
    grid_intrinsics as grid_intrinsics,
    render_decoded as render_decoded,
)
from ._labels import (
    arap_pairs as arap_pairs,
    auto_group as auto_group,
    gt_part_accuracy as gt_part_accuracy,
    knn_cleanup as knn_cleanup,
    part_centroids as part_centroids,
    vote_part_labels as vote_part_labels,
)
from ._model import (
    MODEL_FORMAT as MODEL_FORMAT,
    FeatureDecoder as FeatureDecoder,
    FrozenDict as FrozenDict,
    ObjectModel as ObjectModel,
    decode_rendered as decode_rendered,
    feature_backend_record as feature_backend_record,
    load_object_model as load_object_model,
    make_extractor as make_extractor,
    save_object_model as save_object_model,
)
from ._surface import model_scan_surface as model_scan_surface, scan_surface_points as scan_surface_points
from ..splat._fit import FitConfig as FitConfig, FitResult as FitResult, fit_gaussians as fit_gaussians
