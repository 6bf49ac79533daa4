"""Feature extraction: legacy torch pickle reader, EfficientNet-Lite0 in JAX vs a plain-numpy
forward of the same weights, ImageNet ground truth, the ONNX ViT path vs onnxruntime, and PCA vs
numpy SVD."""

from __future__ import annotations

import dataclasses
import os
import pickle
import struct
from pathlib import Path

import cv2
import equinox as eqx
import jax
import jax.numpy as jnp
import matplotlib
import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper, numpy_helper

from rsrd_jax.features import (
    PCA,
    EfficientNetConfig,
    EfficientNetExtractor,
    FeatureConfig,
    FeatureMap,
    OnnxConfig,
    OnnxFeatureExtractor,
    TorchPickleError,
    default_weights_path,
    fit_pca,
    load_efficientnet_lite0,
    load_legacy_torch_state_dict,
    make_extractor,
    mask_to_grid,
)

MILITARY_UNIFORM = 652  # ImageNet-1k class index of "military uniform"


# ----------------------------------------------------------------------------------------------
# Fixtures
# ----------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def state_dict() -> dict[str, np.ndarray]:
    return load_legacy_torch_state_dict(default_weights_path())


@pytest.fixture(scope="module")
def extractor() -> EfficientNetExtractor:
    return EfficientNetExtractor.pretrained()


@pytest.fixture(scope="module")
def hopper() -> np.ndarray:
    """Grace Hopper portrait shipped with matplotlib (600×512 RGB uint8), centre-cropped square."""
    path = Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg"
    img = cv2.imread(str(path))[:, :, ::-1]
    h, w = img.shape[:2]
    s = min(h, w)
    return np.ascontiguousarray(
        img[(h - s) // 2 : (h - s) // 2 + s, (w - s) // 2 : (w - s) // 2 + s]
    )


def _resize(img: np.ndarray, h: int, w: int) -> np.ndarray:
    return cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)


# ----------------------------------------------------------------------------------------------
# Independent plain-numpy EfficientNet-Lite0 forward (float64, unfolded batch norm, explicit
# TF-SAME padding, direct convolution sums).
# ----------------------------------------------------------------------------------------------

_NP_STRIDES = [1, 2, 1, 2, 1, 2, 1, 1, 1, 1, 1, 2, 1, 1, 1, 1]


def _np_bn(sd, x, p):
    g, b = sd[p + ".weight"], sd[p + ".bias"]
    m, v = sd[p + ".running_mean"], sd[p + ".running_var"]
    return (x - m) / np.sqrt(v.astype(np.float64) + 1e-3) * g + b


def _np_same_pad(x, k, s):
    def pads(n):
        out = -(-n // s)
        total = max((out - 1) * s + k - n, 0)
        return total // 2, total - total // 2

    return np.pad(x, (pads(x.shape[0]), pads(x.shape[1]), (0, 0)))


def _np_conv(x, w, s, depthwise):
    k = w.shape[-1]
    xp = _np_same_pad(x, k, s)
    ho, wo = (xp.shape[0] - k) // s + 1, (xp.shape[1] - k) // s + 1
    out = 0.0
    for i in range(k):
        for j in range(k):
            patch = xp[i : i + s * ho : s, j : j + s * wo : s]
            out = out + (patch * w[:, 0, i, j] if depthwise else patch @ w[:, :, i, j].T)
    return out


def _np_forward(
    sd, img01: np.ndarray, last_block: int = 15
) -> tuple[np.ndarray | None, dict[int, np.ndarray]]:
    """Logits and the stride-4/8/16 stage outputs of one H×W×3 image in [0, 1]; stops early
    (logits None) after ``last_block`` < 15."""
    relu6 = lambda a: np.clip(a, 0.0, 6.0)  # noqa: E731
    x = (img01.astype(np.float64) * 255.0 - 127.0) / 128.0
    x = relu6(_np_bn(sd, _np_conv(x, sd["_conv_stem.weight"], 2, False), "_bn0"))
    stages = {}
    for b, s in enumerate(_NP_STRIDES):
        p = f"_blocks.{b}."
        inp = x
        if p + "_expand_conv.weight" in sd:
            x = relu6(_np_bn(sd, x @ sd[p + "_expand_conv.weight"][:, :, 0, 0].T, p + "_bn0"))
        x = relu6(_np_bn(sd, _np_conv(x, sd[p + "_depthwise_conv.weight"], s, True), p + "_bn1"))
        x = _np_bn(sd, x @ sd[p + "_project_conv.weight"][:, :, 0, 0].T, p + "_bn2")
        if s == 1 and x.shape == inp.shape:
            x = x + inp
        if b == 2:
            stages[4] = x
        if b == 4:
            stages[8] = x
        if b == 10:
            stages[16] = x
        if b == last_block and b < 15:
            return None, stages
    x = relu6(_np_bn(sd, x @ sd["_conv_head.weight"][:, :, 0, 0].T, "_bn1"))
    return x.mean(axis=(0, 1)) @ sd["_fc.weight"].T + sd["_fc.bias"], stages


# ----------------------------------------------------------------------------------------------
# Legacy torch pickle reader
# ----------------------------------------------------------------------------------------------


def test_reader_loads_all_efficientnet_entries(state_dict):
    assert len(state_dict) == 296
    assert state_dict["_conv_stem.weight"].shape == (32, 3, 3, 3)
    assert state_dict["_fc.weight"].shape == (1000, 1280)
    assert state_dict["_fc.weight"].dtype == np.float32
    assert state_dict["_bn0.num_batches_tracked"].dtype == np.int64
    assert all(np.all(np.isfinite(v)) for v in state_dict.values())
    # Running variances are non-negative (some dead channels have exactly 0).
    assert all(np.all(v >= 0) for k, v in state_dict.items() if k.endswith("running_var"))


def _write_legacy(path: Path, tensors: dict[str, tuple[np.ndarray, int, tuple, tuple]]) -> None:
    """Writes a legacy torch file by hand: {name: (flat float32 storage, offset, size, stride)}.

    Placeholder globals are pickled from a temporary module and renamed to torch's in the
    protocol-2 byte stream (GLOBAL opcodes are plain text lines), so torch is never needed."""
    import collections
    import io
    import sys
    import types

    mod = types.ModuleType("zzfaketorch")

    class FloatStorage:
        pass

    def rebuild(*args):  # stands for torch._utils._rebuild_tensor_v2
        return args

    FloatStorage.__module__ = rebuild.__module__ = "zzfaketorch"
    FloatStorage.__qualname__ = "FloatStorage"
    rebuild.__qualname__ = rebuild.__name__ = "_rebuild_tensor_v2"
    mod.FloatStorage, mod._rebuild_tensor_v2 = FloatStorage, rebuild

    class P(pickle.Pickler):
        def persistent_id(self, obj):
            if isinstance(obj, tuple) and obj and obj[0] == "__storage__":
                return ("storage", FloatStorage, obj[1], "cpu", obj[2], None)
            return None

    class T:
        def __init__(self, key, n, off, size, stride):
            self.args = (
                ("__storage__", key, n),
                off,
                size,
                stride,
                False,
                collections.OrderedDict(),
            )

        def __reduce__(self):
            return (rebuild, self.args)

    od = collections.OrderedDict()
    for i, (name, (flat, off, size, stride)) in enumerate(tensors.items()):
        od[name] = T(str(i), flat.size, off, size, stride)
    body = io.BytesIO()
    sys.modules["zzfaketorch"] = mod
    try:
        P(body, protocol=2).dump(od)
    finally:
        del sys.modules["zzfaketorch"]
    raw = body.getvalue()
    raw = raw.replace(b"czzfaketorch\n_rebuild_tensor_v2\n", b"ctorch._utils\n_rebuild_tensor_v2\n")
    raw = raw.replace(b"czzfaketorch\nFloatStorage\n", b"ctorch\nFloatStorage\n")
    assert b"zzfaketorch" not in raw
    out = io.BytesIO()
    for obj in (0x1950A86A20F9469CFC6C, 1001, {"little_endian": True, "protocol_version": 1001}):
        pickle.dump(obj, out, protocol=2)
    out.write(raw)
    pickle.dump([str(i) for i in range(len(tensors))], out, protocol=2)
    for flat, *_ in tensors.values():
        out.write(struct.pack("<q", flat.size))
        out.write(flat.astype("<f4").tobytes())
    path.write_bytes(out.getvalue())


def test_reader_handles_offsets_and_strides(tmp_path):
    flat = np.arange(24, dtype=np.float32)
    path = tmp_path / "hand.pth"
    _write_legacy(
        path,
        {
            "a": (flat, 0, (2, 3, 4), (12, 4, 1)),
            "transposed": (flat[:12], 0, (4, 3), (1, 4)),
            "offset": (flat, 5, (3,), (2,)),
        },
    )
    sd = load_legacy_torch_state_dict(path)
    np.testing.assert_array_equal(sd["a"], flat.reshape(2, 3, 4))
    np.testing.assert_array_equal(sd["transposed"], flat[:12].reshape(3, 4).T)
    np.testing.assert_array_equal(sd["offset"], [5.0, 7.0, 9.0])


def test_reader_rejects_bad_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="not found"):
        load_legacy_torch_state_dict(tmp_path / "missing.pth")

    raw = default_weights_path().read_bytes()
    trunc = tmp_path / "truncated.pth"
    trunc.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(TorchPickleError, match="truncated"):
        load_legacy_torch_state_dict(trunc)

    junk = tmp_path / "junk.pth"
    junk.write_bytes(os.urandom(64))
    with pytest.raises(TorchPickleError, match="junk.pth"):
        load_legacy_torch_state_dict(junk)

    zipped = tmp_path / "zip.pth"
    zipped.write_bytes(b"PK\x03\x04" + b"\0" * 60)
    with pytest.raises(TorchPickleError, match="zip.pth"):
        load_legacy_torch_state_dict(zipped)

    # A pickle that would run code must be refused, not executed.
    class Evil:
        def __reduce__(self):
            return (os.system, ("touch " + str(tmp_path / "pwned"),))

    evil = tmp_path / "evil.pth"
    evil.write_bytes(
        pickle.dumps(0x1950A86A20F9469CFC6C, protocol=2)
        + pickle.dumps(1001, protocol=2)
        + pickle.dumps({"little_endian": True}, protocol=2)
        + pickle.dumps(Evil(), protocol=2)
    )
    with pytest.raises(TorchPickleError, match="refusing"):
        load_legacy_torch_state_dict(evil)
    assert not (tmp_path / "pwned").exists()


def test_loader_rejects_wrong_architecture(tmp_path):
    path = tmp_path / "small.pth"
    _write_legacy(path, {"_conv_stem.weight": (np.zeros(8, np.float32), 0, (8,), (1,))})
    with pytest.raises(TorchPickleError, match="_conv_stem.weight"):
        load_efficientnet_lite0(path)


# ----------------------------------------------------------------------------------------------
# EfficientNet-Lite0 vs numpy; ImageNet ground truth
# ----------------------------------------------------------------------------------------------


# Full-network checks share two compilations: logits and default features of one 3×224×224
# batch (the extractor's network sizes are multiples of 32). Odd sizes are checked on the
# stride-4 stage alone (cheap to compile and to run in numpy).


@pytest.fixture(scope="module")
def feature_batch(hopper) -> np.ndarray:
    """The portrait, a noisy copy (σ = 2/255) and a copy shifted by one pixel: 3×224×224×3."""
    img = _resize(hopper, 224, 224)
    rng = np.random.default_rng(1)
    noisy = np.clip(img + rng.normal(0, 2.0, img.shape), 0, 255).astype(np.uint8)
    return np.stack([img, noisy, np.roll(img, 1, axis=(0, 1))])


@pytest.fixture(scope="module")
def batch_logits(extractor, feature_batch) -> np.ndarray:
    return np.asarray(extractor.logits(feature_batch))


@pytest.fixture(scope="module")
def batch_features(extractor, feature_batch) -> FeatureMap:
    return extractor(feature_batch)


def _unit(a: np.ndarray) -> np.ndarray:
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def test_jax_matches_numpy_forward(state_dict, batch_logits, feature_batch, batch_features):
    ref_logits, ref_stages = _np_forward(state_dict, feature_batch[0] / 255.0)
    scale = np.abs(ref_logits).max()
    np.testing.assert_allclose(batch_logits[0], ref_logits, atol=2e-5 * scale, rtol=0)
    assert np.argmax(batch_logits[0]) == np.argmax(ref_logits)
    # Default features: [unit(stride-8 stage), unit(bilinear ×2 upsampled stride-16 stage)].
    s8, s16 = ref_stages[8], ref_stages[16]
    assert s8.shape == (28, 28, 40) and s16.shape == (14, 14, 112)
    up16 = cv2.resize(s16.astype(np.float32), (28, 28), interpolation=cv2.INTER_LINEAR)
    feats = np.asarray(batch_features.features[0])
    np.testing.assert_allclose(feats[..., :40], _unit(s8), atol=2e-4)
    np.testing.assert_allclose(feats[..., 40:], _unit(up16), atol=2e-4)


@pytest.mark.parametrize("size", [(45, 51), (46, 52)])
def test_odd_and_even_sizes_match_numpy(state_dict, extractor, hopper, size):
    """TF-SAME padding: symmetric for odd sizes, the extra pixel after for even ones."""
    img = _resize(hopper, *size)
    cfg = EfficientNetConfig(strides=(4,), size_multiple=1, normalize_levels=False)
    got = EfficientNetExtractor(net=extractor.net, config=cfg)(img).features
    _, ref = _np_forward(state_dict, img / 255.0, last_block=2)
    assert got.shape == ref[4].shape == (-(-size[0] // 4), -(-size[1] // 4), 24)
    np.testing.assert_allclose(got, ref[4], atol=2e-5 * np.abs(ref[4]).max())


def test_imagenet_class_and_stable_ranking(batch_logits):
    """Grace Hopper in uniform is ImageNet's 'military uniform' (652), the classic torch-free
    ground truth; top-5 must survive small noise and a one-pixel shift."""
    top5 = [set(np.argsort(-row)[:5]) for row in batch_logits]
    assert np.argmax(batch_logits[0]) == MILITARY_UNIFORM
    for other in top5[1:]:
        assert MILITARY_UNIFORM in other
        assert len(top5[0] & other) >= 4
    probs = jax.nn.softmax(batch_logits[0])
    assert probs[MILITARY_UNIFORM] > 0.2


# ----------------------------------------------------------------------------------------------
# Feature extractor interface
# ----------------------------------------------------------------------------------------------


def test_extractor_shapes_batching_and_levels(extractor, feature_batch, batch_features):
    fmap = batch_features
    assert isinstance(fmap, FeatureMap)
    assert fmap.features.shape == (3, 28, 28, 152) == (3, *extractor.output_shape(224, 224), 152)
    assert extractor.feature_dim == 152
    assert fmap.stride == (8.0, 8.0)
    # Float input in [0, 1] = uint8; an image's features do not depend on its batch position.
    imgs = feature_batch
    np.testing.assert_allclose(extractor(imgs / 255.0).features, fmap.features, atol=1e-5)
    np.testing.assert_allclose(extractor(imgs[::-1]).features[2], fmap.features[0], atol=1e-5)
    # Nested batch shape.
    assert extractor(imgs[None]).features.shape == (1, 3, 28, 28, 152)
    # Each level L2-normalised: the concatenated norm is sqrt(2).
    np.testing.assert_allclose(jnp.linalg.norm(fmap.features, axis=-1), np.sqrt(2), rtol=1e-4)


def test_extractor_config_stride_scale_and_size_multiple(extractor, hopper):
    img = _resize(hopper, 32, 40)
    cfg = EfficientNetConfig(strides=(8,), input_scale=2.0, normalize_levels=False)
    ext = EfficientNetExtractor(net=extractor.net, config=cfg)
    # 64×80 after scaling, rounded to multiples of 32: 64×96 → 8×12 cells.
    fmap = ext(img)
    assert fmap.features.shape == (8, 12, 40) == (*ext.output_shape(32, 40), 40)
    assert fmap.stride == (4.0, 40 / 12)
    exact = EfficientNetExtractor(
        net=extractor.net, config=dataclasses.replace(cfg, size_multiple=1)
    )
    assert exact.output_shape(32, 40) == (8, 10)
    with pytest.raises(ValueError, match="strides"):
        EfficientNetConfig(strides=(8, 12))


def test_extractor_rejects_bad_images(extractor):
    with pytest.raises(ValueError, match="H×W×3"):
        extractor(np.zeros((64, 64), np.uint8))
    with pytest.raises(ValueError, match="H×W×3"):
        extractor(np.zeros((64, 64, 4), np.uint8))
    with pytest.raises(ValueError, match="≥ 32"):
        extractor(np.zeros((16, 64, 3), np.uint8))
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        extractor(np.full((64, 64, 3), 255.0, np.float32))
    with pytest.raises(ValueError, match="non-finite"):
        extractor(np.full((64, 64, 3), np.nan, np.float32))
    with pytest.raises(ValueError, match="dtype"):
        extractor(np.zeros((64, 64, 3), np.int32))


def test_mask_to_grid_matches_block_average(rng):
    mask = rng.random((2, 3, 16, 24)) < 0.5
    grid = mask_to_grid(mask, (4, 6))
    np.testing.assert_array_equal(grid, mask.reshape(2, 3, 4, 4, 6, 4).mean((3, 5)) >= 0.5)
    # Non-integer ratio: 10 rows → 3 cells of 10/3 rows; rows 0–4 masked covers cell 1 half.
    half = np.zeros((10, 10), bool)
    half[:5] = True
    np.testing.assert_array_equal(mask_to_grid(half, (3, 3))[:, 0], [True, True, False])
    np.testing.assert_array_equal(mask_to_grid(half, (3, 3), 0.6)[:, 0], [True, False, False])
    with pytest.raises(ValueError, match="grid_shape"):
        mask_to_grid(half, (20, 3))


# ----------------------------------------------------------------------------------------------
# ONNX ViT extractor
# ----------------------------------------------------------------------------------------------

PATCH, DIM = 7, 8


def _build_vit(
    path: Path, static_batch: bool = False, grid_output: bool = False, fixed_hw=("H", "W")
) -> None:
    """A tiny ViT-like model: patch-embedding conv, tokens, a mean 'CLS' and a max 'register'
    token prepended, then a per-token tanh(x W + b) layer. Output N × (2 + h·w) × D."""
    rng = np.random.default_rng(0)
    inits = [
        numpy_helper.from_array(
            rng.normal(0, 0.2, (DIM, 3, PATCH, PATCH)).astype(np.float32), "pw"
        ),
        numpy_helper.from_array(rng.normal(0, 0.1, DIM).astype(np.float32), "pb"),
        numpy_helper.from_array(np.array([0, DIM, -1], np.int64), "shape"),
        numpy_helper.from_array(rng.normal(0, 0.5, (DIM, DIM)).astype(np.float32), "W"),
        numpy_helper.from_array(rng.normal(0, 0.1, DIM).astype(np.float32), "b"),
    ]
    nodes = [
        helper.make_node(
            "Conv", ["x", "pw", "pb"], ["grid"], kernel_shape=[PATCH] * 2, strides=[PATCH] * 2
        )
    ]
    if not grid_output:
        nodes += [
            helper.make_node("Reshape", ["grid", "shape"], ["flat"]),
            helper.make_node("Transpose", ["flat"], ["tok"], perm=[0, 2, 1]),
            helper.make_node("ReduceMean", ["tok"], ["cls"], axes=[1], keepdims=1),
            helper.make_node("ReduceMax", ["tok"], ["reg"], axes=[1], keepdims=1),
            helper.make_node("Concat", ["cls", "reg", "tok"], ["all"], axis=1),
            helper.make_node("MatMul", ["all", "W"], ["lin"]),
            helper.make_node("Add", ["lin", "b"], ["pre"]),
            helper.make_node("Tanh", ["pre"], ["tokens"]),
        ]
    batch = 1 if static_batch else "N"
    out_name = "grid" if grid_output else "tokens"
    graph = helper.make_graph(
        nodes,
        "tiny_vit",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [batch, 3, *fixed_hw])],
        [
            helper.make_tensor_value_info(
                out_name,
                TensorProto.FLOAT,
                [batch, DIM, "h", "w"] if grid_output else [batch, "T", DIM],
            )
        ],
        initializer=inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 10  # onnxruntime 1.31 rejects onnx 1.23's default IR 14
    onnx.checker.check_model(model)
    onnx.save(model, str(path))


def _direct(path: Path, imgs01: np.ndarray, mean, std) -> np.ndarray:
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    x = ((imgs01 - np.asarray(mean)) / np.asarray(std)).transpose(0, 3, 1, 2).astype(np.float32)
    return sess.run(None, {"x": x})[0]


def test_onnx_matches_onnxruntime(tmp_path, rng):
    path = tmp_path / "vit.onnx"
    _build_vit(path)
    imgs = rng.integers(0, 256, (2, 35, 49, 3), dtype=np.uint8)  # 5 × 7 patches
    mean, std = (0.5, 0.4, 0.3), (0.2, 0.25, 0.3)
    ext = OnnxFeatureExtractor(
        OnnxConfig(str(path), patch_size=PATCH, mean=mean, std=std, num_prefix_tokens=2)
    )
    fmap = ext(imgs)
    tokens = _direct(path, imgs / 255.0, mean, std)
    assert tokens.shape == (2, 2 + 35, DIM)
    assert fmap.features.shape == (2, 5, 7, DIM) and fmap.stride == (7.0, 7.0)
    np.testing.assert_allclose(fmap.features, tokens[:, 2:].reshape(2, 5, 7, DIM), atol=1e-5)
    # Patch (i, j) comes from pixels [7i, 7i+7) × [7j, 7j+7): perturbing one patch changes only it.
    bumped = imgs.copy()
    bumped[:, 14:21, 28:35] = 255 - bumped[:, 14:21, 28:35]
    diff = np.abs(np.asarray(ext(bumped).features - fmap.features)).max(axis=-1)
    assert np.all(diff[:, 2, 4] > 1e-3) and np.count_nonzero(diff > 1e-6) == 2


def test_onnx_resize_static_batch_and_grid_output(tmp_path, rng):
    path = tmp_path / "vit1.onnx"
    _build_vit(path, static_batch=True)
    imgs = rng.random((3, 40, 60, 3)).astype(np.float32)
    ext = OnnxFeatureExtractor(
        OnnxConfig(str(path), patch_size=PATCH, input_size=(28, 42), num_prefix_tokens=2)
    )
    fmap = ext(imgs)
    assert fmap.features.shape == (3, 4, 6, DIM) == (3, *ext.output_shape(40, 60), DIM)
    assert fmap.stride == (10.0, 10.0)
    # Batched with a batch-1 model = each image alone.
    np.testing.assert_allclose(fmap.features[2], ext(imgs[2]).features, atol=1e-6)

    # A model with a fixed 21×28 input: input size taken from the model, prefix count inferred.
    fpath = tmp_path / "fixed.onnx"
    _build_vit(fpath, fixed_hw=(21, 28))
    fext = OnnxFeatureExtractor(OnnxConfig(str(fpath), patch_size=PATCH))
    assert fext.config.input_size == (21, 28) and fext.output_shape(40, 60) == (3, 4)
    f = fext(imgs)
    assert f.features.shape == (3, 3, 4, DIM) and f.stride == (40 / 3, 60 / 4)
    small = np.stack([cv2.resize(im, (28, 21), interpolation=cv2.INTER_AREA) for im in imgs])
    direct = _direct(fpath, small, fext.config.mean, fext.config.std)
    np.testing.assert_allclose(f.features, direct[:, 2:].reshape(3, 3, 4, DIM), atol=1e-5)
    with pytest.raises(ValueError, match="fixed to 21×28"):
        OnnxFeatureExtractor(OnnxConfig(str(fpath), patch_size=PATCH, input_size=(14, 14)))

    gpath = tmp_path / "grid.onnx"
    _build_vit(gpath, grid_output=True)
    gext = OnnxFeatureExtractor(OnnxConfig(str(gpath), patch_size=PATCH))
    g = gext(imgs[:, :35, :49])
    direct = _direct(gpath, imgs[:, :35, :49], gext.config.mean, gext.config.std)
    np.testing.assert_allclose(g.features, direct.transpose(0, 2, 3, 1), atol=1e-5)


def test_onnx_errors(tmp_path, rng):
    with pytest.raises(FileNotFoundError, match="missing.onnx"):
        OnnxFeatureExtractor(OnnxConfig(str(tmp_path / "missing.onnx")))
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not an onnx model")
    with pytest.raises(ValueError, match="bad.onnx"):
        OnnxFeatureExtractor(OnnxConfig(str(bad)))
    path = tmp_path / "vit.onnx"
    _build_vit(path)
    ext = OnnxFeatureExtractor(OnnxConfig(str(path), patch_size=PATCH, num_prefix_tokens=1))
    with pytest.raises(ValueError, match="num_prefix_tokens=1"):
        ext(rng.integers(0, 256, (35, 49, 3), dtype=np.uint8))
    with pytest.raises(ValueError, match="input_size"):
        OnnxConfig(str(path), patch_size=PATCH, input_size=(30, 42))
    wrong_patch = OnnxFeatureExtractor(OnnxConfig(str(path), patch_size=5))
    with pytest.raises(ValueError, match="patch_size=5"):
        wrong_patch(rng.integers(0, 256, (35, 50, 3), dtype=np.uint8))


# ----------------------------------------------------------------------------------------------
# PCA
# ----------------------------------------------------------------------------------------------


def _anisotropic(rng, n, d):
    basis, _ = np.linalg.qr(rng.normal(size=(d, d)))
    scales = np.geomspace(5.0, 0.05, d)
    return (rng.normal(size=(n, d)) * scales) @ basis.T + rng.normal(size=d)


def test_pca_matches_svd(rng):
    x = _anisotropic(rng, 600, 12)
    maps = [x[:300].reshape(10, 30, 12), x[300:].reshape(15, 20, 12)]  # pooled over two "views"
    pca = fit_pca([jnp.asarray(m, jnp.float32) for m in maps], dim=5)
    xc = x - x.mean(0)
    _, s, vt = np.linalg.svd(xc, full_matrices=False)
    np.testing.assert_allclose(pca.explained_variance, s[:5] ** 2 / (len(x) - 1), rtol=1e-4)
    assert np.all(np.diff(np.asarray(pca.explained_variance)) < 0)
    np.testing.assert_allclose(np.abs(np.sum(np.asarray(pca.components) * vt[:5], 1)), 1, atol=1e-4)
    # Projection = SVD scores up to sign; reconstruction = projection onto the subspace.
    y = pca.project(jnp.asarray(maps[0], jnp.float32))
    assert y.shape == (10, 30, 5)
    scores = (xc[:300] @ vt[:5].T).reshape(10, 30, 5)
    np.testing.assert_allclose(np.abs(y), np.abs(scores), atol=1e-3)
    recon = pca.reconstruct(y)
    want = (xc[:300] @ vt[:5].T @ vt[:5] + x.mean(0)).reshape(10, 30, 12)
    np.testing.assert_allclose(recon, want, atol=1e-3)
    # Full-rank PCA round-trips exactly.
    full = fit_pca(jnp.asarray(x, jnp.float32), dim=12)
    xf = jnp.asarray(x, jnp.float32)
    np.testing.assert_allclose(full.reconstruct(full.project(xf)), xf, atol=1e-4)
    # vmap over a batch axis = batched call.
    np.testing.assert_allclose(
        jax.vmap(pca.project)(jnp.asarray(maps[0], jnp.float32)), y, atol=1e-6
    )


def test_pca_masks_serialisation_and_errors(rng):
    x = _anisotropic(rng, 200, 6).astype(np.float32).reshape(10, 20, 6)
    mask = rng.random((10, 20)) < 0.5
    a = fit_pca([x], dim=3, masks=[mask])
    b = fit_pca(x[mask], dim=3)
    np.testing.assert_allclose(a.components, b.components, atol=1e-6)
    fm = a.project_map(FeatureMap(features=jnp.asarray(x), stride=(4.0, 4.0)))
    assert fm.features.shape == (10, 20, 3) and fm.stride == (4.0, 4.0)

    arrays = a.to_arrays()
    c = PCA.from_arrays(arrays)
    for k in ("mean", "components", "explained_variance"):
        np.testing.assert_array_equal(getattr(c, k), getattr(a, k))
    with pytest.raises(ValueError, match="pca_mean"):
        PCA.from_arrays({**arrays, "pca_mean": np.zeros(5, np.float32)}, source="model.safetensors")
    with pytest.raises(ValueError, match="missing"):
        PCA.from_arrays({"pca_mean": arrays["pca_mean"]})
    with pytest.raises(ValueError, match="dim=7"):
        fit_pca(x, dim=7)
    with pytest.raises(ValueError, match="different feature dimensions"):
        fit_pca([x, x[..., :5]], dim=2)
    with pytest.raises(ValueError, match=r"masks\[0\]"):
        fit_pca([x], dim=2, masks=[mask[:5]])


def test_feature_config_round_trip_and_factory(tmp_path):
    import json

    path = tmp_path / "vit.onnx"
    _build_vit(path)
    cfg = FeatureConfig(
        backend="onnx",
        onnx=OnnxConfig(str(path), patch_size=PATCH, mean=(0.5, 0.5, 0.5)),
        efficientnet=EfficientNetConfig(strides=(4, 8), input_scale=1.5),
        pca_dim=32,
    )
    back = FeatureConfig.from_dict(json.loads(json.dumps(cfg.to_dict())))
    assert back == cfg
    ext = make_extractor(back)
    assert isinstance(ext, OnnxFeatureExtractor) and ext.config.mean == (0.5, 0.5, 0.5)
    with pytest.raises(ValueError, match="model.json.efficientnet: unknown fields"):
        FeatureConfig.from_dict(
            {**cfg.to_dict(), "efficientnet": {"stride": [8]}}, source="model.json"
        )
    with pytest.raises(ValueError, match="version"):
        FeatureConfig.from_dict({**cfg.to_dict(), "version": 99})
    with pytest.raises(ValueError, match="backend"):
        FeatureConfig(backend="dino")
    with pytest.raises(ValueError, match="needs FeatureConfig.onnx"):
        FeatureConfig(backend="onnx")


def test_extractor_chunking_matches_single_pass(extractor, rng):
    imgs = rng.integers(0, 256, (5, 32, 40, 3), dtype=np.uint8)
    chunked = EfficientNetExtractor(
        net=extractor.net, config=EfficientNetConfig(strides=(2,), chunk_size=2)
    )
    whole = EfficientNetExtractor(
        net=extractor.net, config=EfficientNetConfig(strides=(2,), chunk_size=8)
    )
    np.testing.assert_allclose(chunked(imgs).features, whole(imgs).features, atol=1e-5)


def test_extractor_traces_once_per_image_size(extractor, rng):
    """Many frames of one size, through fresh extractor objects, compile once."""
    from rsrd_jax.features._extractor import _efficientnet_features

    cfg = EfficientNetConfig(strides=(2,), chunk_size=3)
    before = eqx.debug.get_num_traces(_efficientnet_features)
    for _ in range(3):
        ext = EfficientNetExtractor(net=extractor.net, config=cfg)
        ext(rng.integers(0, 256, (2, 64, 32, 3), dtype=np.uint8))
    assert eqx.debug.get_num_traces(_efficientnet_features) == before + 1
    ext(rng.integers(0, 256, (2, 96, 32, 3), dtype=np.uint8))  # a new size traces again
    assert eqx.debug.get_num_traces(_efficientnet_features) == before + 2
