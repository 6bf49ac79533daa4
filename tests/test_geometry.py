"""Cameras and SE(3) helpers against hand-written references."""

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from rsrd_jax.geometry import (
    Camera,
    Intrinsics,
    T_cam_world_to_opengl_c2w,
    backproject_depth,
    look_at,
    opengl_c2w_to_T_cam_world,
    pose_error,
    project_points,
    se3_from_wxyz_xyz,
)


def test_projection_matches_K_matrix(rng):
    K = Intrinsics.create(100.0, 110.0, 32.5, 24.0, 64, 48)
    p = rng.uniform([-0.3, -0.3, 0.5], [0.3, 0.3, 2.0], (50, 3)).astype(np.float32)
    uv, z = project_points(K, jnp.asarray(p))
    h = p @ np.asarray(K.K()).T
    np.testing.assert_allclose(np.asarray(uv), h[:, :2] / h[:, 2:], rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(np.asarray(z), p[:, 2], rtol=1e-6)


def test_pixel_centre_convention():
    # a centred principal point (cx = w/2) puts the optical axis between the two middle pixels,
    # and backprojecting a pixel centre then projecting it lands on (j + 0.5, i + 0.5)
    K = Intrinsics.from_fov(1.0, 8, 6)
    assert float(K.cx) == 4.0 and float(K.cy) == 3.0
    pts = backproject_depth(K, jnp.full((6, 8), 2.0))
    uv, _ = project_points(K, pts)
    jj, ii = np.meshgrid(np.arange(8) + 0.5, np.arange(6) + 0.5)
    np.testing.assert_allclose(np.asarray(uv[..., 0]), jj, atol=1e-5)
    np.testing.assert_allclose(np.asarray(uv[..., 1]), ii, atol=1e-5)


def test_look_at_centres_target_and_keeps_up_up():
    K = Intrinsics.from_fov(0.8, 64, 48)
    T = look_at([0.5, -0.4, 0.3], [0.0, 0.1, 0.05])
    cam = Camera(K, T)
    uv, z = cam.project(jnp.array([0.0, 0.1, 0.05]))
    np.testing.assert_allclose(np.asarray(uv), [32.0, 24.0], atol=1e-3)
    assert float(z) > 0
    # a point above the target appears higher in the image (smaller v)
    uv_up, _ = cam.project(jnp.array([0.0, 0.1, 0.15]))
    assert float(uv_up[1]) < 24.0


def test_opengl_round_trip_and_axes(rng):
    # an OpenGL camera at the origin looking down -z (identity c2w) is an OpenCV camera with
    # y and z flipped: a point at -z in front of it has positive OpenCV depth
    T = opengl_c2w_to_T_cam_world(np.eye(4))
    p = np.asarray(T @ jnp.array([0.1, 0.2, -1.0]))
    np.testing.assert_allclose(p, [0.1, -0.2, 1.0], atol=1e-6)
    for _ in range(5):
        c2w = np.asarray(jaxlie.SE3.sample_uniform(jax.random.key(int(rng.integers(1e6)))).as_matrix(), np.float64)
        back = T_cam_world_to_opengl_c2w(opengl_c2w_to_T_cam_world(c2w))
        np.testing.assert_allclose(back, c2w, atol=1e-5)


def test_scaled_and_cropped_intrinsics_are_consistent(rng):
    K = Intrinsics.create(80.0, 80.0, 40.0, 30.0, 80, 60)
    p = jnp.asarray(rng.uniform([-0.2, -0.2, 1.0], [0.2, 0.2, 2.0], (10, 3)), jnp.float32)
    uv, _ = project_points(K, p)
    uv2, _ = project_points(K.scaled(160, 120), p)
    np.testing.assert_allclose(np.asarray(uv2), 2 * np.asarray(uv), rtol=1e-5)
    uv3, _ = project_points(K.cropped(10, 5, 40, 30), p)
    np.testing.assert_allclose(np.asarray(uv3), np.asarray(uv) - np.array([10.0, 5.0]), atol=1e-4)


@pytest.mark.parametrize("batch", [(), (3,), (2, 4)])
def test_camera_project_batches_and_vmaps(batch, key):
    K = Intrinsics.from_fov(0.9, 32, 24)
    T = look_at([0.0, -1.0, 0.5], [0.0, 0.0, 0.0])
    pts = jax.random.normal(key, batch + (3,)) * 0.1
    uv, z = Camera(K, T).project(pts)
    assert uv.shape == batch + (2,) and z.shape == batch
    # vmap over camera poses equals a loop
    Ts = jaxlie.SE3(jnp.stack([T.wxyz_xyz, look_at([1.0, 0.0, 0.5], [0, 0, 0]).wxyz_xyz]))
    uv_v, _ = jax.vmap(lambda T_: Camera(K, T_).project(pts))(Ts)
    for i in range(2):
        uv_i, _ = Camera(K, jaxlie.SE3(Ts.wxyz_xyz[i])).project(pts)
        np.testing.assert_allclose(np.asarray(uv_v[i]), np.asarray(uv_i), rtol=1e-5, atol=1e-4)


def test_bad_intrinsics_are_rejected():
    with pytest.raises(ValueError, match="focal"):
        Intrinsics.create(-1.0, 1.0, 0, 0, 4, 4)
    with pytest.raises(ValueError, match="finite"):
        Intrinsics.create(float("nan"), 1.0, 0, 0, 4, 4)
    with pytest.raises(ValueError, match="size"):
        Intrinsics.create(1.0, 1.0, 0, 0, 0, 4)
    with pytest.raises(ValueError, match="4×4"):
        opengl_c2w_to_T_cam_world(np.full((4, 4), np.nan))


def test_pose_error_and_wxyz_xyz(key):
    T = jaxlie.SE3.sample_uniform(key)
    d = jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.from_z_radians(0.2), jnp.array([0.01, 0.0, 0.0]))
    t_err, r_err = pose_error(T, T @ d)
    assert abs(float(r_err) - 0.2) < 1e-4
    assert float(t_err) == pytest.approx(0.01, abs=1e-5)
    # a non-normalised quaternion on disk is normalised on load
    arr = T.wxyz_xyz.at[:4].multiply(3.0)
    np.testing.assert_allclose(np.asarray(se3_from_wxyz_xyz(arr).as_matrix()), np.asarray(T.as_matrix()), atol=1e-5)


def test_shape_annotations_are_checked_under_pytest():
    # jaxtyping + beartype run on rsrd_jax under pytest: a wrong trailing axis is rejected
    import jaxtyping

    with pytest.raises(jaxtyping.TypeCheckError):
        project_points(Intrinsics.from_fov(1.0, 4, 4), jnp.zeros((5, 2)))
