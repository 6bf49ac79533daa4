"""Pinhole cameras with OpenCV axes (x right, y down, z forward).

Pixel centres sit at integer + 0.5 (nerfstudio and gsplat): the pixel (i, j) in row i, column j
covers [j, j + 1) × [i, i + 1) and its centre is (j + 0.5, i + 0.5). A centred principal point is
therefore cx = w / 2.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Array, Float

# OpenGL camera axes (x right, y up, z backward) -> OpenCV axes (x right, y down, z forward).
Num = float | int | np.floating | np.integer
"""A plain number (beartype under pytest is strict about int vs float)."""

_GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])


class Intrinsics(eqx.Module):
    """Pinhole intrinsics in pixels; image size is static (it fixes shapes)."""

    fx: Float[Array, ""]
    """Focal length along x, pixels."""
    fy: Float[Array, ""]
    """Focal length along y, pixels."""
    cx: Float[Array, ""]
    """Principal point x, pixels (pixel centres at +0.5, so cx = w/2 is centred)."""
    cy: Float[Array, ""]
    """Principal point y, pixels."""
    width: int = eqx.field(static=True)
    """Image width in pixels."""
    height: int = eqx.field(static=True)
    """Image height in pixels."""

    @staticmethod
    def create(fx: Num, fy: Num, cx: Num, cy: Num, width: int, height: int) -> Intrinsics:
        """Builds intrinsics from plain numbers, validating them."""
        values = {"fx": fx, "fy": fy, "cx": cx, "cy": cy}
        for name, v in values.items():
            if not np.isfinite(v):
                raise ValueError(f"intrinsics field {name!r} must be finite, got {v}")
        if fx <= 0 or fy <= 0:
            raise ValueError(f"focal lengths must be positive, got fx={fx}, fy={fy}")
        if int(width) <= 0 or int(height) <= 0:
            raise ValueError(f"image size must be positive, got w={width}, h={height}")
        f32 = lambda v: jnp.asarray(v, jnp.float32)  # noqa: E731
        return Intrinsics(f32(fx), f32(fy), f32(cx), f32(cy), int(width), int(height))

    @staticmethod
    def from_fov(fov_y: Num, width: int, height: int) -> Intrinsics:
        """Square-pixel intrinsics with vertical field of view `fov_y` (radians), centred."""
        f = 0.5 * height / np.tan(0.5 * fov_y)
        return Intrinsics.create(f, f, width / 2.0, height / 2.0, width, height)

    def K(self) -> Float[Array, "3 3"]:
        """The 3×3 calibration matrix."""
        z = jnp.zeros_like(self.fx)
        return jnp.stack(
            [
                jnp.stack([self.fx, z, self.cx]),
                jnp.stack([z, self.fy, self.cy]),
                jnp.stack([z, z, jnp.ones_like(z)]),
            ]
        )

    def scaled(self, width: int, height: int) -> Intrinsics:
        """Intrinsics of the same camera resampled to `width`×`height` pixels."""
        sx, sy = width / self.width, height / self.height
        return Intrinsics(self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy, width, height)

    def cropped(self, x0: int, y0: int, width: int, height: int) -> Intrinsics:
        """Intrinsics of the crop whose top-left pixel is (x0, y0)."""
        return Intrinsics(self.fx, self.fy, self.cx - x0, self.cy - y0, width, height)

    def to_dict(self) -> dict:
        """The nerfstudio-style `fl_x, fl_y, cx, cy, w, h` dictionary."""
        return {
            "fl_x": float(self.fx),
            "fl_y": float(self.fy),
            "cx": float(self.cx),
            "cy": float(self.cy),
            "w": int(self.width),
            "h": int(self.height),
        }


class Camera(eqx.Module):
    """A calibrated camera at a pose: `T_cam_world` maps world points into the OpenCV camera frame.

    Batch it by giving `T_cam_world` leading axes (intrinsics stay shared) and `jax.vmap`.
    """

    intrinsics: Intrinsics
    T_cam_world: jaxlie.SE3

    @property
    def width(self) -> int:
        return self.intrinsics.width

    @property
    def height(self) -> int:
        return self.intrinsics.height

    def world_to_cam(self, points_world: Float[Array | np.ndarray, "*batch 3"]) -> Float[Array, "*batch 3"]:
        """World points into the camera frame (metres, OpenCV axes)."""
        return self.T_cam_world @ points_world

    def project(
        self, points_world: Float[Array | np.ndarray, "*batch 3"]
    ) -> tuple[Float[Array, "*batch 2"], Float[Array, "*batch"]]:
        """Projects world points to pixel coordinates.

        Returns:
            uv: (u, v) pixel coordinates (column, row), pixel centres at +0.5.
            z: depth along the optical axis in metres (≤ 0 means behind the camera).
        """
        return project_points(self.intrinsics, self.world_to_cam(points_world))

    def pixel_rays(self) -> tuple[Float[Array, "3"], Float[Array, "h w 3"]]:
        """World-frame ray origin and unit directions through every pixel centre."""
        d_cam = pixel_directions(self.intrinsics)
        T_world_cam = self.T_cam_world.inverse()
        d_world = jnp.einsum("ij,hwj->hwi", T_world_cam.rotation().as_matrix(), d_cam)
        d_world = d_world / jnp.linalg.norm(d_world, axis=-1, keepdims=True)
        return T_world_cam.translation(), d_world


def project_points(
    intrinsics: Intrinsics, points_cam: Float[Array | np.ndarray, "*batch 3"]
) -> tuple[Float[Array, "*batch 2"], Float[Array, "*batch"]]:
    """Pinhole projection of camera-frame points; returns (uv pixels, depth z in metres)."""
    z = points_cam[..., 2]
    safe_z = jnp.where(jnp.abs(z) < 1e-9, 1e-9, z)
    u = intrinsics.fx * points_cam[..., 0] / safe_z + intrinsics.cx
    v = intrinsics.fy * points_cam[..., 1] / safe_z + intrinsics.cy
    return jnp.stack([u, v], axis=-1), z


def pixel_directions(intrinsics: Intrinsics) -> Float[Array, "h w 3"]:
    """Camera-frame directions (z = 1) through every pixel centre."""
    u = jnp.arange(intrinsics.width, dtype=jnp.float32) + 0.5
    v = jnp.arange(intrinsics.height, dtype=jnp.float32) + 0.5
    uu, vv = jnp.meshgrid(u, v)
    x = (uu - intrinsics.cx) / intrinsics.fx
    y = (vv - intrinsics.cy) / intrinsics.fy
    return jnp.stack([x, y, jnp.ones_like(x)], axis=-1)


def backproject_depth(
    intrinsics: Intrinsics, depth: Float[Array | np.ndarray, "h w"]
) -> Float[Array, "h w 3"]:
    """Camera-frame 3D points of a z-depth map (metres); invalid depth (≤ 0) gives z ≤ 0 points."""
    return pixel_directions(intrinsics) * depth[..., None]


def opengl_c2w_to_T_cam_world(c2w: np.ndarray) -> jaxlie.SE3:
    """nerfstudio `transform_matrix` (camera-to-world, OpenGL axes) -> `T_cam_world` (OpenCV axes)."""
    c2w = np.asarray(c2w, dtype=np.float64)
    if c2w.shape == (3, 4):
        c2w = np.concatenate([c2w, [[0.0, 0.0, 0.0, 1.0]]], axis=0)
    if c2w.shape != (4, 4) or not np.all(np.isfinite(c2w)):
        raise ValueError(f"camera-to-world must be a finite 4×4 (or 3×4) matrix, got {c2w.shape}")
    T_world_cvcam = c2w @ _GL_TO_CV
    return jaxlie.SE3.from_matrix(jnp.asarray(T_world_cvcam, jnp.float32)).inverse()


def T_cam_world_to_opengl_c2w(T_cam_world: jaxlie.SE3) -> np.ndarray:
    """Inverse of `opengl_c2w_to_T_cam_world`: the nerfstudio 4×4 camera-to-world (OpenGL axes)."""
    T_world_cvcam = np.asarray(T_cam_world.inverse().as_matrix(), dtype=np.float64)
    return T_world_cvcam @ _GL_TO_CV
