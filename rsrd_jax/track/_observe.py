"""Frame observations on an ROI grid: crop, features (PCA space), occluder masks, mono-depth.

Occluder masks and monocular depth come from small sources behind one interface each, so a real
segmenter or depth network plugs in beside the studio's oracles.
"""

from __future__ import annotations

import abc
from pathlib import Path

import cv2
import jax.numpy as jnp
import numpy as np

from ..geometry import Intrinsics, box_intrinsics, crop, full_frame_box, roi_box  # noqa: F401 (re-exported)
from ..io import ArtefactError, read_camera_json, read_depth_png, read_label_png
from ._dpm import FrameObs


# ------------------------------------------------------------------------------------ sources
class OccluderSource(abc.ABC):
    """Per-frame occluder (hand/person) masks: True where the object may be hidden."""

    name: str = "occluder"

    @abc.abstractmethod
    def __call__(self, t: int, frame: np.ndarray) -> np.ndarray:
        """H×W bool mask for frame `t` (the full-resolution RGB frame is given)."""


class NoOccluder(OccluderSource):
    name = "none"

    def __call__(self, t: int, frame: np.ndarray) -> np.ndarray:
        return np.zeros(frame.shape[:2], bool)


class StudioHandMasks(OccluderSource):
    """The studio's ground-truth hand masks (`demo/gt/hand_mask/NNNNN.png`), dilated by 1 pixel."""

    name = "studio hand masks (oracle)"

    def __init__(self, demo_dir: str | Path):
        self.dir = Path(demo_dir) / "gt" / "hand_mask"
        if not self.dir.is_dir():
            raise ArtefactError(f"studio hand masks not found: {self.dir}")

    def __call__(self, t: int, frame: np.ndarray) -> np.ndarray:
        m = read_label_png(self.dir / f"{t:05d}.png") > 0
        return cv2.dilate(m.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0


class MonoDepthSource(abc.ABC):
    """Per-frame relative depth: larger = farther; only the order of values is used."""

    name: str = "mono-depth"

    @abc.abstractmethod
    def __call__(self, t: int, frame: np.ndarray) -> np.ndarray:
        """H×W float relative depth for frame `t`."""


class NoMonoDepth(MonoDepthSource):
    name = "none"

    def __call__(self, t: int, frame: np.ndarray) -> np.ndarray:
        return np.zeros(frame.shape[:2], np.float32)


class StudioDepthOracle(MonoDepthSource):
    """ORACLE: the studio's true depth through an unknown monotone transform plus noise, so only
    order information survives (a stand-in for a monocular depth network). Label it in reports."""

    name = "studio relative-depth ORACLE"

    def __init__(self, demo_dir: str | Path, seed: int = 0, noise: float = 0.01):
        self.dir = Path(demo_dir) / "gt" / "depth"
        if not self.dir.is_dir():
            raise ArtefactError(f"studio depth not found: {self.dir}")
        rng = np.random.default_rng(seed)
        self.gamma = float(rng.uniform(0.5, 2.0))
        self.scale = float(rng.uniform(0.5, 3.0))
        self.noise = noise
        self.seed = seed

    def __call__(self, t: int, frame: np.ndarray) -> np.ndarray:
        d = read_depth_png(self.dir / f"{t:05d}.png")
        d = np.where(d > 0, d, d[d > 0].max(initial=1.0) * 3)  # sky: far
        rng = np.random.default_rng(self.seed * 100003 + t)
        return (self.scale * d**self.gamma * np.exp(rng.normal(0, self.noise, d.shape))).astype(np.float32)


class OnnxDepthAnything(MonoDepthSource):
    """A user-supplied Depth-Anything (or similar) ONNX model. Its output is *disparity* (larger =
    nearer), so it is inverted to a relative depth; input normalised with ImageNet statistics."""

    name = "Depth-Anything ONNX"

    def __init__(self, path: str | Path, input_size: int = 518, output_is_disparity: bool = True):
        import onnxruntime as ort

        path = Path(path)
        if not path.is_file():
            raise ArtefactError(f"depth ONNX model not found: {path}")
        self.session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
        self.input_name = self.session.get_inputs()[0].name
        self.size = input_size
        self.disparity = output_is_disparity

    def __call__(self, t: int, frame: np.ndarray) -> np.ndarray:
        h, w = frame.shape[:2]
        x = cv2.resize(frame, (self.size, self.size), interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0
        x = (x - np.array([0.485, 0.456, 0.406], np.float32)) / np.array([0.229, 0.224, 0.225], np.float32)
        out = self.session.run(None, {self.input_name: x.transpose(2, 0, 1)[None]})[0]
        out = np.asarray(out, np.float32).reshape(out.shape[-2], out.shape[-1])
        out = cv2.resize(out, (w, h), interpolation=cv2.INTER_LINEAR)
        return 1.0 / np.maximum(out, 1e-6) if self.disparity else out


class FingertipSource(abc.ABC):
    """Per-frame 2D fingertips of the demonstrator's hands (thumb and index tip of each hand), as
    a 2D hand detector gives them (MediaPipe, HaMeR's 2D keypoints). The tracker's hand term pins
    the part each hand pinches to the midpoint of its two fingertips (`track._hands`)."""

    name: str = "fingertips"

    @property
    @abc.abstractmethod
    def num_hands(self) -> int:
        """Hands per frame (fixed for a video)."""

    @abc.abstractmethod
    def __call__(self, t: int, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(uv, detected) of frame `t`: `num_hands`×2×2 pixel coordinates (thumb tip, index tip) in
        the full frame (pixel centres at +0.5) and a `num_hands`×2 bool mask of the detected ones."""


class NoFingertips(FingertipSource):
    name = "none"

    @property
    def num_hands(self) -> int:
        return 1

    def __call__(self, t: int, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.zeros((1, 2, 2), np.float32), np.zeros((1, 2), bool)


class StudioFingertips(FingertipSource):
    """ORACLE: the studio's projected fingertips (`demo/gt/hand_keypoints.npz`, `keypoints_uv`
    T×H×2×2), optionally with Gaussian pixel noise (a detector's error, `noise_px` standard
    deviation per coordinate). A fingertip counts as detected when it projects into the image,
    also when something hides it: a 2D hand detector infers hidden fingertips from the rest of
    the hand. Label it as an oracle in reports."""

    name = "studio fingertips (oracle)"

    def __init__(self, demo_dir: str | Path, noise_px: float = 0.0, seed: int = 0):
        p = Path(demo_dir) / "gt" / "hand_keypoints.npz"
        if not p.is_file():
            raise ArtefactError(f"studio hand keypoints not found: {p}")
        with np.load(p) as z:
            if "keypoints_uv" not in z.files:
                raise ArtefactError(f"{p}: field 'keypoints_uv' missing (expected the studio's hand keypoints)")
            uv = np.asarray(z["keypoints_uv"], np.float64)
        if uv.ndim != 4 or uv.shape[2:] != (2, 2):
            raise ArtefactError(f"{p}: keypoints_uv must be T×H×2×2 (frames, hands, thumb/index, uv), got {uv.shape}")
        if noise_px < 0 or not np.isfinite(noise_px):
            raise ValueError(f"noise_px must be a finite value ≥ 0, got {noise_px}")
        K = read_camera_json(Path(demo_dir) / "camera.json")  # the image bounds of "detected"
        rng = np.random.default_rng(seed)
        self.uv = (uv + rng.normal(0.0, noise_px, uv.shape)).astype(np.float32)
        self.detected = (np.isfinite(uv).all(-1) & (uv[..., 0] >= 0) & (uv[..., 0] < K.width)
                         & (uv[..., 1] >= 0) & (uv[..., 1] < K.height))  # fmt: skip
        if noise_px > 0:
            self.name = f"studio fingertips (oracle, {noise_px:g} px noise)"

    @property
    def num_hands(self) -> int:
        return int(self.uv.shape[1])

    def __call__(self, t: int, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if not 0 <= t < len(self.uv):
            raise ArtefactError(f"studio hand keypoints: frame {t} requested, the file has {len(self.uv)} frames")
        return self.uv[t], self.detected[t]


def model_extractor(model, extractor=None):
    """The feature extractor for `model` (rebuilt from its `feature_backend` when None), checked
    against the model's PCA input dimension.

    Raises:
        ArtefactError: if the extractor's feature dimension differs from the model's.
    """
    if extractor is None:
        from ..parts import make_extractor

        extractor = make_extractor(model.feature_backend)
    if extractor.feature_dim != model.pca.input_dim:
        raise ArtefactError(
            f"feature backend mismatch: the extractor gives {extractor.feature_dim}-d features but the "
            f"model's PCA expects {model.pca.input_dim}-d ({model.feature_backend})"
        )
    return extractor


class Observer:
    """Builds `FrameObs` for a video: ROI crop -> extractor -> PCA, plus masks and mono-depth."""

    def __init__(self, extractor, pca, intrinsics: Intrinsics, roi_size: int,
                 occluder: OccluderSource | None = None, mono: MonoDepthSource | None = None,
                 fingertips: FingertipSource | None = None, table_pairs: int = 2000):  # fmt: skip
        self.extractor, self.pca, self.K = extractor, pca, intrinsics
        self.table_pairs = int(table_pairs)
        self.table_depth: np.ndarray | None = None
        """H×W metric depth (camera z) of the support plane along each pixel's ray, NaN where the
        ray does not meet it (`plane_depth`); set by the tracker once the object's pose is known.
        None: no hand depths (`hand_depths`)."""
        self.roi = int(roi_size)
        self.grid = tuple(int(x) for x in extractor.output_shape(self.roi, self.roi))
        if self.grid[0] != self.grid[1]:
            raise ValueError(f"feature grid of a square ROI must be square, got {self.grid}")
        self.occluder = occluder or NoOccluder()
        self.mono = mono or NoMonoDepth()
        self.fingertips = fingertips or NoFingertips()

    @property
    def grid_size(self) -> int:
        return self.grid[0]

    def grid_intrinsics(self, box) -> Intrinsics:
        return box_intrinsics(self.K, box, self.grid_size)

    def pinch_points(self, t: int, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each hand's pinch point on frame `t`: the midpoint of its thumb and index tips in
        full-frame pixels (H×2, 0 where not seen), and whether both tips were detected (H,)."""
        H = self.fingertips.num_hands
        tips, det = self.fingertips(t, frame)
        tips = np.asarray(tips, np.float64).reshape(H, 2, 2)
        seen = (np.asarray(det, bool).reshape(H, 2) & np.isfinite(tips).all(-1)).all(-1)
        return np.where(seen[:, None], np.nan_to_num(tips).mean(1), 0.0), seen

    def observe(self, t: int, frame: np.ndarray, box) -> FrameObs:
        """The observations of frame `t` in `box` (x0, y0, side)."""
        g = self.grid_size
        roi_img = crop(frame, box, self.roi)
        fmap = self.extractor(roi_img)
        feats = np.asarray(self.pca.project(fmap.features), np.float32).reshape(g, g, -1)
        inside = crop(np.ones(frame.shape[:2], np.float32), box, g, cv2.INTER_AREA) > 0.99
        occ_full = self.occluder(t, frame)
        occ = crop(occ_full.astype(np.float32), box, g, cv2.INTER_AREA) > 0.01
        weight = (inside & ~occ).astype(np.float32)
        rgb = crop(frame, box, g, cv2.INTER_AREA).astype(np.float32) / 255.0
        mono_full = self.mono(t, frame)
        mono = crop(mono_full.astype(np.float32), box, g, cv2.INTER_AREA)
        # background feature: median of the usable cells on the ROI's outer ring
        ring = np.zeros((g, g), bool)
        ring[:2], ring[-2:], ring[:, :2], ring[:, -2:] = True, True, True, True
        sel = ring & (weight > 0)
        bg = np.median(feats[sel], axis=0) if sel.any() else np.median(feats.reshape(-1, feats.shape[-1]), axis=0)
        bg_rgb = np.median(rgb[sel], axis=0) if sel.any() else np.median(rgb.reshape(-1, 3), axis=0)
        # each hand's pinch point in ROI-grid pixels; the anchors are set by the tracker (`track._hands`)
        pinch, seen = self.pinch_points(t, frame)
        x0, y0, side = box
        tips_grid = np.where(seen[:, None], (pinch - [x0, y0]) * (g / side), 0.0)
        hand_depth, hand_depth_seen = self.hand_depths(t, pinch, seen, mono_full, occ_full, box)
        return FrameObs(
            intrinsics=self.grid_intrinsics(box),
            features=jnp.asarray(feats),
            weight=jnp.asarray(weight),
            rgb=jnp.asarray(rgb),
            mono=jnp.asarray(mono),
            bg_feature=jnp.asarray(bg, jnp.float32),
            bg_rgb=jnp.asarray(bg_rgb, jnp.float32),
            hand_uv=jnp.asarray(tips_grid, jnp.float32),
            hand_seen=jnp.asarray(seen, jnp.float32),
            hand_part=jnp.zeros(len(seen), jnp.int32),
            hand_point=jnp.zeros((len(seen), 3), jnp.float32),
            hand_surface=jnp.zeros((len(seen), 3), jnp.float32),
            hand_weight=jnp.zeros(len(seen), jnp.float32),
            hand_depth=jnp.asarray(hand_depth),
            hand_depth_seen=jnp.asarray(hand_depth_seen),
        )

    def hand_depths(self, t: int, pinch: np.ndarray, seen: np.ndarray, mono: np.ndarray, occluded: np.ndarray,
                    box) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
        """Each seen hand's depth (camera z, m) on frame `t`, read off the table: `table_pairs`
        table pixels (the support plane seen, not occluded, outside the ROI `box` where the object
        is) have a metric depth (`table_depth`) and a mono-depth; the hand's depth is the
        threshold that best splits those the mono-depth puts nearer than the hand's pinch point
        (median of its 3×3 pixels) from those it puts farther (fewest pixels on the wrong side).
        Only the mono-depth's order is used. Unknown (seen 0) without `table_depth`, where the
        occluder mask covers the pinch point (the mono-depth there sees the hand, not the held
        part: on the studio usb_plug the brick's pinch point, behind the demonstrator's arm, read
        80 mm too near), when fewer than 5 % of the pixels lie on either side (the hand is
        outside the table's depth range) or when more than 20 % of them are on the wrong side at
        the best threshold.

        Returns:
            (H,) depths (0 where unknown), (H,) 1 where known.
        """
        H = len(seen)
        depth, known = np.zeros(H, np.float32), np.zeros(H, np.float32)
        if self.table_depth is None or not seen.any():
            return depth, known
        valid = np.isfinite(self.table_depth) & ~np.asarray(occluded, bool)
        x0, y0, side = (int(round(v)) for v in box)
        valid[max(y0, 0) : max(y0 + side, 0), max(x0, 0) : max(x0 + side, 0)] = False
        idx = np.flatnonzero(valid)
        if len(idx) < 20:
            return depth, known
        pick = np.random.default_rng(t).choice(idx, min(self.table_pairs, len(idx)), replace=False)
        z = self.table_depth.reshape(-1)[pick]
        order = np.argsort(z)
        z = z[order]
        m = np.asarray(mono, np.float64)
        m_table = m.reshape(-1)[pick][order]
        h_img, w_img = m.shape
        occ = np.asarray(occluded, bool)
        for k in np.flatnonzero(seen):
            u, v = int(np.clip(pinch[k, 0], 0, w_img - 1)), int(np.clip(pinch[k, 1], 0, h_img - 1))
            win = (slice(max(v - 1, 0), v + 2), slice(max(u - 1, 0), u + 2))
            if occ[win].mean() > 0.5:  # the hand itself hides the held part there
                continue
            farther = m_table > float(np.median(m[win]))
            # wrong side of a threshold after the i nearest pixels: farther ones before it, nearer ones after
            wrong = np.concatenate([[0], np.cumsum(farther)]) + np.concatenate([[0], np.cumsum((~farther)[::-1])])[::-1]
            i = int(np.argmin(wrong))
            if min(i, len(z) - i) < 0.05 * len(z) or wrong[i] > 0.2 * len(z):
                continue
            depth[k], known[k] = 0.5 * (z[i - 1] + z[i]), 1.0
        return depth, known


def plane_depth(intrinsics: Intrinsics, T_cam_obj, plane) -> np.ndarray:
    """H×W: the camera-frame depth z at which each pixel's ray (pixel centres at +0.5) meets the
    plane n·x = d (object frame, `plane` = (n, d)) seen from `T_cam_obj` (jaxlie SE3); NaN where
    it does not meet it in front of the camera."""
    K = intrinsics
    M = np.asarray(T_cam_obj.as_matrix(), np.float64)
    n_o, d_o = np.asarray(plane[:3], np.float64), float(plane[3])
    n_c = M[:3, :3] @ n_o
    d_c = d_o + n_c @ M[:3, 3]
    u, v = np.meshgrid(np.arange(K.width) + 0.5, np.arange(K.height) + 0.5)
    rays = np.stack([(u - float(K.cx)) / float(K.fx), (v - float(K.cy)) / float(K.fy), np.ones_like(u)], -1)
    den = rays @ n_c
    with np.errstate(divide="ignore", invalid="ignore"):
        z = d_c / den
    return np.where(np.isfinite(z) & (z > 0), z, np.nan)
