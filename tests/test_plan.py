"""Planning: trajectory costs, candidate search, RobotPlan artefact, studio ground-truth inputs."""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rsrd_jax.grasp import GraspConfig, GraspResult, PartGrasps, TopDownConfig
from rsrd_jax.io import ArtefactError, load_plan, save_plan
from rsrd_jax.plan import (
    CollisionData,
    CostParams,
    CostWeights,
    PlanConfig,
    PlanResult,
    PoseData,
    keyframe_indices,
    plan_config_from_dict,
    plan_robot,
    problem_data,
    resample_keyframes,
    root_still_trajectory,
    strip_robot,
    tcp_errors,
    trajectory_problem,
)
from rsrd_jax.plan._costs import pose_residual, pose_residual_jacobian
from rsrd_jax.robot import HOME_Q, load_yumi, object_boxes_from_points, tcp_poses


def _plain(o):
    return np.asarray(o).tolist()


@pytest.fixture(scope="module")
def robot():
    return load_yumi()


def _cube(half=0.02, n=6):
    g = np.linspace(-half, half, n)
    pts = np.stack(np.meshgrid(g, g, g), -1).reshape(-1, 3)
    return pts[np.max(np.abs(pts), 1) >= half - 1e-9]  # surface


def _grasps(n_valid=8, n_pad=0, width=0.04) -> PartGrasps:
    """Top-down grasps of a cube centred at the part origin, rolled about the approach axis."""
    rolls = np.linspace(0, np.pi, n_valid, endpoint=False)
    down = jaxlie.SO3.from_x_radians(np.pi)  # grasp z (approach) = -z of the part frame
    T = [jaxlie.SE3.from_rotation(down @ jaxlie.SO3.from_z_radians(float(r))).wxyz_xyz for r in rolls]
    T += [jnp.asarray([1.0, 0, 0, 0, 0, 0, 0])] * n_pad
    n = n_valid + n_pad
    valid = np.arange(n) < n_valid
    return PartGrasps(
        T_part_grasp=jnp.asarray(np.stack(T), jnp.float32), width=jnp.full((n,), width),
        score=jnp.where(valid, 1.0, -jnp.inf), valid=jnp.asarray(valid), base_index=jnp.arange(n),
        contacts=jnp.zeros((n, 2, 3)), base_valid=jnp.asarray(valid), result=GraspResult.success,
        num_hit=jnp.array(n), num_width_ok=jnp.array(n), num_antipodal=jnp.array(n),
    )  # fmt: skip


def _trajectory(T=12):
    """One part, rest centroid at (0, 0, 0.12) in the object frame, sliding and lifting 6 cm
    while turning 20° about z."""
    s = np.linspace(0, 1, T)
    out = []
    for si in s:
        R = jaxlie.SO3.from_z_radians(np.deg2rad(20) * si)
        out.append(jaxlie.SE3.from_rotation_and_translation(R, jnp.asarray([0.06 * si, 0.0, 0.12 + 0.03 * si])).wxyz_xyz)
    return np.asarray(out)[:, None]


T_ROBOT_OBJ = np.array([1.0, 0, 0, 0, 0.42, -0.18, 0.0])
CFG = PlanConfig(num_keyframes=4, approach_steps=4, chunk_size=8, max_iterations=40, parts=(0,), arms=(0,),
                 approach_candidates=4)  # fmt: skip


def test_keyframes_and_resampling():
    assert keyframe_indices(1, 50).tolist() == [0, 0]
    assert keyframe_indices(5, 50).tolist() == [0, 1, 2, 3, 4]
    k = keyframe_indices(100, 5)
    assert k[0] == 0 and k[-1] == 99 and len(k) == 5
    q = np.stack([np.arange(5.0)] * 16, 1)
    r = resample_keyframes(q * 0 + k[:, None].astype(float), k, 100)
    np.testing.assert_allclose(r[:, 0], np.arange(100), atol=1e-9)
    with pytest.raises(ValueError):
        keyframe_indices(0, 5)


def test_pose_residual_matches_numpy_and_gradients_match_fd(robot):
    lite = strip_robot(robot)
    K = 4
    rng = np.random.default_rng(0)
    x = jnp.asarray(HOME_Q + 0.2 * rng.standard_normal((K, 16)), jnp.float32)
    x = x.at[0, 3].set(robot.upper[3] + 0.05)  # one limit violated
    tgt = np.asarray(tcp_poses(robot, x)) + 0.0
    tgt[..., 4:] += 0.03 * rng.standard_normal(tgt[..., 4:].shape)
    tgt[..., :4] = Rotation.from_rotvec(0.2 * rng.standard_normal((K, 2, 3))).as_quat(scalar_first=True)
    active = np.array([[1.0, 0.0]] * K, np.float32)
    pose = PoseData(jnp.asarray(tgt, jnp.float32), jnp.asarray(active))
    pts = _cube()
    obj = object_boxes_from_points(pts, np.zeros(len(pts), int), 1)
    w = CostWeights(acceleration=0.5, collision=3.0, collision_margin=0.05)
    params = CostParams(lite, w, obj)
    coll = CollisionData(jnp.tile(jnp.asarray([[1.0, 0, 0, 0, 0.45, -0.2, 0.15]]), (K, 1, 1)),
                         jnp.ones((K, robot.geom.cap_radius.shape[0], 1), bool))  # fmt: skip
    prob = trajectory_problem(True, True)
    data = problem_data(pose, K, True, coll)
    res = jax.jit(lambda y: prob.residuals(y, data, params))(x)
    # pose residual against an independent numpy/scipy evaluation
    T = np.asarray(tcp_poses(robot, x))
    Rt = Rotation.from_quat(tgt[..., :4].reshape(-1, 4), scalar_first=True)
    Rc = Rotation.from_quat(T[..., :4].reshape(-1, 4), scalar_first=True)
    rot = (Rt.inv() * Rc).as_rotvec().reshape(K, 2, 3)
    pos = T[..., 4:] - tgt[..., 4:]
    r = np.asarray(res[0])
    np.testing.assert_allclose(r[:, :3], 5.0 * pos[:, 0], atol=2e-5)
    np.testing.assert_allclose(r[:, 3:6], 1.0 * rot[:, 0], atol=2e-4)
    np.testing.assert_allclose(r[:, 19:26], 1.0 * (np.asarray(x)[:, 7:14] - HOME_Q[7:14]), atol=1e-6)
    assert np.all(r[:, 6:19] == 0)  # right arm holds nothing, left arm tracks nothing
    lim = np.asarray(res[1])
    xn, lo, hi = np.asarray(x), np.asarray(robot.lower), np.asarray(robot.upper)
    np.testing.assert_allclose(lim, 100 * (np.maximum(xn - hi, 0) + np.maximum(lo - xn, 0)), rtol=1e-4, atol=1e-4)
    assert lim[0, 3] == pytest.approx(100 * 0.05, rel=1e-3)
    np.testing.assert_allclose(np.asarray(res[4]), 0.5 * (np.asarray(x)[2:] - 2 * np.asarray(x)[1:-1] + np.asarray(x)[:-2]), atol=1e-6)
    assert np.asarray(res[5]).max() > 0  # home arm near a box at 15 cm: margin active
    # gradient of the total cost vs central finite differences along random directions
    f = jax.jit(lambda y: prob.cost(y, data, params))
    g = jax.jit(jax.grad(f))(x)
    for i in range(3):
        v = jnp.asarray(rng.standard_normal((K, 16)), jnp.float32)
        v = v / jnp.linalg.norm(v)
        eps = 1e-3
        fd = (f(x + eps * v) - f(x - eps * v)) / (2 * eps)
        assert float(jnp.sum(g * v)) == pytest.approx(float(fd), rel=2e-2, abs=2e-2)


def test_analytic_pose_jacobian_matches_autodiff_and_fd(robot):
    lite = strip_robot(robot)
    params = CostParams(lite, CostWeights(), None)
    rng = np.random.default_rng(3)
    for i in range(4):
        q = jnp.asarray(HOME_Q + 0.4 * rng.standard_normal(16), jnp.float32)
        tgt = tcp_poses(robot, q + jnp.asarray(0.3 * rng.standard_normal(16), jnp.float32))
        act = jnp.asarray([[1.0, 0.0], [0.0, 1.0], [3.0, 1.0], [1.0, 1.0]][i])
        ref = (q + 0.1, jnp.asarray(2.0)) if i == 3 else (None, None)
        d = PoseData(tgt, act, *ref)
        r0 = pose_residual(q, d, params)
        r1, J1 = pose_residual_jacobian(q, d, params)
        np.testing.assert_array_equal(np.asarray(r0), np.asarray(r1))
        np.testing.assert_allclose(np.asarray(J1), np.asarray(jax.jacfwd(pose_residual)(q, d, params)), atol=2e-5)
        eps = 1e-3
        qd = np.asarray(q, np.float64)
        fd = np.stack([(np.asarray(pose_residual(jnp.asarray(qd + eps * e, jnp.float32), d, params), np.float64)
                        - np.asarray(pose_residual(jnp.asarray(qd - eps * e, jnp.float32), d, params), np.float64))
                       / (2 * eps) for e in np.eye(16)], 1)  # fmt: skip
        np.testing.assert_allclose(np.asarray(J1), fd, atol=3e-3)
    # a weight > 1 (the grasp keyframe) scales the arm's tracking rows and adds no home pull
    q = jnp.asarray(HOME_Q + 0.3 * rng.standard_normal(16), jnp.float32)
    tgt = tcp_poses(robot, q + 0.2)
    r1 = np.asarray(pose_residual(q, PoseData(tgt, jnp.asarray([1.0, 0.0])), params))
    r3 = np.asarray(pose_residual(q, PoseData(tgt, jnp.asarray([3.0, 0.0])), params))
    np.testing.assert_allclose(r3[:6], 3.0 * r1[:6], rtol=1e-5, atol=1e-7)
    assert np.all(r3[6:13] == 0) and np.all(r1[6:13] == 0)
    np.testing.assert_array_equal(r3[13:], r1[13:])
    # near the target the rotation residual's Jacobian uses the small-angle expansion
    d = PoseData(tcp_poses(robot, jnp.asarray(HOME_Q)), jnp.ones(2))
    _, J1 = pose_residual_jacobian(jnp.asarray(HOME_Q), d, params)
    np.testing.assert_allclose(np.asarray(J1), np.asarray(jax.jacfwd(pose_residual)(jnp.asarray(HOME_Q), d, params)),
                               atol=2e-5)


def test_seating_coarse_to_fine_equals_checking_every_keyframe(robot):
    """``_seat_grasps`` checks a few keyframes first; its depths equal the brute-force choice
    (every grasp, every depth, every keyframe) for the grasps that seat."""
    from rsrd_jax.grasp import build_part_mesh, sample_antipodal_grasps
    from rsrd_jax.plan._proxy import hand_clearance, hand_geometry, part_sdf, robot_proxy
    from rsrd_jax.plan._search import _pad_table_allowance, _seat_grasps, grasp_targets

    lite = strip_robot(robot)
    pts = [_cube(0.02, 8), _cube(0.015, 6)]
    K = 9
    T_obj_part = np.tile(np.array([1.0, 0, 0, 0, 0, 0, 0.12]), (K, 2, 1))
    # part 1 sweeps across, 5 cm above part 0, through some grasps' gripper at a few keyframes
    T_obj_part[:, 1, 4] = np.linspace(-0.15, 0.15, K)
    T_obj_part[:, 1, 6] = 0.12 + 0.05
    T_robot_obj = T_ROBOT_OBJ
    cfg = PlanConfig(collision_margin=0.002)
    mesh = build_part_mesh(pts[0], cfg.mesh_config)
    g = sample_antipodal_grasps(mesh, jax.random.PRNGKey(0), GraspConfig(num_grasps=12))
    proxy = robot_proxy(lite, cfg.sample_spacing)
    sdf = part_sdf(pts, cfg.sdf_spacing)
    hand = hand_geometry(lite, proxy)
    T_robot_part = np.asarray((jaxlie.SE3(jnp.asarray(T_robot_obj, jnp.float32))
                               @ jaxlie.SE3(jnp.asarray(T_obj_part, jnp.float32))).wxyz_xyz)  # fmt: skip
    Tg = np.asarray(g.T_part_grasp, float)
    opening = np.clip(np.asarray(g.width) / 2, 0, float(robot.upper[14])).astype(np.float32)
    valid = np.asarray(g.valid, bool)
    ok, depth = _seat_grasps(lite, hand, sdf, Tg, opening, valid, T_robot_obj, T_obj_part[:, 0], T_robot_part, 0, cfg)
    sub = [0, 3, 5, 8]  # the coarse keyframes for K = 9 (part 1 is right above part 0 at keyframe 4)
    brute, coarse = [], []
    for dd in cfg.grasp_depths:
        Td = np.asarray((jaxlie.SE3(jnp.asarray(Tg, jnp.float32))
                         @ jaxlie.SE3.from_translation(jnp.asarray([0.0, 0.0, -dd]))).wxyz_xyz)  # fmt: skip
        T_tcp = grasp_targets(T_robot_obj, T_obj_part[:, 0], Td)
        for out, kf in ((brute, slice(None)), (coarse, sub)):
            out.append(np.asarray(hand_clearance(lite, hand, sdf, jnp.asarray(T_tcp[:, kf], jnp.float32),
                                                 jnp.asarray(opening), jnp.asarray(T_robot_part[kf], jnp.float32),
                                                 jnp.asarray(0), True, _pad_table_allowance(cfg))))  # fmt: skip
    clear = np.stack(brute, 1) >= cfg.collision_margin
    # the fine pass decides: some grasps clear the coarse keyframes and still collide in between
    assert np.any(valid[:, None] & (np.stack(coarse, 1) >= cfg.collision_margin) & ~clear)
    ok_b = valid & clear.any(1)
    np.testing.assert_array_equal(ok, ok_b)
    assert 0 < ok.sum() < valid.sum()  # some grasps seat, some do not: the check decides something
    depth_b = np.asarray(cfg.grasp_depths)[np.argmax(clear, 1)]
    np.testing.assert_array_equal(depth[ok], depth_b[ok])
    assert len(set(depth[ok].tolist())) > 1  # several depths chosen


def test_seating_checks_the_approach_opening_at_the_grasp(robot):
    """A 60 × 12 × 4 mm plate 12 mm above the table (as on a stand), pinched across its width
    from above, once with a level jaw and once with the jaw tilted 30° about the plate's length.
    Opened 10 mm per finger beyond the grasp (the approach's narrowest opening,
    ``approach_clearance``), the tilted jaw's lower pad drops 5 mm: without
    ``seat_approach_opening`` that grasp seats at a depth where the approach must end with a pad
    in the table; with it, it seats only where the open jaw clears too (checked with
    ``hand_clearance`` directly), and the level grasp keeps its depth."""
    from rsrd_jax.plan._proxy import hand_clearance, hand_geometry, part_sdf, robot_proxy
    from rsrd_jax.plan._search import _pad_table_allowance, _seat_grasps, grasp_targets

    rng = np.random.default_rng(0)
    half = np.array([0.03, 0.006, 0.002])
    p = rng.uniform(-half, half, (6000, 3))
    face = rng.integers(0, 3, len(p))
    p[np.arange(len(p)), face] = np.sign(rng.standard_normal(len(p))) * half[face]  # surface samples
    lite = strip_robot(robot)
    K = 3
    T_obj_part = np.tile(np.array([1.0, 0, 0, 0, 0, 0, 0.012]), (K, 1, 1))
    T_obj_part[:, 0, 4] = np.linspace(0.0, 0.03, K)  # slides 3 cm sideways
    cfg = PlanConfig(collision_margin=0.002, approach_clearance=(None, 0.01))
    proxy = robot_proxy(lite, cfg.sample_spacing)
    sdf = part_sdf([p], cfg.sdf_spacing)
    hand = hand_geometry(lite, proxy)
    T_robot_part = np.asarray((jaxlie.SE3(jnp.asarray(T_ROBOT_OBJ, jnp.float32))
                               @ jaxlie.SE3(jnp.asarray(T_obj_part, jnp.float32))).wxyz_xyz)  # fmt: skip
    down = jaxlie.SO3.from_x_radians(np.pi) @ jaxlie.SO3.from_z_radians(np.pi / 2)  # z down, jaw x along the width (y)
    Tg = np.stack([np.asarray(jaxlie.SE3.from_rotation(jaxlie.SO3.from_y_radians(0.0) @ down).wxyz_xyz),
                   np.asarray(jaxlie.SE3.from_rotation(jaxlie.SO3.from_x_radians(np.deg2rad(30.0)) @ down).wxyz_xyz)])
    opening = np.full(2, 0.006, np.float32)
    valid = np.ones(2, bool)
    args = (lite, hand, sdf, Tg, opening, valid, T_ROBOT_OBJ, T_obj_part[:, 0], T_robot_part, 0, cfg)
    ok0, d0 = _seat_grasps(*args)
    ok1, d1 = _seat_grasps(*args, opening_approach=opening + 0.01)

    def open_clearance(i, d):  # the gripper at the first keyframe, jaw at the approach opening
        Td = np.asarray((jaxlie.SE3(jnp.asarray(Tg[i:i + 1], jnp.float32))
                         @ jaxlie.SE3.from_translation(jnp.asarray([0.0, 0.0, -d]))).wxyz_xyz)  # fmt: skip
        T_tcp = grasp_targets(T_ROBOT_OBJ, T_obj_part[:, 0], Td)[:, :1]
        return float(hand_clearance(lite, hand, sdf, jnp.asarray(T_tcp, jnp.float32), jnp.asarray(opening[i:i + 1] + 0.01),
                                    jnp.asarray(T_robot_part[:1], jnp.float32), jnp.asarray(0), True,
                                    _pad_table_allowance(cfg))[0])  # fmt: skip

    assert ok0.all() and ok1[0] and d1[0] == d0[0]  # the level jaw: opening it lowers no pad
    assert open_clearance(0, d1[0]) >= cfg.collision_margin
    assert open_clearance(1, d0[1]) < cfg.collision_margin  # seated without the check: the open pad hits
    assert not ok1[1] or (d1[1] > d0[1] and open_clearance(1, d1[1]) >= cfg.collision_margin)


def test_open_pads_must_clear_the_grasped_part_on_the_way_in(robot):
    """A top-down grasp of the 4 cm cube rolled 45° about the approach axis: the fully open jaw
    (pads 24 mm from the centre) cannot pass the cube's vertical edges (28 mm from it), so on
    the way in the pads cut through them. With ``approach_pads_clear_part`` the approach is
    rejected (``pads_on_part``); without it the same grasp plans. (The open pads also end inside
    the cube, so with ``approach_grasp_pads_margin``, the default, the grasp never seats: it is
    off here.) MuJoCo's own box–box distance
    between the posed pads and the cube confirms the overlap at the approach's second-to-last
    waypoint; the unrolled grasp of a 3 cm cube (9 mm gaps) passes the check."""
    traj = _trajectory()
    down = jaxlie.SO3.from_x_radians(np.pi) @ jaxlie.SO3.from_z_radians(np.pi / 4)
    g = _grasps(1, 0)
    g = dataclasses.replace(g, T_part_grasp=jnp.asarray(jaxlie.SE3.from_rotation(down).wxyz_xyz, jnp.float32)[None])
    assert plan_robot(robot, [_cube()], traj, T_ROBOT_OBJ, grasps={0: g}, config=CFG).info["rejections"]["grasp_collision"] == 1
    cfg = dataclasses.replace(CFG, approach_grasp_pads_margin=None)
    strict = plan_robot(robot, [_cube()], traj, T_ROBOT_OBJ, grasps={0: g}, config=cfg)
    assert strict.result == PlanResult.approach, strict.message
    assert strict.info["attempts"][0]["approach_rejections"] == {"pads_on_part": 1}
    assert strict.info["attempts"][0]["approach_pads_to_part_best"] < 0
    loose = plan_robot(robot, [_cube()], traj, T_ROBOT_OBJ, grasps={0: g},
                       config=dataclasses.replace(cfg, approach_pads_clear_part=False))  # fmt: skip
    assert loose.success, loose.message
    T_cube = np.asarray((jaxlie.SE3(jnp.asarray(T_ROBOT_OBJ)) @ jaxlie.SE3(jnp.asarray(traj[0, 0]))).wxyz_xyz)
    assert _right_pads_to_box(robot, (0.02, 0.02, 0.02), T_cube)(loose.q_approach[-2]) < 0.0
    ok = plan_robot(robot, [_cube(0.015)], traj, T_ROBOT_OBJ, grasps={0: _grasps(1, 0, 0.03)}, config=CFG)
    assert ok.success and ok.info["attempts"][0]["approach_pads_to_part_best"] >= CFG.collision_margin


def _box_surface(c, h, n, rng):
    p = rng.uniform(-h, h, (n, 3))
    face = rng.integers(0, 3, n)
    p[np.arange(n), face] = np.sign(rng.standard_normal(n)) * h[face]
    return p + c


def _panel_on_stand(seed=0):
    """led_light's shape: part 1 a 60 × 60 × 10 mm panel (y ∈ [0, 60] mm, z ∈ ±5 mm) with a 30 mm
    wide, 20 mm long, 6 mm thick tab sticking out of its y = 0 edge at mid-height; part 0 a 20 mm
    stand under the panel only (z ∈ [−25, −5] mm), each in its part frame (the object frame's
    (0, 0, 0.12) at rest). Returns both point sets, the trajectory (the stand still, the panel
    lifted and slid away as `_trajectory`) and the panel's (centre, half-sizes)."""
    rng = np.random.default_rng(seed)
    panel = (np.array([0.0, 0.03, 0.0]), np.array([0.03, 0.03, 0.005]))
    tab = (np.array([0.0, -0.01, 0.0]), np.array([0.015, 0.01, 0.003]))
    inside = lambda p, c, h: np.all(np.abs(p - c) < h - 1e-6, axis=1)  # noqa: E731
    a, b = _box_surface(*panel, 2500, rng), _box_surface(*tab, 1500, rng)
    part = np.concatenate([a[~inside(a, *tab)], b[~inside(b, *panel)]])  # the union's surface
    stand = _box_surface(np.array([0.0, 0.03, -0.015]), np.array([0.03, 0.03, 0.01]), 2500, rng)
    moving = _trajectory()
    still = np.tile(np.array([1.0, 0, 0, 0, 0, 0, 0.12]), (len(moving), 1, 1))
    return [stand, part], np.concatenate([still, moving], 1), panel


def test_open_pads_must_not_end_inside_the_grasped_part(robot):
    """A top-down pinch across the tab's 30 mm width, 8 mm out from the panel (led_light): the
    stand under the panel makes it seat 16 mm back (the pads' tips 4 mm below the tab's
    mid-plane, 1 mm above the stand), where the fully open pads (25 mm wide) reach 4.5 mm over the
    panel's edge with their tips below its top face, though one approach step earlier they are
    11 mm above it. With ``approach_grasp_pads_margin`` the grasp never seats; with it but without the seating
    check (``seat_approach_opening`` off) the approach is rejected (``pads_in_part_at_grasp``);
    without it the grasp plans, and MuJoCo's own box–box distance between the posed pads and the
    panel confirms that the pads end inside the panel and not one waypoint earlier. The same pinch
    at the tab's far end (pads 7.5 mm clear of the panel) plans, clear in MuJoCo too."""
    parts, traj, (c_panel, h_panel) = _panel_on_stand()
    cfg = dataclasses.replace(CFG, parts=(1,))
    down = jaxlie.SO3.from_x_radians(np.pi)  # approach along −z, the jaw's axis along the tab's width (x)

    def pinch(y):  # the grasp centre on the tab's mid-plane, as sampled grasps lie
        g = _grasps(1, 0, 0.03)
        T = jaxlie.SE3.from_rotation_and_translation(down, jnp.asarray([0.0, y, 0.0])).wxyz_xyz
        return {1: dataclasses.replace(g, T_part_grasp=jnp.asarray(T, jnp.float32)[None])}

    T_panel = np.asarray((jaxlie.SE3(jnp.asarray(T_ROBOT_OBJ, jnp.float32)) @ jaxlie.SE3(jnp.asarray(traj[0, 1], jnp.float32))
                          @ jaxlie.SE3.from_translation(jnp.asarray(c_panel, jnp.float32))).wxyz_xyz)  # fmt: skip
    to_panel = _right_pads_to_box(robot, tuple(h_panel), T_panel)
    assert PlanConfig().approach_grasp_pads_margin == -0.001  # the default
    near = plan_robot(robot, parts, traj, T_ROBOT_OBJ, grasps=pinch(-0.008), config=cfg)
    assert not near.success and near.info["rejections"]["grasp_collision"] == 1, near.message
    late = plan_robot(robot, parts, traj, T_ROBOT_OBJ, grasps=pinch(-0.008),
                      config=dataclasses.replace(cfg, seat_approach_opening=False))  # fmt: skip
    assert late.result == PlanResult.approach, late.message
    assert late.info["attempts"][0]["approach_rejections"] == {"pads_in_part_at_grasp": 1}
    assert late.info["attempts"][0]["approach_pads_at_grasp_best"] < cfg.approach_grasp_pads_margin
    loose = plan_robot(robot, parts, traj, T_ROBOT_OBJ, grasps=pinch(-0.008),
                       config=dataclasses.replace(cfg, approach_grasp_pads_margin=None))  # fmt: skip
    assert loose.success, loose.message
    assert loose.info["chosen"]["grasp_depth"][0] == 0.016  # backed off from the stand
    assert to_panel(loose.q_approach[-1]) < -0.002  # the open pads end inside the panel
    assert to_panel(loose.q_approach[-2]) > 0.01  # ... and are well above it one step earlier
    far = plan_robot(robot, parts, traj, T_ROBOT_OBJ, grasps=pinch(-0.02), config=cfg)
    assert far.success, far.message
    assert far.info["attempts"][0]["approach_pads_at_grasp_best"] >= cfg.approach_grasp_pads_margin
    assert to_panel(far.q_approach[-1]) > 0.003


def test_plan_tracks_synthetic_trajectory_and_roundtrips(robot, tmp_path):
    traj = _trajectory()
    plan = plan_robot(robot, [_cube()], traj, T_ROBOT_OBJ, grasps={0: _grasps(8, 0)}, config=CFG)
    assert plan.success, (plan.message, plan.info)
    assert plan.part.tolist() == [0, -1] and plan.active.tolist() == [True, False]
    # independent check: FK of the returned joints vs T_robot_obj · T_obj_part · T_part_grasp
    # the chosen grasp is the sampled one backed off along its approach axis (seating depth)
    g0 = jaxlie.SE3(_grasps(8, 0).T_part_grasp[plan.grasp_index[0]])
    depth = plan.info["chosen"]["grasp_depth"][0]
    assert depth in CFG.grasp_depths and depth > 0  # palm 4 mm inside the 4 cm cube at depth 0
    g = g0 @ jaxlie.SE3.from_translation(jnp.asarray([0.0, 0.0, -depth]))
    np.testing.assert_allclose(np.asarray(g.wxyz_xyz), plan.T_part_grasp[0], atol=1e-5)
    g = g.wxyz_xyz
    T_tgt = jaxlie.SE3(jnp.asarray(T_ROBOT_OBJ, jnp.float32)) @ jaxlie.SE3(jnp.asarray(traj[plan.keyframe_indices, 0], jnp.float32)) @ jaxlie.SE3(g)
    tcp = jaxlie.SE3(tcp_poses(robot, jnp.asarray(plan.q_keyframes, jnp.float32))[:, 0])
    err = np.linalg.norm(np.asarray(tcp.translation() - T_tgt.translation()), axis=-1)
    assert err.max() < 0.01
    ang = np.linalg.norm(np.asarray((T_tgt.rotation().inverse() @ tcp.rotation()).log()), axis=-1)
    assert ang.max() < np.deg2rad(10)
    # the grasp itself (first keyframe) within the tighter grasp tolerances
    assert err[0] <= CFG.grasp_position_tolerance and ang[0] <= np.deg2rad(CFG.grasp_rotation_tolerance_deg)
    assert plan.q_video.shape == (len(traj), 16)
    np.testing.assert_allclose(plan.q_video[plan.keyframe_indices], plan.q_keyframes, atol=1e-9)
    assert np.all(plan.min_distance >= 0)
    # approach: starts 6 cm behind the first grasp along the gripper z and ends at it
    tcp_a = np.asarray(tcp_poses(robot, jnp.asarray(plan.q_approach, jnp.float32))[:, 0, 4:])
    assert np.linalg.norm(tcp_a[0] - tcp_a[-1]) == pytest.approx(0.06, abs=0.01)
    assert np.linalg.norm(tcp_a[-1] - np.asarray(T_tgt.translation()[0])) < 0.01
    assert tcp_a[0, 2] > tcp_a[-1, 2] + 0.04  # top-down grasp: pre-grasp above
    # idle arm stays near home
    np.testing.assert_allclose(plan.q_keyframes[:, 7:14], np.tile(HOME_Q[7:14], (len(plan.q_keyframes), 1)), atol=0.05)
    # artefact round trip
    save_plan(plan, tmp_path / "p")
    back = load_plan(tmp_path / "p")
    assert back.success and back.result == "success"
    np.testing.assert_allclose(back.q_video, plan.q_video)
    assert back.info["rejections"]["grasp_invalid"] == 0
    # plan.json records the PlanConfig, and it rebuilds to the same config
    cfg_back = plan_config_from_dict(back.info["config"])
    assert cfg_back.grasp_depths == CFG.grasp_depths and isinstance(cfg_back.grasp_depths, tuple)
    assert float(cfg_back.weights.position) == float(CFG.weights.position)
    assert json.dumps(dataclasses.asdict(cfg_back), default=_plain) == json.dumps(dataclasses.asdict(CFG), default=_plain)
    with pytest.raises(ValueError, match="mesh_config.*nope"):
        plan_config_from_dict({"mesh_config": {"nope": 1}})
    # validation names the file and field
    js = tmp_path / "p" / "plan.json"
    meta = json.loads(js.read_text())
    meta["format"] = "nope"
    js.write_text(json.dumps(meta))
    with pytest.raises(ArtefactError, match="format"):
        load_plan(tmp_path / "p")


def test_grasp_keyframe_weight_pulls_the_first_keyframe_onto_its_target(robot):
    """A first frame 2 cm off the smooth path: the solver spreads the error over the keyframes with
    weight 1; with ``grasp_keyframe_weight`` 3 the grasp keyframe lands much closer (same grasp,
    TCP error from FK of the returned joints). A 3 cm cube: the fully open jaw (5 cm) passes it
    on the way in by the margin, the 4 cm cube's 4 mm gaps it would not."""
    traj = _trajectory()
    traj[0, 0, 4] -= 0.02
    loose = dataclasses.replace(CFG, position_tolerance=0.05, rotation_tolerance_deg=30.0,
                                grasp_position_tolerance=0.05, grasp_rotation_tolerance_deg=30.0)  # fmt: skip
    errs = []
    for w in (1.0, 3.0):
        plan = plan_robot(robot, [_cube(0.015)], traj, T_ROBOT_OBJ, grasps={0: _grasps(1, 0, 0.03)},
                          config=dataclasses.replace(loose, grasp_keyframe_weight=w))  # fmt: skip
        assert plan.success and plan.grasp_index[0] == 0, plan.message
        T_tgt = (jaxlie.SE3(jnp.asarray(T_ROBOT_OBJ, jnp.float32)) @ jaxlie.SE3(jnp.asarray(traj[plan.keyframe_indices, 0], jnp.float32))
                 @ jaxlie.SE3(jnp.asarray(plan.T_part_grasp[0], jnp.float32)))  # fmt: skip
        tcp = jaxlie.SE3(tcp_poses(robot, jnp.asarray(plan.q_keyframes, jnp.float32))[:, 0])
        errs.append(np.linalg.norm(np.asarray(tcp.translation() - T_tgt.translation()), axis=-1))
    assert errs[0][0] > 0.002  # weight 1: 2.6 mm at the grasp
    assert errs[1][0] < 0.5 * errs[0][0]  # weight 3: 0.3 mm
    assert errs[1][1:].max() < 0.005


def test_infeasible_requests_return_reasons(robot, tmp_path):
    traj = _trajectory()
    far = T_ROBOT_OBJ.copy()
    far[4] = 3.0
    plan = plan_robot(robot, [_cube()], traj, far, grasps={0: _grasps(6, 2)}, config=CFG)
    assert plan.result == PlanResult.unreachable and not plan.success
    rej = plan.info["attempts"][0]["rejections"]["right"]
    # the jaw rolled 30° or 60° off the cube's faces: fully open, its pads end 2.3 mm inside the
    # cube's vertical edges, so those four never seat (``approach_grasp_pads_margin``)
    assert rej["grasp_invalid"] == 2 and rej["grasp_collision"] == 4 and rej["pose_error"] == 2
    save_plan(plan, tmp_path / "far")
    assert load_plan(tmp_path / "far").result == "unreachable"
    # a grasp tolerance no solution meets: every solved candidate is rejected at pose_error
    tight = plan_robot(robot, [_cube()], traj, T_ROBOT_OBJ, grasps={0: _grasps(6, 0)},
                       config=dataclasses.replace(CFG, grasp_position_tolerance=1e-7))
    assert tight.result == PlanResult.unreachable
    rej = tight.info["attempts"][0]["rejections"]["right"]
    assert rej["pose_error"] > 0 and rej["joint_limits"] == rej["collision"] == 0
    # two parts: part 0's grasps all miss the tight tolerance, part 1's (at the centre of a 20 cm
    # block) never seat; the failure reported is the furthest stage reached, part 0's pose error
    two = np.concatenate([traj, traj], 1)
    two[:, 1, 5] += 0.3
    both = plan_robot(robot, [_cube(), _cube(0.1, 10)], two, T_ROBOT_OBJ, grasps={0: _grasps(6, 0), 1: _grasps(6, 0)},
                      config=dataclasses.replace(CFG, grasp_position_tolerance=1e-7, parts=(0, 1)))  # fmt: skip
    rej = [a["rejections"]["right"] for a in both.info["attempts"]]
    assert rej[0]["pose_error"] == 2 and rej[0]["grasp_collision"] == 4 and rej[1]["grasp_collision"] == 6
    assert both.result == PlanResult.unreachable and both.info["failed_stage"] == "pose_error"
    none = plan_robot(robot, [_cube()], traj, T_ROBOT_OBJ, grasps={0: _grasps(0, 8)}, config=CFG)
    assert none.result == PlanResult.no_grasp and "grasp" in none.message
    with pytest.raises(ValueError, match="T_obj_part"):
        plan_robot(robot, [_cube()], np.concatenate([traj, traj], 1), T_ROBOT_OBJ, config=CFG)
    with pytest.raises(ValueError, match="mesh_points"):
        plan_robot(robot, [_cube()], traj, T_ROBOT_OBJ, config=CFG, mesh_points=[_cube(), _cube()])


def test_a_part_that_did_not_move_is_not_planned_for(robot):
    """The fingertips touch a still cube throughout while a second cube moves: the hand ranking
    puts the still one first, and the plan holds the moving one (holding the still one would
    reproduce nothing). With the filter off, the still cube is planned for first."""
    moving = _trajectory()
    still = np.repeat(moving[:1], len(moving), 0)
    still[..., 5] += 0.25
    traj = np.concatenate([still, moving], 1)
    c = np.asarray(still[0, 0, 4:])
    tips = np.broadcast_to(np.stack([c - [0.021, 0, 0], c + [0.021, 0, 0]]), (len(traj), 1, 2, 3)).copy()
    cfg = dataclasses.replace(CFG, parts=None)
    plan = plan_robot(robot, [_cube(), _cube()], traj, T_ROBOT_OBJ, hands=tips, grasps={0: _grasps(8), 1: _grasps(8)}, config=cfg)
    assert plan.info["ranking"] == "hands" and plan.info["still_parts"] == [0]
    assert plan.info["relative_motion_mm"][0] == 0.0 and plan.info["relative_motion_mm"][1] > 20
    assert [a["parts"] for a in plan.info["attempts"]] == [{"right": 1}]
    assert plan.success and plan.part.tolist() == [1, -1], plan.message
    off = plan_robot(robot, [_cube(), _cube()], traj, T_ROBOT_OBJ, hands=tips, grasps={0: _grasps(8), 1: _grasps(8)},
                     config=dataclasses.replace(cfg, min_motion_fraction=0.0))  # fmt: skip
    assert off.info["still_parts"] == [] and off.info["attempts"][0]["parts"] == {"right": 0}


def test_tcp_errors_zero_at_fk(robot):
    q = jnp.asarray(HOME_Q, jnp.float32)[None]
    pos, rot = tcp_errors(strip_robot(robot), q, tcp_poses(robot, q))
    assert float(pos.max()) < 1e-6 and float(rot.max()) < 1e-3


@pytest.fixture(scope="module")
def nerf_gun(tmp_path_factory):
    from rsrd_jax.studio import StudioConfig, make_object

    out = tmp_path_factory.mktemp("studio") / "nerf_gun"
    small = (32, 24)
    make_object("nerf_gun", out, StudioConfig(scan_views=1, demo_frames=6, scan_size=small, demo_size=small,
                                              robot_size=small))  # fmt: skip
    return out


@pytest.mark.slow
def test_studio_inputs_match_studio_ground_truth_and_plan(robot, nerf_gun):
    """T_obj_part derived from scan + demo ground truth agrees with the studio's independent
    T_cam_world_part (built from the demo scene's own rest poses); a plan on it tracks its targets
    or says why not, with counts that add up."""
    from rsrd_jax.grasp import build_part_mesh, sample_antipodal_grasps
    from rsrd_jax.plan import studio_plan_inputs

    inp = studio_plan_inputs(nerf_gun)
    with np.load(nerf_gun / "demo/gt/part_poses.npz") as z:
        T_cwp = jaxlie.SE3(jnp.asarray(z["T_cam_world_part"], jnp.float32))
        T_cam_obj = jaxlie.SE3(jnp.asarray(z["T_cam_world"], jnp.float32)) @ jaxlie.SE3(jnp.asarray(z["T_demo_scan"], jnp.float32))
    for k in range(2):
        xl = jnp.asarray(inp.part_points[k][:64], jnp.float32)
        for t in range(inp.T_obj_part.shape[0]):
            a = (T_cam_obj @ jaxlie.SE3(jnp.asarray(inp.T_obj_part[t, k], jnp.float32))) @ xl
            b = jaxlie.SE3(T_cwp.wxyz_xyz[t, k]) @ (xl + jnp.asarray(inp.part_centroids[k], jnp.float32))
            assert float(jnp.abs(a - b).max()) < 1e-4
    moving = int(np.argmax(np.linalg.norm(inp.T_obj_part[-1, :, 4:] - inp.T_obj_part[0, :, 4:], axis=-1)))
    g = sample_antipodal_grasps(build_part_mesh(inp.part_points[moving]), jax.random.PRNGKey(0))
    g = jax.tree.map(lambda a: a[:8] if getattr(a, "ndim", 0) and a.shape[0] == g.valid.shape[0] else a, g)
    cfg = PlanConfig(num_keyframes=4, approach_steps=4, chunk_size=8, max_iterations=40, parts=(moving,), arms=(0,),
                     approach_candidates=4)  # fmt: skip
    plan = plan_robot(robot, inp.part_points, inp.T_obj_part, inp.T_robot_obj, grasps={moving: g}, config=cfg)
    rej = plan.info["attempts"][0]["rejections"]["right"]
    assert sum(rej.values()) <= 8
    if plan.success:
        assert plan.position_error[0] <= 0.01 and plan.rotation_error[0] <= np.deg2rad(10)
    else:
        assert plan.result_name in ("unreachable", "joint_limits", "collision", "approach") and plan.message


def test_root_still_trajectory_holds_the_root_and_keeps_each_part_relative_to_it():
    """Against 4×4 matrices (scipy): ``T'[t, k] = T[0, 0] · T[t, 0]⁻¹ · T[t, k]``, the root constant,
    every part's pose relative to the root unchanged, and the root motion removed reported."""
    rng = np.random.default_rng(3)
    T, P = 7, 3
    q = Rotation.random(T * P, random_state=4).as_quat().reshape(T, P, 4)  # xyzw
    x = rng.normal(0.0, 0.05, (T, P, 3))
    traj = np.concatenate([q[..., [3, 0, 1, 2]], x], -1)

    def mat(p):
        M = np.eye(4)
        M[:3, :3], M[:3, 3] = Rotation.from_quat(np.r_[p[1:4], p[0]]).as_matrix(), p[4:]
        return M

    out, removed = root_still_trajectory(traj)
    for t in range(T):
        for k in range(P):
            ref = mat(traj[0, 0]) @ np.linalg.inv(mat(traj[t, 0])) @ mat(traj[t, k])
            np.testing.assert_allclose(mat(out[t, k]), ref, atol=1e-5)
            rel = np.linalg.inv(mat(out[t, 0])) @ mat(out[t, k])
            np.testing.assert_allclose(rel, np.linalg.inv(mat(traj[t, 0])) @ mat(traj[t, k]), atol=1e-5)
    np.testing.assert_array_equal(out[:, 0], np.repeat(traj[:1, 0], T, 0))
    dist = max(np.linalg.norm(traj[t, 0, 4:] - traj[0, 0, 4:]) for t in range(T))
    turn = max((Rotation.from_matrix(mat(traj[0, 0])[:3, :3]).inv() * Rotation.from_matrix(mat(traj[t, 0])[:3, :3])).magnitude()
               for t in range(T))  # fmt: skip
    assert removed["max_root_motion_mm"] == pytest.approx(1000 * dist, abs=0.01)
    assert removed["max_root_turn_deg"] == pytest.approx(np.rad2deg(turn), abs=0.01)


def test_a_drifting_root_is_held_still_unless_a_hand_held_it(robot):
    """A cube (part 1) moving on a root cube (part 0) whose track drifts 4 cm along with it: with
    ``root_still`` the plan follows the cube relative to the still root (FK of the joints within
    1 cm of ``T_robot_obj · T_root(0) · T_root(t)⁻¹ · T_cube(t) · grasp``, ≥ 3 cm off the
    object-frame target at the last keyframe) and reports the drift; with it off (the default),
    or with a hand on the root, it follows the object-frame motion."""
    moving = _trajectory()
    drift = np.zeros_like(moving)
    drift[..., 0] = 1.0
    drift[..., 5] = 0.3
    drift[..., 4] = np.linspace(0.0, 0.04, len(moving))[:, None]  # the root slides 4 cm along x
    cube = moving.copy()
    cube[..., 4] += drift[..., 4]
    traj = np.concatenate([drift, cube], 1)
    cfg = dataclasses.replace(CFG, parts=(1,), root_still=True)
    grasps = {1: _grasps(8)}

    def fk_error(plan, target):
        g = jaxlie.SE3(jnp.asarray(plan.T_part_grasp[0], jnp.float32))
        T_tgt = jaxlie.SE3(jnp.asarray(T_ROBOT_OBJ, jnp.float32)) @ jaxlie.SE3(jnp.asarray(target[plan.keyframe_indices, 1], jnp.float32)) @ g
        tcp = jaxlie.SE3(tcp_poses(robot, jnp.asarray(plan.q_keyframes, jnp.float32))[:, 0])
        return np.linalg.norm(np.asarray(tcp.translation() - T_tgt.translation()), axis=-1)

    still = root_still_trajectory(traj)[0]
    np.testing.assert_allclose(still[:, 1, 4:], moving[:, 0, 4:], atol=1e-6)  # the cube's own motion
    plan = plan_robot(robot, [_cube(), _cube()], traj, T_ROBOT_OBJ, grasps=grasps, config=cfg)
    assert plan.success, (plan.message, plan.info)
    assert plan.info["root_still"]["max_root_motion_mm"] == pytest.approx(40.0, abs=0.01)
    assert fk_error(plan, still).max() < 0.01 and fk_error(plan, traj)[-1] > 0.03
    for off in (plan_robot(robot, [_cube(), _cube()], traj, T_ROBOT_OBJ, grasps=grasps,
                           config=dataclasses.replace(cfg, root_still=False)),
                plan_robot(robot, [_cube(), _cube()], traj, T_ROBOT_OBJ, grasps=grasps, config=cfg, hand_parts=(0, 1))):  # fmt: skip
        assert off.success and off.info["root_still"] is None, (off.message, off.info.get("root_still"))
        assert fk_error(off, traj).max() < 0.01 and fk_error(off, still)[-1] > 0.03


def test_bimanual_plan_couples_both_arms(robot):
    """Two 3 cm cubes moving in parallel, 36 cm apart: the (left part, right part) pair is planned in
    one 16-DoF solve; the crossed assignment is rejected (it collides) and the straight one wins."""
    tr = _trajectory()
    tr2 = tr.copy()
    tr2[..., 5] += 0.36
    traj = np.concatenate([tr, tr2], 1)
    # the pair comes from the hands (left hand on part 1, right on part 0), bimanual="auto"
    cfg = PlanConfig(num_keyframes=4, approach_steps=4, chunk_size=8, max_iterations=40, approach_candidates=4,
                     top_k_per_arm=2)  # fmt: skip
    assert cfg.bimanual == "auto"
    grasps = {0: _grasps(8, 0, 0.03), 1: _grasps(8, 0, 0.03)}
    plan = plan_robot(robot, [_cube(0.015), _cube(0.015)], traj, T_ROBOT_OBJ, grasps=grasps, config=cfg, hand_parts=(1, 0))
    assert plan.success, plan.info
    assert plan.info["bimanual"]["bimanual"] is True and "parts 1 (left) and 0 (right)" in plan.info["bimanual"]["reason"]
    assert plan.part.tolist() == [0, 1] and plan.active.all()
    assert np.all(plan.position_error < 0.01) and np.all(plan.rotation_error < np.deg2rad(10))
    assert plan.min_distance[0] >= 0  # no arm-arm collision
    gap = np.abs(plan.q_approach[-2] - plan.q_approach[-1]).max()
    assert gap < 0.3  # approach stays on the trajectory's null-space branch
    # both hands on one part: single-arm
    one = plan_robot(robot, [_cube(0.015), _cube(0.015)], traj, T_ROBOT_OBJ, grasps=grasps, config=cfg, hand_parts=(1, 1))
    assert one.info["bimanual"]["bimanual"] is False and "single-arm" in one.info["bimanual"]["reason"]
    assert one.active.sum() <= 1
    with pytest.raises(ValueError, match="hand_parts"):
        plan_robot(robot, [_cube(0.015), _cube(0.015)], traj, T_ROBOT_OBJ, grasps=grasps, config=cfg, hand_parts=(0, 2))


def test_single_arm_fallback_takes_the_part_that_moved_most(robot, monkeypatch):
    """A bimanual demo whose pair plan fails falls back to one arm on the part that moved most
    relative to its parent, though both hands' fingertips rank the other part first (a hand held
    it still; the tracked demo drifts it by 15 mm, above `min_motion_fraction`): usb_plug's
    single-arm fallbacks held its brick and left the plug in it."""
    from rsrd_jax.plan import _search

    mover = _trajectory()  # part 1: slides 6 cm, lifts 3 cm, turns 20°
    still = np.repeat(mover[:1], len(mover), 0)
    still[:, 0, 5] += 0.12  # part 0, 12 cm to the side, drifting 15 mm
    still[:, 0, 4] += np.linspace(0.0, 0.015, len(mover))
    traj = np.concatenate([still, mover], 1)
    # both hands' fingertips on part 0 all along: the hand ranking puts it first
    tips = np.repeat(np.repeat(still[:, :, None, 4:], 2, 1), 2, 2) + np.array([0.0, 0.0, 0.025])
    cfg = PlanConfig(num_keyframes=4, approach_steps=4, chunk_size=8, max_iterations=40, approach_candidates=4,
                     top_k_per_arm=2, max_parts=1)  # fmt: skip
    original = _search._plan_robot

    def pair_fails(*a):  # the pair's plan cannot meet its tolerance: "unreachable"
        c = a[6]
        return original(*a[:6], dataclasses.replace(c, position_tolerance=1e-9) if c.bimanual else c, *a[7:])

    monkeypatch.setattr(_search, "_plan_robot", pair_fails)
    grasps = {0: _grasps(8, 0, 0.03), 1: _grasps(8, 0, 0.03)}
    args = (robot, [_cube(0.015), _cube(0.015)], traj, T_ROBOT_OBJ)
    plan = plan_robot(*args, hands=tips, grasps=grasps, config=cfg, hand_parts=(0, 1))
    d = plan.info["bimanual"]
    assert d["bimanual"] is True and d["fallback"] == "single-arm" and d["bimanual_result"] == "unreachable", d
    assert d["fallback_parts"] == [1, 0]
    assert plan.success and sorted(plan.part.tolist()) == [-1, 1], plan.info
    # the hand ranking alone (no pair decided) takes part 0 in the object frame; with the root
    # held still (`root_still`, no hand known to hold it) it did not move, so part 1
    single = dataclasses.replace(cfg, bimanual=False)
    alone = plan_robot(*args, hands=tips, grasps=grasps, config=single)
    assert sorted(alone.part.tolist()) == [-1, 0]
    still = plan_robot(*args, hands=tips, grasps=grasps, config=dataclasses.replace(single, root_still=True))
    assert still.info["still_parts"] == [0] and sorted(still.part.tolist()) == [-1, 1]


@pytest.mark.slow
def test_cli_plan_from_model_and_trajectory_files(tmp_path):
    """`rsrd-jax plan MODEL TRAJ --object-pose ...` on a one-part cube model and a written
    trajectory: grasps are sampled on the model's Gaussians (their ±1σ extents), the plan tracks
    T_robot_obj · T_obj_part · T_part_grasp at every keyframe, --rerun writes plan.rrd, and
    --no-topdown-grasps is recorded in plan.json's config (the default keeps the top-down set)."""
    from rsrd_jax.cli import main
    from rsrd_jax.features import fit_pca
    from rsrd_jax.io import PartTrajectory, save_trajectory
    from rsrd_jax.parts import FeatureDecoder, ObjectModel, save_object_model
    from rsrd_jax.splat import Gaussians

    rng = np.random.default_rng(0)
    centre = np.array([0.0, 0.0, 0.12])
    pts = _cube(0.02, 12) + centre
    n = len(pts)
    g = Gaussians.create(pts, np.tile([1.0, 0, 0, 0], (n, 1)), np.full((n, 3), np.log(0.002)), np.zeros(n),
                         rng.uniform(size=(n, 3)), rng.normal(size=(n, 4)), np.zeros(n, int))  # fmt: skip
    model = ObjectModel(
        gaussians=g, decoder=FeatureDecoder.create(4, 3, 8, 2, jax.random.key(0)),
        pca=fit_pca(rng.normal(size=(50, 6)).astype(np.float32), dim=3),
        part_centroids=jnp.asarray(centre[None], jnp.float32), arap_pairs=jnp.zeros((0, 2), jnp.int32),
        feature_backend={"name": "none"}, part_names=("cube",), meta={},
    )  # fmt: skip
    save_object_model(model, tmp_path / "model")
    traj = _trajectory()
    T = len(traj)
    save_trajectory(PartTrajectory(
        T_obj_part=traj, T_cam_obj=np.tile([1.0, 0, 0, 0, 0, 0, 0.5], (T, 1)), T_cam_world_part=traj.copy(),
        residual=np.zeros((T, 1)), visible=np.ones((T, 1)), loss=np.zeros(T), meta={},
    ), tmp_path / "traj")  # fmt: skip
    out = tmp_path / "plan"
    rc = main(["plan", str(tmp_path / "model"), str(tmp_path / "traj"), "--object-pose", *map(str, T_ROBOT_OBJ),
               "--out", str(out), "--keyframes", "4", "--chunk", "8", "--max-iterations", "40", "--hands", "none",
               "--grasps", "2", "--approach-steps", "4", "--rerun", "--extent-meshes", "--grasp-keyframe-weight", "3",
               "--no-topdown-grasps"])  # fmt: skip
    plan = load_plan(out)
    assert rc == 0 and plan.success, plan.info
    assert plan.info["config"]["topdown_grasp_config"] is None
    assert plan_config_from_dict(plan.info["config"]).topdown_grasp_config is None
    assert plan_config_from_dict({}).topdown_grasp_config is not None
    k = int(plan.part[plan.active][0])
    assert k == 0
    a = int(np.nonzero(plan.active)[0][0])
    T_tgt = jaxlie.SE3(jnp.asarray(T_ROBOT_OBJ, jnp.float32)) @ jaxlie.SE3(jnp.asarray(traj[plan.keyframe_indices, 0], jnp.float32)) \
        @ jaxlie.SE3(jnp.asarray(plan.T_part_grasp[a], jnp.float32))  # fmt: skip
    tcp = jaxlie.SE3(tcp_poses(load_yumi(), jnp.asarray(plan.q_keyframes, jnp.float32))[:, a])
    assert float(jnp.linalg.norm(tcp.translation() - T_tgt.translation(), axis=-1).max()) < 0.01
    # the grasp holds the cube: its centre lies within the jaw (≤ 2 cm + 5 mm shift from the TCP)
    assert np.linalg.norm(plan.T_part_grasp[a, 4:]) < 0.03
    rrd = out / "plan.rrd"
    assert rrd.is_file() and rrd.stat().st_size > 10_000
    # an inconsistent trajectory (2 parts for a 1-part model) is refused with a message
    save_trajectory(PartTrajectory(
        T_obj_part=np.concatenate([traj, traj], 1), T_cam_obj=np.tile([1.0, 0, 0, 0, 0, 0, 0.5], (T, 1)),
        T_cam_world_part=np.concatenate([traj, traj], 1), residual=np.zeros((T, 2)), visible=np.ones((T, 2)),
        loss=np.zeros(T), meta={},
    ), tmp_path / "traj2")  # fmt: skip
    assert main(["plan", str(tmp_path / "model"), str(tmp_path / "traj2"), "--object-pose", *map(str, T_ROBOT_OBJ),
                 "--out", str(tmp_path / "plan2")]) == 2  # fmt: skip
    # free parts: every part of a trajectory tracked as separable; a part index out of range is refused
    from rsrd_jax.io import load_trajectory
    from rsrd_jax.pipeline import free_parts

    assert free_parts(load_trajectory(tmp_path / "traj")) is None and plan.info["free_parts"] == []
    sep = dataclasses.replace(load_trajectory(tmp_path / "traj2"), meta={"separable": True})
    assert free_parts(sep) == [0, 1]
    assert main(["plan", str(tmp_path / "model"), str(tmp_path / "traj"), "--object-pose", *map(str, T_ROBOT_OBJ),
                 "--out", str(tmp_path / "plan3"), "--free-parts", "1"]) == 2  # fmt: skip
    assert not (tmp_path / "plan3" / "plan.npz").exists()


def test_cli_plan_scan_surface_needs_a_scan_with_depth(tmp_path, capsys):
    """`rsrd-jax plan ... --scan-surface SCAN` with a scan that has no depth maps is an error
    naming the scan's transforms.json and the depth it lacks, exit code 2, before any planning
    and without writing the plan."""
    import cv2

    from rsrd_jax.cli import main
    from rsrd_jax.features import fit_pca
    from rsrd_jax.io import PartTrajectory, save_trajectory
    from rsrd_jax.parts import FeatureDecoder, ObjectModel, save_object_model
    from rsrd_jax.splat import Gaussians

    rng = np.random.default_rng(0)
    pts = _cube(0.02, 4)
    n = len(pts)
    g = Gaussians.create(pts, np.tile([1.0, 0, 0, 0], (n, 1)), np.full((n, 3), np.log(0.002)), np.zeros(n),
                         rng.uniform(size=(n, 3)), rng.normal(size=(n, 4)), np.zeros(n, int))  # fmt: skip
    save_object_model(ObjectModel(
        gaussians=g, decoder=FeatureDecoder.create(4, 3, 8, 2, jax.random.key(0)),
        pca=fit_pca(rng.normal(size=(50, 6)).astype(np.float32), dim=3),
        part_centroids=jnp.zeros((1, 3), jnp.float32), arap_pairs=jnp.zeros((0, 2), jnp.int32),
        feature_backend={"name": "none"}, part_names=("cube",), meta={},
    ), tmp_path / "model")  # fmt: skip
    traj = _trajectory()
    save_trajectory(PartTrajectory(
        T_obj_part=traj, T_cam_obj=np.tile([1.0, 0, 0, 0, 0, 0, 0.5], (len(traj), 1)), T_cam_world_part=traj.copy(),
        residual=np.zeros((len(traj), 1)), visible=np.ones((len(traj), 1)), loss=np.zeros(len(traj)), meta={},
    ), tmp_path / "traj")  # fmt: skip
    scan = tmp_path / "scan"
    scan.mkdir()
    cv2.imwrite(str(scan / "0.png"), np.zeros((8, 8, 3), np.uint8))
    (scan / "transforms.json").write_text(json.dumps({"fl_x": 8, "fl_y": 8, "w": 8, "h": 8, "frames": [
        {"file_path": "0.png", "transform_matrix": np.eye(4).tolist()}]}))  # fmt: skip
    rc = main(["plan", str(tmp_path / "model"), str(tmp_path / "traj"), "--object-pose", *map(str, T_ROBOT_OBJ),
               "--scan-surface", str(scan), "--out", str(tmp_path / "plan")])  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 2 and "transforms.json" in err and "depth" in err, err
    assert not (tmp_path / "plan").exists()


def test_part_sdf_matches_analytic_box_distance():
    """The grid distance of a box known only by surface samples equals the analytic box SDF
    (minus the ball radius) near the surface, is negative inside, and needs no mesh; points far
    outside the grid are farther than the grid margin."""
    from rsrd_jax.plan import part_sdf, sdf_distance

    rng = np.random.default_rng(1)
    half = np.array([0.05, 0.03, 0.02])
    x = rng.uniform(-1, 1, (4000, 3)) * half
    ax = rng.integers(0, 3, len(x))
    x[np.arange(len(x)), ax] = np.sign(rng.standard_normal(len(x))) * half[ax]
    shift = np.array([0.01, -0.02, 0.03])
    sdf = part_sdf([x + shift, x[:500] * 0.5], spacing=0.004, margin=0.03)
    q = rng.uniform(-0.1, 0.1, (3000, 3))
    d = np.asarray(sdf_distance(sdf, jnp.zeros(len(q), jnp.int32), jnp.asarray(q + shift, jnp.float32)))
    e = np.abs(q) - half
    ref = np.linalg.norm(np.maximum(e, 0), axis=1) + np.minimum(e.max(1), 0) - float(sdf.radius[0])
    near = np.abs(ref) < 0.015
    err = np.abs(d - ref)[near]
    assert np.median(err) < 0.001 and err.max() < 0.006  # max: holes of the random surface sampling
    assert np.all(d[ref < -0.004] < 0)  # interior found by the flood fill
    assert np.all(d[ref > 0.004] > 0)
    far = np.asarray(sdf_distance(sdf, jnp.zeros(2, jnp.int32), jnp.asarray([[0.5, 0, 0], [0, 0, -0.4]], jnp.float32)))
    assert np.all(far > 0.3)
    # batched over several leading axes and parts (part 1 is the half-size box, unshifted)
    d2 = sdf_distance(sdf, jnp.ones((2, 3), jnp.int32), jnp.zeros((2, 3, 3)))
    assert d2.shape == (2, 3) and bool(jnp.all(d2 < -0.005))


def test_robot_proxy_pads_cover_finger_pads(robot):
    """The pad capsules of the object check cover each finger's pad box (sampled points of the
    box lie inside a capsule, up to the rounded corners) and stay inside the finger's old
    query capsule except towards the jaw, where it over-covered."""
    from rsrd_jax.plan import robot_proxy

    proxy = robot_proxy(robot)
    kind = np.asarray(proxy.kind)
    assert (kind == 2).sum() == 16 and (kind == 1).sum() == 2
    m = robot.mj_model
    gi = m.geom("pad_r_finger_r").id
    c, half = np.asarray(m.geom_pos[gi]), np.asarray(m.geom_size[gi])
    rng = np.random.default_rng(0)
    pts = c + rng.uniform(-1, 1, (2000, 3)) * half * np.array([1.0, 1.0, 0.85])  # away from the rounded ends
    sel = [i for i, n in enumerate(proxy.names) if n.startswith("pad_r_finger_r")]
    a, b, r = (np.asarray(v)[sel] for v in (proxy.p0, proxy.p1, proxy.radius))
    t = np.clip(np.einsum("nij,ij->ni", pts[:, None] - a[None], b - a) / np.sum((b - a) ** 2, 1), 0, 1)
    dist = np.linalg.norm(pts[:, None] - (a[None] + t[..., None] * (b - a)[None]), axis=-1) - r[None]
    assert np.all(dist.min(1) <= 1e-6)


def _flat_bar(T=6):
    """A 60 × 12 × 6 mm bar lying on the table (centroid 3 mm up), sliding 3 cm along x; top-down
    grasps across its 12 mm width, the pads' width along the bar."""
    g = np.stack(np.meshgrid(np.linspace(-0.03, 0.03, 31), np.linspace(-0.006, 0.006, 7),
                             np.linspace(-0.003, 0.003, 4)), -1).reshape(-1, 3)
    half = np.array([0.03, 0.006, 0.003])
    pts = g[np.any(np.abs(np.abs(g) - half) < 1e-9, axis=1)]
    traj = np.asarray([jaxlie.SE3.from_translation(jnp.asarray([0.03 * s, 0.0, 0.003])).wxyz_xyz
                       for s in np.linspace(0, 1, T)])[:, None]
    rolls = np.array([np.pi / 2, 3 * np.pi / 2])
    down = jaxlie.SO3.from_x_radians(np.pi)
    Tg = np.stack([jaxlie.SE3.from_rotation(down @ jaxlie.SO3.from_z_radians(float(r))).wxyz_xyz for r in rolls])
    n = len(rolls)
    grasps = PartGrasps(
        T_part_grasp=jnp.asarray(Tg, jnp.float32), width=jnp.full((n,), 0.012), score=jnp.ones(n),
        valid=jnp.ones(n, bool), base_index=jnp.arange(n), contacts=jnp.zeros((n, 2, 3)), base_valid=jnp.ones(n, bool),
        result=GraspResult.success, num_hit=jnp.array(n), num_width_ok=jnp.array(n), num_antipodal=jnp.array(n),
    )  # fmt: skip
    return pts, traj, grasps


def _right_pads_to_box(robot, half, T_robot_box):
    """MuJoCo's own box–box distance (m) between the right gripper's pads (posed by the robot
    model at ``q``, fingers at ``grip`` if given) and a box of half-sizes ``half`` at pose
    ``T_robot_box`` (7,), in a two-geom model: returns ``clearance(q, grip=None)``."""
    import mujoco

    m, d = robot.mj_model, mujoco.MjData(robot.mj_model)
    pads = [m.geom(n).id for n in ("pad_r_finger_r", "pad_r_finger_l")]
    size = " ".join(map(str, m.geom_size[pads[0]]))
    pair = mujoco.MjModel.from_xml_string(f"""<mujoco><worldbody>
        <body mocap="true"><geom name="pad" type="box" size="{size}"/></body>
        <body mocap="true"><geom name="box" type="box" size="{' '.join(map(str, half))}"/></body>
        </worldbody></mujoco>""")
    pd = mujoco.MjData(pair)
    pd.mocap_pos[1], pd.mocap_quat[1] = np.asarray(T_robot_box[4:]), np.asarray(T_robot_box[:4])

    def clearance(q, grip=None):
        q = np.array(q, float)
        if grip is not None:
            q[14] = grip
        d.qpos[:] = robot.qpos(q)
        mujoco.mj_forward(m, d)
        out = np.inf
        for p in pads:
            pd.mocap_pos[0] = d.geom_xpos[p]
            mujoco.mju_mat2Quat(pd.mocap_quat[0], d.geom_xmat[p])
            mujoco.mj_forward(pair, pd)
            out = min(out, mujoco.mj_geomDistance(pair, pd, 0, 1, 0.05, None))
        return out

    return clearance


def test_fingertip_grasp_of_a_flat_part_uses_the_pad_table_allowance(robot):
    """The pads end 20 mm past the TCP, so a grasp centred 3 mm above the table can only be seated
    with the pad tips closer to the table than a 3 mm margin: rejected when the pads keep the
    margin, planned with ``pad_table_margin`` 1 mm. MuJoCo's own distance confirms the pads keep
    ≥ 1 mm (and use the allowance); with nothing beside the bar the approach opens the jaw fully."""

    import mujoco

    pts, traj, grasps = _flat_bar()
    cfg = dataclasses.replace(CFG, collision_margin=0.003, pad_table_margin=None)
    strict = plan_robot(robot, [pts], traj, T_ROBOT_OBJ, grasps={0: grasps}, config=cfg)
    assert strict.result == PlanResult.collision
    assert strict.info["rejections"]["grasp_collision"] == 2
    plan = plan_robot(robot, [pts], traj, T_ROBOT_OBJ, grasps={0: grasps},
                      config=dataclasses.replace(cfg, pad_table_margin=0.001))
    assert plan.success, (plan.message, plan.info)
    assert plan.info["chosen"]["grasp_depth"][0] == pytest.approx(0.019)
    np.testing.assert_allclose(plan.q_approach[:, 14], robot.upper[14], atol=1e-6)
    assert plan.info["attempts"][0]["approach_clearance"] is None
    m = robot.mj_model
    d = mujoco.MjData(m)
    table = m.geom("table").id
    pads = [m.geom(n).id for n in ("pad_r_finger_r", "pad_r_finger_l")]
    dist = []
    for q in np.concatenate([plan.q_keyframes, plan.q_approach[-1:]]):
        d.qpos[:] = robot.qpos(q)
        mujoco.mj_forward(m, d)
        dist.append(min(mujoco.mj_geomDistance(m, d, p, table, 0.05, None) for p in pads))
    assert 0.001 - 2e-4 <= min(dist) < 0.003


def test_a_blade_lying_flat_is_held_from_above_by_a_topdown_grasp(robot):
    """A 50 × 14 × 6 mm blade lying on the table, known only by a sheet of points at its mid-plane
    (as the Gaussian centres of a thin part): the mesh sampler's grasps pinch across the sheet
    with a side approach into the table and none seats; with the top-down sampling (the default)
    the plan holds it from above across its 14 mm width (tier 2, ``topdown_grasp``). MuJoCo's own
    distances: at the grasp keyframe both pads are clear of the blade (a box) with the jaw
    5 mm wider than the planned width and within 0.5 mm of it at the planned width, and no pad
    is below the table."""
    import mujoco

    u, v = np.meshgrid(np.linspace(-0.025, 0.025, 51), np.linspace(-0.007, 0.007, 15))
    pts = np.stack([u.ravel(), v.ravel(), np.zeros(u.size)], -1)
    traj = np.asarray([jaxlie.SE3.from_translation(jnp.asarray([0.03 * s, 0.0, 0.003])).wxyz_xyz
                       for s in np.linspace(0, 1, 6)])[:, None]
    cfg = dataclasses.replace(CFG, collision_margin=0.003, grasp_config=GraspConfig(num_grasps=8),
                              spread_grasp_config=GraspConfig(num_grasps=8, min_separation=0.012), hand_grasp_config=None,
                              topdown_grasp_config=TopDownConfig(num_grasps=8), max_candidates=64)  # fmt: skip
    without = plan_robot(robot, [pts], traj, T_ROBOT_OBJ, config=dataclasses.replace(cfg, topdown_grasp_config=None))
    assert not without.success
    plan = plan_robot(robot, [pts], traj, T_ROBOT_OBJ, config=cfg)
    assert plan.success, (plan.message, plan.info["rejections"])
    assert plan.info["chosen"]["topdown_grasp"] and not plan.info["chosen"]["spread_grasp"]
    assert plan.grasp_width[0] == pytest.approx(0.014, abs=0.002)
    T_robot_blade = np.asarray((jaxlie.SE3(jnp.asarray(T_ROBOT_OBJ)) @ jaxlie.SE3(jnp.asarray(traj[0, 0]))).wxyz_xyz)
    clearance = _right_pads_to_box(robot, (0.025, 0.007, 0.003), T_robot_blade)
    q0 = plan.q_keyframes[0]
    w = float(plan.grasp_width[0]) / 2
    assert clearance(q0, w + 0.005) > 0.002
    assert abs(clearance(q0, w)) < 0.0005 + 0.001  # the pads close on the blade's sides
    m, d = robot.mj_model, mujoco.MjData(robot.mj_model)
    d.qpos[:] = robot.qpos(q0)
    mujoco.mj_forward(m, d)
    table = m.geom("table").id
    assert min(mujoco.mj_geomDistance(m, d, m.geom(n).id, table, 0.05, None) for n in ("pad_r_finger_r", "pad_r_finger_l")) > 0


def test_approach_opens_the_jaw_as_wide_as_the_neighbouring_part_allows(robot):
    """A still bar lies beside the grasped flat bar (its near face 22 mm from the grasp centre):
    the fully open pads (25 mm from the centre) would land on it, and so would pads opened 8 mm
    beyond the grasp, so the approach takes the last opening of ``approach_clearance`` (2 mm). MuJoCo's own pad–neighbour distance along the
    approach: below the margin with the jaw fully open, above it with the chosen opening."""
    pts, traj, grasps = _flat_bar()
    T = traj.shape[0]
    beside = np.asarray(jaxlie.SE3.from_translation(jnp.asarray([0.0, 0.028, 0.003])).wxyz_xyz)
    traj2 = np.concatenate([traj, np.repeat(beside[None, None], T, 0)], 1)
    cfg = dataclasses.replace(CFG, collision_margin=0.003, pad_table_margin=0.001, approach_clearance=(None, 0.008, 0.002))
    plan = plan_robot(robot, [pts, pts], traj2, T_ROBOT_OBJ, grasps={0: grasps}, config=cfg)
    assert plan.success, (plan.message, plan.info)
    assert plan.info["attempts"][0]["approach_clearance"] == 0.002
    np.testing.assert_allclose(plan.q_approach[:, 14], 0.006 + 0.002, atol=1e-6)
    # MuJoCo's box–box distance between each right pad (posed by the robot model) and the neighbour
    T_robot_beside = np.asarray((jaxlie.SE3(jnp.asarray(T_ROBOT_OBJ)) @ jaxlie.SE3(jnp.asarray(beside))).wxyz_xyz)
    clearance = _right_pads_to_box(robot, (0.03, 0.006, 0.003), T_robot_beside)
    for grip in (robot.upper[14], 0.006 + 0.008):
        assert min(clearance(q, grip) for q in plan.q_approach[-2:]) < cfg.collision_margin
    assert min(clearance(q, plan.q_approach[0, 14]) for q in plan.q_approach) >= cfg.collision_margin
    with pytest.raises(ValueError, match="approach_clearance"):
        plan_robot(robot, [pts, pts], traj2, T_ROBOT_OBJ, grasps={0: grasps}, config=dataclasses.replace(cfg, approach_clearance=()))


@pytest.mark.slow
@pytest.mark.parametrize("name", ["red_box", "nerf_gun", "scissors", "sunglasses", "bear", "stapler", "led_light",
                                  "wire_cutter", "usb_plug", "toy_drawer", "frog"])
def test_every_studio_demo_plans_on_ground_truth(robot, tmp_path, name):
    """The studio catalogue's design rule, checked with the planner's default settings: the
    demonstrated motion of every object (its ground-truth part trajectory and table pose) has a
    feasible plan, which tracks every keyframe within the tolerances and is collision-free."""
    from rsrd_jax.plan import studio_plan_inputs
    from rsrd_jax.studio import StudioConfig, make_object

    root = tmp_path / name
    make_object(name, root, StudioConfig(scan_views=4, scan_size=(64, 48), demo_frames=30, demo_size=(96, 72),
                                         robot_size=(64, 36), robot_object_yaw_deg=0.0))  # fmt: skip
    inp = studio_plan_inputs(root)
    cfg = PlanConfig()
    plan = plan_robot(robot, inp.part_points, inp.T_obj_part, inp.T_robot_obj, hands=inp.hands, config=cfg)
    assert plan.success, plan.message
    act = np.asarray(plan.active)
    assert np.all(plan.position_error[act] <= cfg.position_tolerance)
    assert np.all(plan.rotation_error[act] <= np.deg2rad(cfg.rotation_tolerance_deg))
    assert np.all(plan.min_distance >= cfg.collision_margin)


def test_spread_grasps_come_after_the_best_scored_ones():
    """Surviving candidates are ordered by cost within a tier; rows of a part's spread grasp set
    (from ``spread_row[part]`` on) come after every best-scored row, whatever their cost."""
    from rsrd_jax.plan._search import _Batch, _combine

    n = 6
    b = _Batch(q=np.zeros((n, 3, 16)), cost=np.array([5.0, 1.0, 3.0, 0.5, 2.0, 4.0]), lm_result=np.zeros(n, int),
               iterations=np.zeros(n, int), pos=np.zeros((n, 2)), rot=np.zeros((n, 2)), viol=np.zeros(n),
               mins=np.zeros((n, 3)), pos0=np.zeros(n), rot0=np.zeros(n))  # fmt: skip
    alive = np.array([True, True, False, True, True, True])
    per_arm = [(0, 1, b, alive, np.zeros((n, 3, 2, 7)), None)]
    args = (None, None, None, None, PlanConfig(), False, 0.025, {}, {})
    tiered = _combine(per_arm, *args, {1: (3,)})
    assert [c["arms"][0][2] for c in tiered] == [1, 0, 3, 4, 5]
    assert [c["tier"] for c in tiered] == [0, 0, 1, 1, 1]
    three = _combine(per_arm, *args, {1: (3, 4)})  # rows from 4 on: the top-down set, after the spread one
    assert [c["arms"][0][2] for c in three] == [1, 0, 3, 4, 5]
    assert [c["tier"] for c in three] == [0, 0, 1, 2, 2]
    by_cost = _combine(per_arm, *args, {})  # no spread set (grasps given): cost order
    assert [c["arms"][0][2] for c in by_cost] == [3, 1, 4, 5, 0] and all(c["tier"] == 0 for c in by_cost)


def test_auto_bimanual_needs_both_hands_on_distinct_parts_one_moved():
    """``bimanual="auto"``: both hands touch distinct parts (contact distance within
    ``bimanual_contact``) and one of them moved → bimanual; otherwise single-arm, with the reason."""
    from rsrd_jax.hands import rank_parts
    from rsrd_jax.plan._search import _two_hands

    rng = np.random.default_rng(0)
    box = lambda size, c, n: np.asarray(c) + rng.uniform(-0.5, 0.5, (n, 3)) * np.asarray(size)  # noqa: E731
    parts = [box((0.3, 0.1, 0.02), (0, 0, 0), 600), box((0.03, 0.03, 0.05), (-0.12, 0, 0.04), 150),
             box((0.03, 0.03, 0.05), (0.12, 0, 0.04), 150)]  # fmt: skip
    nT = 12
    poses = np.zeros((nT, 3, 7), np.float32)
    poses[..., 0] = 1.0
    poses[:, 2, 6] = np.linspace(0.0, 0.05, nT)  # handle b (part 2) is lifted 5 cm
    tips = np.full((nT, 2, 2, 3), np.nan, np.float32)
    for t in range(nT):  # left hand pinches handle b as it moves, right hand holds handle a
        tips[t, 0] = [[0.12, 0.016, 0.05 + poses[t, 2, 6]], [0.12, -0.016, 0.05 + poses[t, 2, 6]]]
        tips[t, 1] = [[-0.12, 0.016, 0.05], [-0.12, -0.016, 0.05]]

    def decide(tp, T=poses):
        rk = rank_parts(parts, T, tp)
        m = np.asarray(rk.relative_motion)
        return _two_hands(rk, m >= 0.2 * max(m.max(), 1e-12), 0.012)

    ok, why = decide(tips)
    assert ok and "bimanual" in why and "part 2" in why and "part 1" in why
    away = tips.copy()
    away[:, 1, :, 1] += 0.05  # right hand 5 cm off handle a
    ok, why = decide(away)
    assert not ok and "not both within 12 mm" in why
    same = tips.copy()
    same[:, 1] = same[:, 0]  # both hands on handle b
    ok, why = decide(same)
    assert not ok and "both hands on one part" in why
    still = poses.copy()
    still[:, 2, 6] = 0.0
    tips_still = tips.copy()
    tips_still[:, 0, :, 2] = 0.05
    assert not decide(tips_still, still)[0] and "neither part moved" in decide(tips_still, still)[1]
    assert not decide(tips[:, :1])[0]  # one hand


def _plate_with_post():
    """Surface points of one part: an 80 × 80 × 8 mm plate lying on the table with a 12 × 12 ×
    30 mm post standing on it 30 mm off centre (object frame: table top z = 0); the part frame
    is its rest centroid. The plate is too wide to pinch across and cannot be pinched across its
    thickness from the table, so only the post can be held."""
    def box(lo, hi, step=0.002):
        axes = [np.arange(a, b + 1e-9, step) for a, b in zip(lo, hi)]
        g = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        on = np.any(np.isclose(g, lo, atol=1e-9) | np.isclose(g, hi, atol=1e-9), axis=1)
        return g[on]

    plate = box((-0.04, -0.04, 0.0), (0.04, 0.04, 0.008))
    post = box((0.024, -0.006, 0.008), (0.036, 0.006, 0.038))
    post = post[post[:, 2] > 0.0085]  # the post's foot is inside the plate's top
    pts = np.concatenate([plate, post])
    pts += np.random.default_rng(0).normal(0.0, 2e-4, pts.shape)  # (an exact grid is degenerate for the alpha shape)
    c = pts.mean(0)
    s = np.linspace(0, 1, 6)
    traj = np.asarray([jaxlie.SE3.from_translation(jnp.asarray(c + [0.03 * v, 0.0, 0.03 * v])).wxyz_xyz for v in s])[:, None]
    return pts - c, traj, np.array([0.03, 0.0, 0.023]) - c


def test_grasps_near_the_hand_hold_the_part_where_the_demonstrator_did(robot):
    """The centre-scored grasps of a plate with a post cluster on the plate, where none seats
    (the table is under it); with the point the demonstrator's hand held (the post) the planner
    also samples grasps there, and the plan holds the post: its grasp centre lies on the post
    (checked in the part frame against the post's box) and plan.json says it is a hand grasp."""
    pts, traj, hand = _plate_with_post()
    cfg = dataclasses.replace(CFG, grasp_config=GraspConfig(num_grasps=4), spread_grasp_config=None,
                              hand_grasp_config=GraspConfig(num_grasps=4), max_candidates=16)  # fmt: skip
    T_robot_obj = np.array([1.0, 0, 0, 0, 0.45, -0.15, 0.0])
    without = plan_robot(robot, [pts], traj, T_robot_obj, config=cfg)
    assert not without.success and without.info["rejections"]["grasp_collision"] > 0
    plan = plan_robot(robot, [pts], traj, T_robot_obj, config=cfg, hand_points=[(0, hand)])
    assert plan.success, (plan.message, plan.info["rejections"])
    assert plan.info["chosen"]["hand_grasp"] == [True, False]
    assert plan.info["chosen"]["tier"] == 1  # used because no best-scored grasp (tier 0) survived
    ranked = plan_robot(robot, [pts], traj, T_robot_obj, config=dataclasses.replace(cfg, hand_grasp_tier=False),
                        hand_points=[(0, hand)])  # ranked with the best-scored ones: the same plan, in tier 0
    assert ranked.info["chosen"]["tier"] == 0 and ranked.grasp_index.tolist() == plan.grasp_index.tolist()
    assert plan.info["hand_points_mm"] == [[0, [round(1e3 * float(v), 2) for v in hand]]]
    # the chosen grasp (backed off by its seating depth along its approach axis) pinches the post
    depth = plan.info["chosen"]["grasp_depth"][0]
    g = jaxlie.SE3(jnp.asarray(plan.T_part_grasp[0], jnp.float32)) @ jaxlie.SE3.from_translation(jnp.asarray([0.0, 0.0, depth]))
    c_obj = np.asarray(g.translation()) + traj[0, 0, 4:]  # at rest (no rotation): object frame
    assert 0.024 - 0.006 <= c_obj[0] <= 0.036 + 0.006 and abs(c_obj[1]) <= 0.012 and c_obj[2] > 0.008
    with pytest.raises(ValueError, match="hand_points"):
        plan_robot(robot, [pts], traj, T_robot_obj, config=cfg, hand_points=[(1, hand)])


def test_bimanual_pairs_take_one_candidate_per_base_grasp_first():
    """``bimanual_per_base``: the rows combined into bimanual pairs come from distinct base grasps
    first, in cost order, and only then further rolls of the same ones."""
    from rsrd_jax.plan._search import _top_per_base

    base = np.array([0, 0, 0, 1, 1, 2, 3, 3])
    ids = np.array([1, 0, 3, 2, 4, 6, 5, 7])  # cost order
    assert _top_per_base(ids, base, 4, 1).tolist() == [1, 3, 6, 5]
    assert _top_per_base(ids, base, 6, 1).tolist() == [1, 3, 6, 5, 0, 2]
    assert _top_per_base(ids, base, 5, 2).tolist() == [1, 0, 3, 4, 6]
    assert _top_per_base(ids, base, 20, 1000).tolist() == ids.tolist()


def _rolling(T=12, deg=-15.0):
    """`_trajectory`'s slide and lift while the part turns ``deg`` about its own x axis (a plug
    pulled out and rolled, studio usb_plug)."""
    out = []
    for si in np.linspace(0, 1, T):
        R = jaxlie.SO3.from_x_radians(np.deg2rad(deg) * si)
        out.append(jaxlie.SE3.from_rotation_and_translation(R, jnp.asarray([0.06 * si, 0.0, 0.12 + 0.03 * si])).wxyz_xyz)
    return np.asarray(out)[:, None]


def test_grasp_twist_is_the_turn_about_the_closing_axis():
    """`_part_turns` / `_grasp_twist` against scipy: a part turning by up to 30° about a random
    axis, random grasp frames: the largest |rotation vector · closing axis| over the poses."""
    from rsrd_jax.plan._search import _grasp_twist, _part_turns

    rng = np.random.default_rng(3)
    u = rng.normal(size=3)
    u /= np.linalg.norm(u)
    R0 = Rotation.random(random_state=4)
    angles = np.deg2rad([0.0, 10.0, 30.0, 20.0])
    Rs = [R0 * Rotation.from_rotvec(a * u) for a in angles]  # turns in the part's own frame
    poses = np.stack([np.r_[np.roll(R.as_quat(), 1), rng.normal(size=3)] for R in Rs])
    turns = _part_turns(poses)
    np.testing.assert_allclose(turns, angles[:, None] * u, atol=1e-5)
    G = Rotation.random(5, random_state=5)
    Tg = np.concatenate([np.roll(G.as_quat(), 1, axis=1), rng.normal(size=(5, 3))], 1)
    want = np.deg2rad(30.0) * np.abs(G.as_matrix()[:, :, 0] @ u)
    np.testing.assert_allclose(_grasp_twist(turns, Tg), want, atol=1e-5)


def test_short_lever_grasps_are_those_near_the_hinge():
    """`_short_lever` against the known hinge: a bar (rest pose a random rotation and offset)
    turning up to 30° about an axis nearly across it near its end; grasps (random frames, bar
    frame) are flagged exactly when their distance from that line (numpy) is under 0.4 × the
    bar's farthest point's; a part that turns 5° flags none."""
    from rsrd_jax.plan._search import _short_lever

    rng = np.random.default_rng(11)
    R0 = Rotation.random(random_state=12)
    x0 = rng.normal(scale=0.1, size=3)
    u = R0.apply([0.1, 0.3, 1.0])  # nearly across the bar, through a point near its end
    u /= np.linalg.norm(u)
    c = R0.apply([-0.045, 0.004, 0.0]) + x0 + 0.2 * u
    pts = np.c_[np.linspace(-0.05, 0.05, 41), np.zeros((41, 2))]  # the bar, its own frame

    def poses(deg):
        out = []
        for a in np.deg2rad(deg):
            Rh = Rotation.from_rotvec(a * u)
            R, t = Rh * R0, Rh.apply(x0 - c) + c
            out.append(np.r_[np.roll(R.as_quat(), 1), t])
        return np.stack(out)

    G = Rotation.random(40, random_state=13)
    gx = np.c_[rng.uniform(-0.06, 0.06, 40), rng.normal(scale=0.01, size=(40, 2))]
    Tg = np.concatenate([np.roll(G.as_quat(), 1, axis=1), gx], 1)
    dist = lambda x: np.linalg.norm(np.cross(R0.apply(x) + x0 - c, u), axis=-1)  # noqa: E731
    want = dist(gx) < 0.4 * dist(pts).max()
    assert 5 < want.sum() < 35
    got = _short_lever(poses([0.0, 10.0, 30.0, 20.0]), Tg, pts, 0.4, np.deg2rad(10.0))
    np.testing.assert_array_equal(got, want)
    assert not _short_lever(poses([0.0, 3.0, 5.0]), Tg, pts, 0.4, np.deg2rad(10.0)).any()


def test_grasps_that_must_twist_a_free_part_rank_after_the_others(robot):
    """A free part (no joint holds it) turning 15° about its x axis: among top-down pinches rolled
    about the approach axis (closing axes at 0, 22.5, ..., 157.5° from x), the plan takes one
    that turns the part by at most `free_twist_deg` (10°) about its own axis; with only twisting
    grasps it still plans, and says so. (Turning the other way, every candidate here collides.)"""
    from rsrd_jax.plan._search import _grasp_twist, _part_turns

    traj = _rolling()
    g = _grasps(8, 0)
    cfg = dataclasses.replace(CFG, max_candidates=8)
    twist = np.rad2deg(_grasp_twist(_part_turns(traj[:, 0]), np.asarray(g.T_part_grasp)))
    np.testing.assert_allclose(twist, 15.0 * np.abs(np.cos(np.linspace(0, np.pi, 8, endpoint=False))), atol=1e-3)
    plan = plan_robot(robot, [_cube()], traj, T_ROBOT_OBJ, grasps={0: g}, config=cfg, free_parts=[0])
    assert plan.success, (plan.message, plan.info)
    assert plan.grasp_index[0] in (3, 4, 5) and twist[plan.grasp_index[0]] <= 10.0
    assert plan.info["chosen"]["twisting_grasp"] is False and plan.info["free_parts"] == [0]
    # the closing axis of the chosen grasp, by the grasp's own frame (scipy): nearly across x
    ax = Rotation.from_quat(np.roll(plan.T_part_grasp[0, :4], -1)).as_matrix()[:, 0]
    assert abs(ax[0]) <= np.cos(np.deg2rad(48.0))  # 10° of 15° about x: 48° or more from x
    only = eqx_rows(g, [0, 1, 7])  # closing axes 0, 22.5 and 157.5 deg from x: all twist > 10 deg
    plan2 = plan_robot(robot, [_cube()], traj, T_ROBOT_OBJ, grasps={0: only}, config=cfg, free_parts=[0])
    assert plan2.success and plan2.info["chosen"]["twisting_grasp"] is True
    with pytest.raises(ValueError, match="free_parts"):
        plan_robot(robot, [_cube()], traj, T_ROBOT_OBJ, grasps={0: g}, config=cfg, free_parts=[1])


def test_grasps_near_a_turning_parts_hinge_rank_after_the_others(robot):
    """A bar turning 30° about a vertical axis through one end (a lid, a scissors blade): of
    pinches across it near the hinge (lever 0.12 of the bar's farthest point) and at the free
    end (0.88), the plan takes the cheapest near the hinge without the rule
    (`short_lever_fraction` None) and one at the free end with it, reporting no short lever;
    with only the pinches near the hinge it still plans, and says so; declared free, the part is
    exempt."""
    from rsrd_jax.plan._search import _short_lever

    g = np.linspace(-0.06, 0.06, 25)
    bar = np.stack(np.meshgrid(g, [-0.01, 0.01], [-0.01, 0.01]), -1).reshape(-1, 3)
    hinge = np.array([0.06, 0.0, 0.12])
    traj = []
    for a in np.deg2rad(np.linspace(0.0, 30.0, 12)):
        R = jaxlie.SO3.from_z_radians(float(a))
        traj.append(jaxlie.SE3.from_rotation_and_translation(R, jnp.asarray(hinge) + R @ jnp.asarray(-hinge + [0, 0, 0.12])).wxyz_xyz)
    traj = np.asarray(traj)[:, None]
    T = np.asarray(_grasps(4, 0, width=0.02).T_part_grasp)
    Tg = np.concatenate([np.concatenate([T[:, :4], T[:, 4:] + [x, 0.0, 0.0]], 1) for x in (-0.045, 0.045)])
    both = PartGrasps(
        T_part_grasp=jnp.asarray(Tg, jnp.float32), width=jnp.full((8,), 0.02), score=jnp.ones(8), valid=jnp.ones(8, bool),
        base_index=jnp.arange(8), contacts=jnp.zeros((8, 2, 3)), base_valid=jnp.ones(8, bool), result=GraspResult.success,
        num_hit=jnp.array(8), num_width_ok=jnp.array(8), num_antipodal=jnp.array(8),
    )  # fmt: skip
    assert _short_lever(traj[:, 0], Tg, bar, 0.4, np.deg2rad(10.0)).tolist() == [False] * 4 + [True] * 4
    cfg = dataclasses.replace(CFG, max_candidates=8)
    off = plan_robot(robot, [bar], traj, T_ROBOT_OBJ, grasps={0: both}, config=dataclasses.replace(cfg, short_lever_fraction=None))
    assert off.success and off.grasp_index[0] >= 4, (off.message, off.grasp_index)
    plan = plan_robot(robot, [bar], traj, T_ROBOT_OBJ, grasps={0: both}, config=cfg)
    assert plan.success, (plan.message, plan.info)
    assert plan.grasp_index[0] < 4 and plan.info["chosen"]["short_lever_grasp"] is False
    assert plan.info["chosen"]["cost"] > off.info["chosen"]["cost"]
    near = eqx_rows(both, [4, 5, 6, 7])
    plan2 = plan_robot(robot, [bar], traj, T_ROBOT_OBJ, grasps={0: near}, config=cfg)
    assert plan2.success and plan2.info["chosen"]["short_lever_grasp"] is True
    # a free part (no hinge sets its path) is exempt: the cheaper pinch near the "hinge" again
    free = plan_robot(robot, [bar], traj, T_ROBOT_OBJ, grasps={0: both}, config=cfg, free_parts=[0])
    assert free.success and free.grasp_index[0] == off.grasp_index[0] and free.info["chosen"]["short_lever_grasp"] is False


def eqx_rows(g: PartGrasps, rows) -> PartGrasps:
    """The grasps of ``rows`` (base grasps renumbered)."""
    r = np.asarray(rows)
    return PartGrasps(
        T_part_grasp=g.T_part_grasp[r], width=g.width[r], score=g.score[r], valid=g.valid[r],
        base_index=jnp.arange(len(r)), contacts=g.contacts[r], base_valid=g.base_valid[r], result=g.result,
        num_hit=g.num_hit, num_width_ok=g.num_width_ok, num_antipodal=g.num_antipodal,
    )  # fmt: skip


def test_twisting_grasps_come_last_within_their_tier():
    """`_combine` orders survivors by (tier, twist, cost): a grasp that must twist a free part
    comes after the others of its tier, never before a better tier."""
    from rsrd_jax.plan._search import _Batch, _combine

    n = 6
    b = _Batch(q=np.zeros((n, 3, 16)), cost=np.array([5.0, 1.0, 3.0, 0.5, 2.0, 4.0]), lm_result=np.zeros(n, int),
               iterations=np.zeros(n, int), pos=np.zeros((n, 2)), rot=np.zeros((n, 2)), viol=np.zeros(n),
               mins=np.zeros((n, 3)), pos0=np.zeros(n), rot0=np.zeros(n))  # fmt: skip
    alive = np.ones(n, bool)
    per_arm = [(0, 1, b, alive, np.zeros((n, 3, 2, 7)), None)]
    args = (None, None, None, None, PlanConfig(), False, 0.025, {}, {})
    twisty = lambda k, i: np.isin(np.asarray(i), [1, 3])  # noqa: E731
    out = _combine(per_arm, *args, {1: (4,)}, twisty)
    assert [c["arms"][0][2] for c in out] == [2, 0, 3, 1, 4, 5]
    assert [c["twist"] for c in out] == [False, False, True, True, False, False]
    assert [c["tier"] for c in out] == [0, 0, 0, 0, 1, 1]
    plain = _combine(per_arm, *args, {1: (4,)})
    assert [c["arms"][0][2] for c in plain] == [3, 1, 2, 0, 4, 5] and not any(c["twist"] for c in plain)


def test_a_free_parts_pinches_are_sampled_within_the_free_cone(robot, monkeypatch):
    """The antipodal samplings of a free part take `free_cone_deg` (15°) as their friction cone
    (the smaller of it and their own); a part not declared free keeps 45°. With rays tilted off
    the normals (Dex-Net's jitter), the free cube's grasp axes lie within 15° of a face normal
    and closer to them than the other's."""
    import rsrd_jax.plan._search as S

    class Stop(Exception):
        pass

    seen = []

    def record(mesh, key, config, **kw):
        g = sample(mesh, key, config, **kw)
        seen.append((float(config.friction_angle_deg), g))
        return g

    def stop(*a, **kw):
        raise Stop  # the top-down set comes after every antipodal one: enough

    sample = S.sample_antipodal_grasps
    monkeypatch.setattr(S, "sample_antipodal_grasps", record)
    monkeypatch.setattr(S, "sample_topdown_grasps", stop)
    jit = GraspConfig(num_grasps=16, axis_jitter=0.5)  # rays tilted up to 26.6° off the normal
    cfg = dataclasses.replace(CFG, grasp_config=jit, spread_grasp_config=jit, hand_grasp_config=None)
    for free in ([0], None):
        with pytest.raises(Stop):
            plan_robot(robot, [_cube(n=12)], _rolling(), T_ROBOT_OBJ, config=cfg, free_parts=free)
    assert [c for c, _ in seen] == [15.0, 15.0, 45.0, 45.0]  # (best-scored, spread) free, then not
    off = []
    for _, g in seen:
        R = Rotation.from_quat(np.roll(np.asarray(g.T_part_grasp)[np.asarray(g.valid)][:, :4], -1, axis=1)).as_matrix()
        off.append(np.rad2deg(np.arccos(np.clip(np.abs(R[:, :, 0]).max(axis=1), -1, 1))).max())  # from a face normal
    # (the same seed and config otherwise: without the narrower cone both would be the same set)
    assert max(off[:2]) <= 15.0 + 0.5 and max(off[2:]) > max(off[:2]) + 2.0, off


def test_a_motion_ending_where_no_gripper_fits_ends_within_the_slack(robot):
    """A cube slides and lifts (``_trajectory``) until it sits under a still plate 1 cm above its
    top: over the last frame every top-down grasp meets the plate (sunglasses' folded arm, 7 mm
    behind the frame). The whole demo has no plan; with the end slack the motion ends at frame 9
    of 11, the earliest frame within the slack's half (frame 10) still colliding. Checked: the
    slack against the trajectory computed by hand, the robot's TCP on the held pose (FK)."""
    g = np.stack(np.meshgrid(np.linspace(0.07, 0.17, 26), np.linspace(-0.06, 0.06, 25)), -1).reshape(-1, 2)
    plate = np.concatenate([g, np.full((len(g), 1), 0.175)], 1)  # the cube's top ends at 0.165
    c = plate.mean(0)
    traj = _trajectory()
    still = np.repeat(np.asarray([[1.0, 0, 0, 0, *c]]), len(traj), 0)[:, None]
    T = np.concatenate([still, traj], 1)
    args = (robot, [plate - c, _cube(0.015)], T, T_ROBOT_OBJ)
    cfg = dataclasses.replace(CFG, parts=(1,))
    grasps = {1: _grasps(8, 0, 0.03)}
    whole = plan_robot(*args, grasps=grasps, config=dataclasses.replace(cfg, end_slack_deg=None))
    assert whole.result == PlanResult.collision and "end_slack" not in whole.info
    plan = plan_robot(*args, grasps=grasps, config=cfg)
    assert plan.success, plan.message
    es = plan.info["end_slack"]
    assert es["frame"] == 9 and es["whole_demo"] == "collision"
    assert [(a["frame"], a["result"]) for a in es["attempts"]] == [(10, "collision"), (9, "success")]
    # frame 9 of 0..11: 2/11 of the 20° turn and of the (6, 0, 3) cm move before the end
    assert es["attempts"][1]["rotation_deg"] == pytest.approx(20 * 2 / 11, abs=0.01)
    assert es["attempts"][1]["position_mm"] == pytest.approx(1000 * np.hypot(0.06, 0.03) * 2 / 11, abs=0.01)
    assert "ends at frame 9 of 11" in plan.message
    # the robot holds the part at frame 9's pose from there on
    assert plan.keyframe_indices[-1] == 11
    T_tgt = (jaxlie.SE3(jnp.asarray(T_ROBOT_OBJ, jnp.float32)) @ jaxlie.SE3(jnp.asarray(traj[9, 0], jnp.float32))
             @ jaxlie.SE3(jnp.asarray(plan.T_part_grasp[0], jnp.float32)))  # fmt: skip
    tcp = tcp_poses(robot, jnp.asarray(plan.q_video[9:], jnp.float32))[:, 0]
    err = np.linalg.norm(np.asarray(tcp[:, 4:] - T_tgt.translation()), axis=-1)
    assert err.max() < CFG.position_tolerance
    # no slack big enough: the original failure, with the attempts
    tight = plan_robot(*args, grasps=grasps, config=dataclasses.replace(cfg, end_slack_deg=1.0))
    assert tight.result == PlanResult.collision and tight.info["end_slack"]["frame"] is None


def test_end_frame_is_the_earliest_frame_after_which_all_stay_within_the_slack():
    """:func:`end_frame` against a brute-force reading of its rule on random deviations, and
    :func:`end_deviation` against numpy on a turning, sliding part beside a still one."""
    from rsrd_jax.plan._search import end_deviation, end_frame

    rng = np.random.default_rng(0)
    for _ in range(200):
        n = int(rng.integers(1, 12))
        rot, pos = rng.uniform(0, 0.3, n), rng.uniform(0, 0.03, n)
        rot[-1] = pos[-1] = 0.0
        mr, mp = rng.uniform(0, 0.3), rng.uniform(0, 0.03)
        brute = min(f for f in range(n) if all(rot[t] <= mr and pos[t] <= mp for t in range(f, n)))
        assert end_frame(rot, pos, mr, mp) == brute
    traj = _trajectory()
    still = np.repeat(traj[:1], len(traj), 0)
    rot, pos = end_deviation(np.concatenate([still, traj], 1))
    s = 1 - np.linspace(0, 1, len(traj))
    np.testing.assert_allclose(rot, np.deg2rad(20) * s, atol=1e-5)
    np.testing.assert_allclose(pos, np.hypot(0.06, 0.03) * s, atol=1e-6)


@pytest.mark.parametrize("lever", ["-0.1", "1", "nan"])
def test_cli_plan_refuses_a_short_lever_outside_0_1(tmp_path, capsys, lever):
    from rsrd_jax.cli import main

    rc = main(["plan", "--studio-gt", str(tmp_path / "nope"), "--out", str(tmp_path / "plan"), "--short-lever", lever])
    err = capsys.readouterr().err
    assert rc == 2 and "--short-lever" in err, err
    assert not (tmp_path / "plan").exists()
    with pytest.raises(ValueError, match="short_lever"):
        plan_robot(load_yumi(), [_cube()], _trajectory(), T_ROBOT_OBJ, config=PlanConfig(short_lever_fraction=float(lever)))


@pytest.mark.parametrize("flag", [[], ["--root-still"]])
def test_cli_plan_and_pipeline_pass_root_still_to_the_planner(tmp_path, monkeypatch, flag):
    """`rsrd-jax plan --root-still` and `PipelineConfig.plan_root_still` reach `PlanConfig.root_still`
    (off without them); the planner is stubbed after it receives its config."""
    import types

    import rsrd_jax.plan as plan_mod
    from rsrd_jax.cli import main
    from rsrd_jax.pipeline import PipelineConfig, _plan_config

    seen = []
    inputs = types.SimpleNamespace(part_points=[_cube(), _cube()], T_obj_part=np.concatenate([_trajectory()] * 2, 1),
                                   hands=None, T_robot_obj=T_ROBOT_OBJ, free_parts=())  # fmt: skip
    monkeypatch.setattr(plan_mod, "studio_plan_inputs", lambda path: inputs)

    class Planned(Exception):
        pass

    def stub(*a, config, **kw):
        seen.append(config)
        raise Planned

    monkeypatch.setattr(plan_mod, "plan_robot", stub)
    with pytest.raises(Planned):
        main(["plan", "--studio-gt", str(tmp_path), "--out", str(tmp_path / "plan"), *flag])
    assert len(seen) == 1 and seen[0].root_still is bool(flag)
    assert _plan_config(PipelineConfig(plan_root_still=bool(flag))).root_still is bool(flag)


@pytest.mark.parametrize("slack", [["-1", "15"], ["10", "nan"]])
def test_cli_plan_refuses_a_negative_or_nan_end_slack(tmp_path, capsys, slack):
    from rsrd_jax.cli import main

    rc = main(["plan", "--studio-gt", str(tmp_path / "nope"), "--out", str(tmp_path / "plan"), "--end-slack", *slack])
    err = capsys.readouterr().err
    assert rc == 2 and "--end-slack" in err, err
    assert not (tmp_path / "plan").exists()
    with pytest.raises(ValueError, match="end_slack"):
        plan_robot(load_yumi(), [_cube()], _trajectory(), T_ROBOT_OBJ, config=PlanConfig(end_slack_deg=float(slack[0]),
                                                                                        end_slack_m=float(slack[1]) / 1000))
