"""Hand-guided part ranking on synthetic articulated objects with known contacts."""

import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from rsrd_jax.hands import (
    LEFT,
    RIGHT,
    ArrayHandKeypoints,
    HandKeypointSource,
    RankConfig,
    fingertips_cam_to_obj,
    rank_parts,
)

T = 20


def _box_points(rng, size, centre, n):
    """Surface-ish samples of an axis-aligned box (part frame = object frame at t = 0)."""
    return centre + rng.uniform(-0.5, 0.5, (n, 3)) * np.asarray(size)


def _poses(translations):
    """T×P×7 identity-rotation poses with the given T×P×3 translations."""
    q = np.zeros(translations.shape[:-1] + (4,))
    q[..., 0] = 1.0
    return np.concatenate([q, translations], axis=-1).astype(np.float32)


def _world(points, pose):
    return np.asarray(jaxlie.SE3(jnp.asarray(pose)).apply(jnp.asarray(points, jnp.float32)))


def _cabinet(rng):
    """Base cabinet (0), drawer sliding out along +x (1), knob on the drawer front (2).

    The knob only moves because the drawer does."""
    base = _box_points(rng, (0.2, 0.2, 0.2), (0.0, 0.0, 0.0), 1500)
    drawer = _box_points(rng, (0.05, 0.16, 0.05), (0.125, 0.0, 0.05), 400)
    knob = _box_points(rng, (0.02, 0.03, 0.02), (0.16, 0.0, 0.05), 100)
    slide = np.linspace(0.0, 0.1, T)
    trans = np.zeros((T, 3, 3))
    trans[:, 1, 0] = slide
    trans[:, 2, 0] = slide
    return [base, drawer, knob], _poses(trans)


def test_touched_part_ranks_first_and_distances_match_brute_force():
    rng = np.random.default_rng(0)
    parts, poses = _cabinet(rng)
    tips = np.full((T, 2, 2, 3), np.nan, np.float32)
    # Right thumb and index pinch the drawer's top face (1 cm above) while it moves.
    for t in range(5, T):
        top = np.array([0.125, 0.0, 0.08]) + poses[t, 1, 4:]
        tips[t, RIGHT] = [top + [0, 0.01, 0.0], top - [0, 0.01, 0.0]]
    r = rank_parts(parts, poses, ArrayHandKeypoints(tips))
    assert r.method == "hands"
    assert int(r.part_order[0]) == 1
    # Mean fingertip distance against a float64 brute force over every point.
    ref = np.zeros(3)
    for p in range(3):
        ds = []
        for t in range(5, T):
            X = _world(parts[p], poses[t, p]).astype(np.float64)
            d = np.linalg.norm(tips[t, RIGHT][:, None] - X[None], axis=-1).min(1)
            ds.append(d.mean())
        ref[p] = np.mean(ds)
    np.testing.assert_allclose(np.asarray(r.mean_distance[RIGHT]), ref, rtol=1e-4, atol=1e-6)
    assert np.all(np.isinf(np.asarray(r.mean_distance[LEFT])))  # left hand never seen


def test_contact_time_not_approach_distance_decides():
    # Two parts; the hand hovers 5 cm from part 0 for most frames but touches part 1 for a few
    # frames. The contact score picks part 1; a mean distance would pick part 0.
    rng = np.random.default_rng(1)
    a = _box_points(rng, (0.04, 0.04, 0.04), (0.0, 0.0, 0.0), 300)
    b = _box_points(rng, (0.04, 0.04, 0.04), (0.3, 0.0, 0.0), 300)
    poses = _poses(np.zeros((T, 2, 3)))
    tips = np.full((T, 1, 2, 3), np.nan, np.float32)
    tips[:, 0] = [0.0, 0.0, 0.07]  # 5 cm above part 0
    tips[15:, 0] = [0.3, 0.0, 0.021]  # on part 1's top face
    r = rank_parts([a, b], poses, tips)
    assert int(r.part_order[0]) == 1
    md = np.asarray(r.mean_distance[0])
    assert md[0] < md[1]
    cd = np.asarray(r.contact_distance[0])
    assert cd[1] < 0.03 < cd[0]


def test_bimanual_pairs_are_ordered_left_right():
    rng = np.random.default_rng(2)
    base = _box_points(rng, (0.3, 0.1, 0.02), (0.0, 0.0, 0.0), 600)
    handle_a = _box_points(rng, (0.03, 0.03, 0.05), (-0.12, 0.0, 0.04), 150)
    handle_b = _box_points(rng, (0.03, 0.03, 0.05), (0.12, 0.0, 0.04), 150)
    parts = [base, handle_a, handle_b]
    poses = _poses(np.zeros((T, 3, 3)))
    tips = np.full((T, 2, 2, 3), np.nan, np.float32)
    tips[:, LEFT] = [[0.12, 0.016, 0.05], [0.12, -0.016, 0.05]]  # left hand on handle b
    tips[:, RIGHT] = [[-0.12, 0.016, 0.05], [-0.12, -0.016, 0.05]]  # right hand on handle a
    r = rank_parts(parts, poses, tips)
    assert tuple(np.asarray(r.pair_order[0]).tolist()) == (2, 1)
    assert len(r.pair_order) == 6 and np.all(np.diff(np.asarray(r.pair_score)) <= 0)
    swapped = rank_parts(parts, poses, tips[:, ::-1])
    assert tuple(np.asarray(swapped.pair_order[0]).tolist()) == (1, 2)
    assert set(np.asarray(r.part_order[:2]).tolist()) == {1, 2}


def test_motion_fallback_prefers_the_part_that_moved_relative_to_its_parent():
    rng = np.random.default_rng(3)
    parts, poses = _cabinet(rng)
    r = rank_parts(parts, poses, None)
    assert r.method == "motion"
    np.testing.assert_array_equal(np.asarray(r.parent), [-1, 0, 1])
    assert int(r.part_order[0]) == 1  # the drawer, not the knob riding on it
    motion = np.asarray(r.relative_motion)
    # Independent check: the drawer moves by slide(t) relative to the base, the knob by 0.
    np.testing.assert_allclose(motion[1], np.mean(np.linspace(0.0, 0.1, T)), rtol=1e-4)
    assert motion[2] < 1e-6 and motion[0] < 1e-6
    # All-NaN hands are no hands.
    r2 = rank_parts(parts, poses, np.full((T, 2, 2, 3), np.nan, np.float32))
    assert r2.method == "motion"
    np.testing.assert_array_equal(np.asarray(r2.part_order), np.asarray(r.part_order))


def test_motion_fallback_with_rotating_lid():
    # Box base (0) and a lid (1) hinged at its back edge, opening by 90°.
    rng = np.random.default_rng(5)
    base = _box_points(rng, (0.1, 0.1, 0.05), (0.0, 0.0, 0.0), 600)
    lid = _box_points(rng, (0.1, 0.1, 0.01), (0.0, 0.0, 0.03), 200)
    hinge = np.array([-0.05, 0.0, 0.03])
    angles = np.linspace(0.0, np.pi / 2, T)
    R = jaxlie.SO3.from_y_radians(jnp.asarray(-angles, jnp.float32))
    t = hinge - np.asarray(R.apply(jnp.asarray(hinge, jnp.float32)))
    lid_pose = np.concatenate([np.asarray(R.wxyz), t], axis=-1)
    poses = np.stack([_poses(np.zeros((T, 3))), lid_pose], axis=1).astype(np.float32)
    r = rank_parts([base, lid], poses)
    assert int(r.part_order[0]) == 1 and np.asarray(r.parent).tolist() == [-1, 0]
    # Reference RMS displacement of the lid's points, float64.
    X0 = lid.astype(np.float64)
    rms = []
    for k in range(T):
        X = _world(lid, poses[k, 1]).astype(np.float64)
        rms.append(np.sqrt(np.mean(np.sum((X - X0) ** 2, -1))))
    np.testing.assert_allclose(float(r.relative_motion[1]), np.mean(rms), rtol=1e-3)


def test_keypoint_source_protocol_and_camera_conversion():
    class Detector:
        def fingertips_obj(self):
            return np.zeros((4, 1, 2, 3), np.float32)

    assert isinstance(Detector(), HandKeypointSource)
    assert isinstance(ArrayHandKeypoints(np.zeros((4, 2, 2, 3), np.float32)), HandKeypointSource)
    rng = np.random.default_rng(6)
    T_cam_obj = jaxlie.SE3.exp(jnp.asarray(rng.normal(size=(4, 6)), jnp.float32))
    k_obj = rng.normal(size=(4, 2, 2, 3)).astype(np.float32)
    k_obj[1, 0] = np.nan
    k_cam = np.einsum("tij,thkj->thki", np.asarray(T_cam_obj.rotation().as_matrix()), k_obj)
    k_cam += np.asarray(T_cam_obj.translation())[:, None, None]
    back = np.asarray(fingertips_cam_to_obj(jnp.asarray(k_cam), T_cam_obj.wxyz_xyz))
    np.testing.assert_allclose(back, k_obj, atol=1e-4)
    assert np.all(np.isnan(back[1, 0]))


def test_bad_inputs_name_the_argument():
    rng = np.random.default_rng(7)
    parts, poses = _cabinet(rng)
    with pytest.raises(ValueError, match="T_obj_part"):
        rank_parts(parts, poses[:, :2])
    with pytest.raises(ValueError, match="hands"):
        rank_parts(parts, poses, np.zeros((T, 3, 2, 3), np.float32))
    with pytest.raises(ValueError, match="frame_weights"):
        rank_parts(parts, poses, None, frame_weights=np.zeros(T))
    with pytest.raises(ValueError, match="base_part"):
        rank_parts(parts, poses, None, config=RankConfig(base_part=5))


def _studio_demo(name: str, frames: int = 24):
    """Render-free studio demo: part surface points, T_world_part and fingertips over the demo.
    The world frame stands in for the object frame (the ranking only needs one common frame)."""
    from rsrd_jax.studio import SceneOptions, build_scene, get_object, part_surface_points

    obj = get_object(name)
    scene = build_scene(obj, np.eye(4), SceneOptions(64, 48, 45.0, 0, hands=True))
    pts = [part_surface_points(scene.model, b, 400, 0) for b in scene.body_ids]
    T, tips = [], []
    for s in np.linspace(0.0, 1.0, frames):
        scene.set_configuration(s)
        T.append(scene.part_poses())
        tips.append(scene.fingertips())
    T = np.asarray(T)
    wxyz = np.asarray(jaxlie.SO3.from_matrix(jnp.asarray(T[..., :3, :3])).wxyz)
    poses = np.concatenate([wxyz, T[..., :3, 3]], axis=-1).astype(np.float32)
    return obj, pts, poses, np.asarray(tips, np.float32)


def _check_studio(name: str):
    obj, pts, poses, tips = _studio_demo(name)
    touched = [c.part for c in obj.contacts]
    r = rank_parts(pts, poses, tips)
    assert int(r.part_order[0]) in touched
    if len(touched) == 2:  # studio hand i holds contact i; hand 0 counts as left
        assert tuple(np.asarray(r.pair_order[0]).tolist()) == tuple(touched)
    m = rank_parts(pts, poses)  # no hands: the top parts must be the animated ones
    animated = set(obj.keyframes)
    assert set(np.asarray(m.part_order[: len(animated)]).tolist()) == animated


def test_studio_frog_bimanual_and_motion():
    _check_studio("frog")


@pytest.mark.slow
@pytest.mark.parametrize("name", ["red_box", "nerf_gun", "scissors", "sunglasses", "bear", "stapler",
                                  "led_light", "wire_cutter", "usb_plug", "toy_drawer"])
def test_studio_catalogue(name):
    _check_studio(name)
