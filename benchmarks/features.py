"""Feature extraction: EfficientNet-Lite0 (JAX) time per frame, stage selection by matching
accuracy under known warps, and PCA fit/projection time.

Stage selection: natural images shipped with matplotlib / scikit-learn (no downloads) are warped
by known random similarity transforms (±20°, scale 0.85–1.15, ±15 px); every feature cell of the
source is matched to its cosine nearest neighbour in the warped image (after PCA to 64 dims, as
the pipeline uses them) and the error of the matched cell centre against the true warp is
measured in input pixels. Metrics: median error and the fraction within 4 / 8 / 16 px.

Receptive-field centres (full run only): the centroid of |∂(Σ_c feature)/∂image| of central
cells (the effective receptive field, Luo et al. 2016) minus the ``FeatureMap`` cell centre, for
network input sizes that are multiples of 32, ≡ 4 mod 8, and odd.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import jax
import jax.numpy as jnp
import matplotlib
import numpy as np

from benchmarks._util import measure, record
from rsrd_jax.features import EfficientNetConfig, EfficientNetExtractor, fit_pca

NAME = "features"


def _natural_images() -> list[np.ndarray]:
    import sklearn.datasets

    hopper = Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg"
    out = [cv2.imread(str(hopper))[:, :, ::-1]]
    out += [np.asarray(im) for im in sklearn.datasets.load_sample_images().images]
    return out


def _warp_pairs(h: int, w: int, per_image: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    pairs = []
    for im in _natural_images():
        base = cv2.resize(im, (w, h), interpolation=cv2.INTER_AREA)
        for _ in range(per_image):
            m = cv2.getRotationMatrix2D(
                (w / 2, h / 2), rng.uniform(-20, 20), rng.uniform(0.85, 1.15)
            )
            m[:, 2] += rng.uniform(-15, 15, 2)
            warped = cv2.warpAffine(
                base, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT
            )
            pairs.append((base, warped, m))
    return pairs


def _matching_errors(ext: EfficientNetExtractor, pairs, pca_dim: int = 64) -> np.ndarray:
    a_map = ext(np.stack([p[0] for p in pairs]))
    b_map = ext(np.stack([p[1] for p in pairs]))
    fa, fb = np.asarray(a_map.features), np.asarray(b_map.features)
    if fa.shape[-1] > pca_dim:
        pca = fit_pca([fa, fb], dim=pca_dim)
        fa, fb = np.asarray(pca.project(jnp.asarray(fa))), np.asarray(pca.project(jnp.asarray(fb)))
    h, w = pairs[0][0].shape[:2]
    sy, sx = a_map.stride
    gh, gw = fa.shape[1:3]
    yy, xx = np.meshgrid((np.arange(gh) + 0.5) * sy, (np.arange(gw) + 0.5) * sx, indexing="ij")
    src = np.stack([xx.ravel(), yy.ravel()], 1)
    errs = []
    for i, (_, _, m) in enumerate(pairs):
        a = fa[i].reshape(-1, fa.shape[-1])
        b = fb[i].reshape(-1, fb.shape[-1])
        a = a / np.linalg.norm(a, axis=1, keepdims=True)
        b = b / np.linalg.norm(b, axis=1, keepdims=True)
        gt = src @ m[:, :2].T + m[:, 2]
        inside = (gt[:, 0] > 8) & (gt[:, 0] < w - 8) & (gt[:, 1] > 8) & (gt[:, 1] < h - 8)
        nn = np.argmax(a @ b.T, axis=1)
        errs.append(np.linalg.norm(src[nn] - gt, axis=1)[inside])
    return np.concatenate(errs)


def _rf_offsets(net, img: np.ndarray, size: int, stride: int) -> np.ndarray:
    """Effective-receptive-field centroid minus FeatureMap cell centre (y, x) of central cells."""
    x = cv2.resize(img, (size, size), interpolation=cv2.INTER_AREA)[None] / 255.0
    x = (jnp.asarray(x, jnp.float32) - 127 / 255) / (128 / 255)
    grid = -(-size // stride)
    pitch = size / grid

    @jax.jit
    def grad_of_cell(x, i, j):
        def cell(x):
            (m,) = net.features(x, (stride,))
            return jax.lax.dynamic_slice(m, (0, i, j, 0), (1, 1, 1, m.shape[-1])).sum()

        return jnp.abs(jax.grad(cell)(x))[0].sum(-1)

    centres = (np.arange(size) + 0.5)[:, None]
    out = []
    mid = grid // 2
    for i in (mid - 1, mid):
        for j in (mid - 1, mid):
            g = np.asarray(grad_of_cell(x, i, j))
            g = g / g.sum()
            cy = float((g.sum(1)[:, None] * centres).sum())
            cx = float((g.sum(0)[:, None] * centres).sum())
            out.append((cy - (i + 0.5) * pitch, cx - (j + 0.5) * pitch))
    return np.asarray(out)


def run(quick: bool) -> list[dict]:
    """Benchmark records (see module docstring)."""
    records = []
    base = EfficientNetExtractor.pretrained()
    hopper = _natural_images()[0]
    repeat = 3 if quick else 10

    # Time per frame at the default configuration (stride-8 + upsampled stride-16 features).
    for (h, w), batch in [((128, 128), 1), ((192, 256), 1), ((128, 128), 8)]:
        img = cv2.resize(hopper, (w, h), interpolation=cv2.INTER_AREA)
        imgs = np.broadcast_to(img, (batch, h, w, 3)).copy() if batch > 1 else img
        compile_s, ms = measure(lambda x: base(x).features, imgs, repeat=repeat)
        out = base(imgs)
        records.append(
            record(
                NAME,
                {
                    "op": "extract",
                    "strides": list(base.config.strides),
                    "h": h,
                    "w": w,
                    "batch": batch,
                },
                ms,
                compile_s,
                {
                    "ms_per_frame": ms / batch,
                    "out_shape": list(out.features.shape),
                    "stride": list(out.stride),
                },
            )
        )

    img = cv2.resize(hopper, (224, 224), interpolation=cv2.INTER_AREA)
    compile_s, ms = measure(base.logits, img, repeat=repeat)
    records.append(record(NAME, {"op": "imagenet_logits", "h": 224, "w": 224}, ms, compile_s, {}))

    # Stage selection by warp-matching accuracy at 192×256.
    configs = [((8,), 1.0), ((8, 16), 1.0), ((4, 8, 16), 1.0)]
    if not quick:
        configs += [((4,), 1.0), ((16,), 1.0), ((32,), 1.0), ((4, 8), 1.0), ((8, 16, 32), 1.0),
                    ((16,), 2.0), ((8, 16), 2.0)]  # fmt: skip
    pairs = _warp_pairs(192, 256, per_image=2 if quick else 4)
    for strides, scale in configs:
        ext = EfficientNetExtractor(
            net=base.net, config=EfficientNetConfig(strides=strides, input_scale=scale)
        )
        img = pairs[0][0]
        compile_s, ms = measure(lambda x, e=ext: e(x).features, img, repeat=repeat)
        err = _matching_errors(ext, pairs)
        records.append(
            record(
                NAME,
                {
                    "op": "stage_select",
                    "strides": list(strides),
                    "input_scale": scale,
                    "h": 192,
                    "w": 256,
                },
                ms,
                compile_s,
                {
                    "grid": list(ext.output_shape(192, 256)),
                    "dim": ext.feature_dim,
                    "pairs": len(pairs),
                    "median_err_px": float(np.median(err)),
                    "within_4px": float(np.mean(err < 4)),
                    "within_8px": float(np.mean(err < 8)),
                    "within_16px": float(np.mean(err < 16)),
                },
            )
        )

    if not quick:
        for stride in (8, 16):
            for size in (128, 100, 97):
                offs = np.concatenate(
                    [_rf_offsets(base.net, im, size, stride) for im in _natural_images()]
                )
                records.append(
                    record(
                        NAME,
                        {"op": "rf_centre", "stride": stride, "size": size},
                        0.0,
                        0.0,
                        {
                            "offset_y_px": float(offs[:, 0].mean()),
                            "offset_x_px": float(offs[:, 1].mean()),
                            "offset_std_px": float(offs.std()),
                        },
                    )
                )

    # PCA over "all scan views": 40 maps of 24×32×152 → 64 dims.
    rng = np.random.default_rng(0)
    views = [rng.normal(size=(24, 32, 152)).astype(np.float32) for _ in range(40)]
    compile_s, ms = measure(lambda v: fit_pca(v, dim=64).components, views, repeat=repeat)
    pca = fit_pca(views, dim=64)
    records.append(
        record(
            NAME,
            {"op": "pca_fit", "views": 40, "grid": [24, 32], "d": 152, "k": 64},
            ms,
            compile_s,
            {},
        )
    )
    x = jnp.asarray(np.stack(views))
    compile_s, ms = measure(pca.project, x, repeat=repeat)
    records.append(
        record(
            NAME,
            {"op": "pca_project", "views": 40, "grid": [24, 32], "d": 152, "k": 64},
            ms,
            compile_s,
            {},
        )
    )
    return records
