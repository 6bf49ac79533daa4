"""SE(3) helpers over jaxlie shared by every stage.

Conventions (documented once, here):
- `T_a_b` maps points given in frame b into frame a: `p_a = T_a_b @ p_b`; composition
  `T_a_c = T_a_b @ T_b_c`.
- Quaternions are wxyz; poses on disk are 7-vectors `wxyz_xyz` (jaxlie's `SE3.wxyz_xyz`).
- Units: metres and radians.
- Frames: `world` is the scan's own coordinates; `obj` the object model frame; `part` a part's
  frame (origin at the part centroid); `cam` a camera with OpenCV axes (x right, y down, z forward).
"""

from __future__ import annotations

import jax.numpy as jnp
import jaxlie
import numpy as np
from collections.abc import Sequence

from jax.typing import ArrayLike
from jaxtyping import Array, Float


def se3_from_wxyz_xyz(arr: Float[ArrayLike, "*batch 7"]) -> jaxlie.SE3:
    """SE3 from wxyz_xyz 7-vectors (the on-disk format); the quaternion is normalised."""
    arr = jnp.asarray(arr)
    q = arr[..., :4] / jnp.linalg.norm(arr[..., :4], axis=-1, keepdims=True)
    return jaxlie.SE3(jnp.concatenate([q, arr[..., 4:]], axis=-1))


def se3_from_rt(R: Float[Array, "*batch 3 3"], t: Float[Array, "*batch 3"]) -> jaxlie.SE3:
    """SE3 from a rotation matrix and a translation."""
    return jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.from_matrix(R), t)


Vec3 = ArrayLike | Sequence[float | int]


def look_at(eye: Vec3, target: Vec3, up: Vec3 = (0.0, 0.0, 1.0)) -> jaxlie.SE3:
    """`T_cam_world` of an OpenCV camera at `eye` looking at `target` with world `up` pointing up
    in the image (image y is down)."""
    eye, target, up = (np.asarray(v, np.float64) for v in (eye, target, up))
    z = target - eye
    z = z / np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-8:  # looking along `up`: pick any perpendicular x
        x = np.cross(z, np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0]))
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    R_world_cam = np.stack([x, y, z], axis=1)
    T_world_cam = se3_from_rt(jnp.asarray(R_world_cam, jnp.float32), jnp.asarray(eye, jnp.float32))
    return T_world_cam.inverse()


def pose_error(
    T_a: jaxlie.SE3, T_b: jaxlie.SE3
) -> tuple[Float[Array, "*batch"], Float[Array, "*batch"]]:
    """Translation error (metres) and rotation angle error (radians) between two poses."""
    d = T_a.inverse() @ T_b
    trans = jnp.linalg.norm(T_a.translation() - T_b.translation(), axis=-1)
    w = jnp.clip(jnp.abs(d.rotation().wxyz[..., 0]), 0.0, 1.0)
    return trans, 2.0 * jnp.arccos(w)


def yaw_rotation(yaw: ArrayLike) -> jaxlie.SO3:
    """Rotation about world +z by `yaw` radians."""
    return jaxlie.SO3.from_z_radians(jnp.asarray(yaw))
