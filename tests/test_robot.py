"""YuMi model: FK vs MuJoCo C and vs the JSON URDF chain, home pose, collision distances vs
MuJoCo C mj_geomDistance, MJX penetration (thin slab), jacobians, vmap, bad inputs, servo tracking."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import jaxlie
import mujoco
import numpy as np
import pytest

from rsrd_jax import robot


@pytest.fixture(scope="module")
def yumi() -> robot.YumiModel:
    return robot.load_yumi()


def _random_q(rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.uniform(robot.JOINT_LOWER, robot.JOINT_UPPER, size=(n, 16)).astype(np.float32)


def _mj_state(yumi: robot.YumiModel, q: np.ndarray) -> tuple[mujoco.MjModel, mujoco.MjData]:
    m = yumi.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = yumi.qpos(q)
    mujoco.mj_kinematics(m, d)
    return m, d


# ----------------------------------------------------------------------------------------------
# Forward kinematics


def test_fk_matches_mujoco_c(yumi, rng):
    qs = _random_q(rng, 6)
    res = robot.forward_kinematics(yumi, jnp.asarray(qs))
    pos, rot = np.asarray(res.T_world_link.translation()), np.asarray(res.T_world_link.rotation().as_matrix())
    tpos, trot = np.asarray(res.T_world_tcp.translation()), np.asarray(res.T_world_tcp.rotation().as_matrix())
    for k, q in enumerate(qs):
        m, d = _mj_state(yumi, q.astype(float))
        for i, name in enumerate(robot.LINK_NAMES):
            np.testing.assert_allclose(pos[k, i], d.body(name).xpos, atol=2e-6)
            np.testing.assert_allclose(rot[k, i], d.body(name).xmat.reshape(3, 3), atol=2e-6)
        for i, s in enumerate(robot.TCP_SITES):
            np.testing.assert_allclose(tpos[k, i], d.site(s).xpos, atol=2e-6)
            np.testing.assert_allclose(trot[k, i], d.site(s).xmat.reshape(3, 3), atol=2e-6)


def _urdf_fk(facts: dict, q16: np.ndarray) -> dict[str, np.ndarray]:
    """Independent numpy FK of the JSON's URDF joints: T_child = T_parent Trans(xyz) Rpy Rot(axis q)."""

    def rpy(r, p, y):
        cx, sx, cy, sy, cz, sz = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
        Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
        Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
        Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
        return Rz @ Ry @ Rx

    def axis_angle(a, t):
        a = np.asarray(a, float)
        K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
        return np.eye(3) + np.sin(t) * K + (1 - np.cos(t)) * K @ K

    order = facts["actuated_joint_order_yourdfpy"]
    val = {n: float(v) for n, v in zip(order, q16)}
    T = {"world": np.eye(4)}
    pending = list(facts["joints"])
    while pending:
        for j in list(pending):
            if j["parent"] not in T:
                continue
            local = np.eye(4)
            local[:3, :3] = rpy(*j["origin_rpy"])
            local[:3, 3] = j["origin_xyz"]
            motion = np.eye(4)
            qv = val.get(j.get("mimic", {}).get("joint", j["name"]), 0.0)
            if j["type"] == "revolute":
                motion[:3, :3] = axis_angle(j["axis"], qv)
            elif j["type"] == "prismatic":
                motion[:3, 3] = np.asarray(j["axis"], float) * qv
            T[j["child"]] = T[j["parent"]] @ local @ motion
            pending.remove(j)
    return T


def test_fk_matches_json_urdf_chain(yumi, rng):
    facts = json.loads((robot.MODEL_DIR / "yumi_kinematics.json").read_text())
    qs = _random_q(rng, 6)
    res = robot.forward_kinematics(yumi, jnp.asarray(qs))
    Tl = np.asarray(res.T_world_link.as_matrix())
    Tt = np.asarray(res.T_world_tcp.as_matrix())
    for k, q in enumerate(qs):
        ref = _urdf_fk(facts, q.astype(float))
        for i, name in enumerate(robot.LINK_NAMES):
            np.testing.assert_allclose(Tl[k, i], ref[name], atol=2e-5, err_msg=name)
        np.testing.assert_allclose(Tt[k, 0], ref["right_dummy_point"], atol=2e-5)
        np.testing.assert_allclose(Tt[k, 1], ref["left_dummy_point"], atol=2e-5)


def test_home_pose_matches_json(yumi):
    facts = json.loads((robot.MODEL_DIR / "yumi_kinematics.json").read_text())
    res = robot.forward_kinematics(yumi, yumi.home)
    tcp = np.asarray(res.T_world_tcp.translation())
    np.testing.assert_allclose(tcp, robot.HOME_TCP_POSITIONS, atol=1e-4)
    # Both TCP z axes point straight down.
    z = np.asarray(res.T_world_tcp.rotation().as_matrix())[:, :, 2]
    np.testing.assert_allclose(z, [[0, 0, -1], [0, 0, -1]], atol=1e-4)
    rec = facts["home_pose"]["fk_at_home_computed"]
    pos = np.asarray(res.T_world_link.translation())
    for i, name in enumerate(robot.LINK_NAMES):
        np.testing.assert_allclose(pos[i], rec[name]["pos"], atol=1e-4, err_msg=name)
    # The MJCF keyframe is the same home pose, and qpos order is JOINT_NAMES through qpos_adr.
    m = yumi.mj_model
    key = m.key("home").id
    np.testing.assert_allclose(m.key_qpos[key][list(yumi.qpos_adr)], robot.HOME_Q, atol=1e-8)


def test_fk_jacobian_finite_differences(yumi, rng):
    q0 = jnp.asarray(_random_q(rng, 1)[0])

    def tcp_pos(q):
        return robot.forward_kinematics(yumi, q).T_world_tcp.translation().reshape(-1)

    J_fwd = np.asarray(jax.jacfwd(tcp_pos)(q0))
    J_rev = np.asarray(jax.jacrev(tcp_pos)(q0))
    assert np.all(np.isfinite(J_fwd))
    np.testing.assert_allclose(J_fwd, J_rev, atol=1e-5)
    eps = 1e-3
    J_fd = np.stack([(np.asarray(tcp_pos(q0.at[i].add(eps))) - np.asarray(tcp_pos(q0.at[i].add(-eps))))
                     / (2 * eps) for i in range(16)], axis=1)
    np.testing.assert_allclose(J_fwd, J_fd, atol=2e-3)
    # Right TCP depends on right-arm joints only (and not on the fingers).
    assert np.abs(J_fwd[:3, 7:]).max() == 0.0 and np.abs(J_fwd[3:, :7]).max() == 0.0
    # Geometric check against MuJoCo's site jacobian.
    m, d = _mj_state(yumi, np.asarray(q0, float))
    mujoco.mj_comPos(m, d)
    jp = np.zeros((3, m.nv))
    mujoco.mj_jacSite(m, d, jp, None, m.site("tcp_r").id)
    np.testing.assert_allclose(J_fwd[:3, :7], jp[:, [m.jnt_dofadr[m.joint(n).id] for n in robot.RIGHT_ARM_JOINTS]], atol=1e-4)


def test_tcp_jacobian_matches_mujoco_site_jacobian(yumi, rng):
    qs = _random_q(rng, 3)
    T, J = robot.tcp_jacobian(yumi, jnp.asarray(qs))
    assert T.shape == (3, 2, 7) and J.shape == (3, 2, 6, 16)
    np.testing.assert_allclose(np.asarray(T), np.asarray(robot.tcp_poses(yumi, jnp.asarray(qs))), atol=1e-6)
    for k, q in enumerate(qs):
        m, d = _mj_state(yumi, q.astype(float))
        mujoco.mj_comPos(m, d)
        for a, (site, names) in enumerate(zip(robot.TCP_SITES, (robot.RIGHT_ARM_JOINTS, robot.LEFT_ARM_JOINTS))):
            jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
            mujoco.mj_jacSite(m, d, jp, jr, m.site(site).id)
            cols = [m.jnt_dofadr[m.joint(n).id] for n in names]
            own = robot.RIGHT_ARM if a == 0 else robot.LEFT_ARM
            np.testing.assert_allclose(np.asarray(J[k, a, :3, own]), jp[:, cols], atol=1e-5)
            np.testing.assert_allclose(np.asarray(J[k, a, 3:, own]), jr[:, cols], atol=1e-5)
            other = np.ones(16, bool)
            other[own] = False
            assert np.abs(np.asarray(J[k, a][:, other])).max() == 0.0  # other arm, fingers


def test_fk_batch_shapes_and_vmap(yumi, rng):
    qs = jnp.asarray(_random_q(rng, 6))
    flat = robot.tcp_poses(yumi, qs)
    assert flat.shape == (6, 2, 7)
    for shape in [(2, 3), (3, 2)]:
        out = robot.tcp_poses(yumi, qs.reshape(*shape, 16))
        assert out.shape == (*shape, 2, 7)
        np.testing.assert_allclose(np.asarray(out).reshape(6, 2, 7), np.asarray(flat), atol=1e-6)
    single = robot.tcp_poses(yumi, qs[0])
    assert single.shape == (2, 7)
    via_vmap = jax.vmap(lambda q: robot.tcp_poses(yumi, q))(qs)
    np.testing.assert_allclose(np.asarray(via_vmap), np.asarray(flat), atol=1e-6)
    links = robot.forward_kinematics(yumi, qs.reshape(2, 3, 16)).T_world_link
    assert links.wxyz_xyz.shape == (2, 3, robot.NUM_LINKS, 7)


def test_bad_inputs(yumi):
    # Under pytest jaxtyping's runtime check (a TypeError) fires first; the host check that users
    # get outside tests is called directly too.
    from rsrd_jax.robot._model import check_q

    with pytest.raises((ValueError, TypeError), match="16"):
        robot.forward_kinematics(yumi, jnp.zeros((3, 14)))
    with pytest.raises((ValueError, TypeError), match="16"):
        robot.collision_distances(yumi, jnp.zeros(7))
    with pytest.raises((ValueError, TypeError), match="(floating|Float)"):
        robot.forward_kinematics(yumi, jnp.zeros(16, jnp.int32))
    with pytest.raises(ValueError, match=r"shape \(\*batch, 16\).*got shape \(3, 14\)"):
        check_q(jnp.zeros((3, 14)))
    with pytest.raises(ValueError, match="floating"):
        check_q(np.zeros(16, np.int64))
    bad = jnp.asarray(robot.HOME_Q, jnp.float32).at[3].set(jnp.nan)
    with pytest.raises(Exception, match="NaN"):
        jax.block_until_ready(robot.forward_kinematics(yumi, bad).T_world_tcp.wxyz_xyz)
    with pytest.raises(Exception, match="NaN"):  # batch of 6: shares the compile of other tests
        jax.block_until_ready(robot.collision_distances(yumi, jnp.tile(bad, (6, 1))).min_self)
    obj = robot.object_boxes_from_points(np.random.default_rng(0).normal(size=(20, 3)) * 0.02,
                                         np.zeros(20, int), 1)
    with pytest.raises(ValueError, match="T_world_part"):
        robot.collision_distances(yumi, yumi.home, obj)
    with pytest.raises((ValueError, TypeError), match="T_world_part"):
        robot.collision_distances(yumi, yumi.home, obj, jnp.zeros((2, 7)))
    with pytest.raises(ValueError, match="MJCF"):
        robot.build_scene_spec("<body name='x'")
    with pytest.raises(ValueError, match="part 1"):
        robot.object_boxes_from_points(np.zeros((4, 3)), np.zeros(4, int), 2)


# ----------------------------------------------------------------------------------------------
# Collision distances


def test_self_and_table_distances_match_mujoco_c(yumi, rng):
    qs = _random_q(rng, 6)
    qs[0] = robot.HOME_Q
    res = robot.collision_distances(yumi, jnp.asarray(qs))
    g = yumi.geom
    cc, cb = np.asarray(g.self_cc), np.asarray(g.self_cb)
    gid = {n: yumi.mj_model.geom(n).id for n in g.cap_names + g.box_names + ("table",)}
    n_pen = 0
    for k, q in enumerate(qs):
        m, d = _mj_state(yumi, q.astype(float))
        pairs = g.self_pair_names()
        got = np.asarray(res.self_distance[k])
        pairs += [(n, "table") for n in g.cap_names]
        got = np.concatenate([got, np.asarray(res.table_distance[k])])
        for (a, b), dist in zip(pairs, got):
            ref = mujoco.mj_geomDistance(m, d, gid[a], gid[b], 10.0, None)
            is_box = "base_link" in b or b == "table"
            if ref > 0 or not is_box:
                assert abs(dist - ref) < 1e-5, (k, a, b, dist, ref)
            else:  # penetration depth conventions differ for boxes: the sign must agree
                n_pen += 1
                assert dist < 0, (k, a, b, dist, ref)
        assert bool(res.in_collision[k]) == bool(
            min(res.min_self[k], res.min_table[k]) < 0)
    assert not bool(res.in_collision[0]), "home pose must be collision-free"
    assert float(res.min_self[0]) > 0.1 and float(res.min_table[0]) > 0.1
    assert res.self_distance.shape == (6, cc.shape[0] + cb.shape[0])


def _object_xml(obj: robot.ObjectGeometry, T_world_part: np.ndarray) -> str:
    geoms = []
    for k in range(obj.box_part.shape[0]):
        T = jaxlie.SE3(T_world_part[int(obj.box_part[k])]) @ jaxlie.SE3(obj.box_wxyz_xyz[k])
        w = np.asarray(T.wxyz_xyz, float)
        geoms.append(f'<geom name="ob{k}" type="box" size="{" ".join(map(str, np.asarray(obj.box_half[k])))}" '
                     f'quat="{" ".join(map(str, w[:4]))}" pos="{" ".join(map(str, w[4:]))}"/>')
    for k in range(obj.cap_part.shape[0]):
        T = jaxlie.SE3(T_world_part[int(obj.cap_part[k])])
        a, b = np.asarray(T @ obj.cap_p0[k], float), np.asarray(T @ obj.cap_p1[k], float)
        geoms.append(f'<geom name="oc{k}" type="capsule" size="{float(obj.cap_radius[k])}" '
                     f'fromto="{" ".join(map(str, np.concatenate([a, b])))}"/>')
    return '<body name="o">' + "".join(geoms) + "</body>"


@pytest.fixture(scope="module")
def two_part_object():
    """Points of a two-part object, its primitives (one box and one capsule per part) and part
    poses near the right gripper at home."""
    rng = np.random.default_rng(3)
    pts = np.concatenate([rng.normal(size=(60, 3)) * [0.04, 0.01, 0.015],
                          rng.normal(size=(60, 3)) * [0.01, 0.03, 0.01] + [0.0, 0.0, 0.03]])
    ids = np.repeat([0, 1], 60)
    boxes = robot.object_boxes_from_points(pts, ids, 2)
    caps = robot.object_capsules_from_points(pts, ids, 2)
    obj = robot.ObjectGeometry(
        box_part=boxes.box_part, box_wxyz_xyz=boxes.box_wxyz_xyz, box_half=boxes.box_half,
        cap_part=caps.cap_part, cap_p0=caps.cap_p0, cap_p1=caps.cap_p1, cap_radius=caps.cap_radius,
        num_parts=2)
    T_world_part = np.stack([
        np.asarray(jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.from_z_radians(0.3), jnp.array([0.48, -0.18, 0.09])).wxyz_xyz),
        np.asarray(jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.from_x_radians(0.5), jnp.array([0.45, -0.25, 0.06])).wxyz_xyz),
    ]).astype(np.float32)
    return pts, ids, obj, T_world_part


def test_object_distances_match_mujoco_c(yumi, rng, two_part_object):
    pts, ids, obj, T_world_part = two_part_object
    # Boxes and capsules cover their part's points.
    for k in range(2):
        T = jaxlie.SE3(obj.box_wxyz_xyz[k])
        local = np.asarray(T.inverse() @ jnp.asarray(pts[ids == k], jnp.float32))
        assert np.all(np.abs(local) <= np.asarray(obj.box_half[k]) + 1e-5)
        dd = jax.vmap(lambda x: robot.capsule_capsule(x, x, jnp.zeros(()), obj.cap_p0[k], obj.cap_p1[k],
                                                      obj.cap_radius[k]))(jnp.asarray(pts[ids == k], jnp.float32))
        assert float(dd.max()) <= 1e-5
    qs = _random_q(rng, 6) * 0.15 + robot.HOME_Q.astype(np.float32) * 0.85
    spec = robot.build_scene_spec(_object_xml(obj, T_world_part), pos=(0, 0, 0))
    m = spec.compile()
    d = mujoco.MjData(m)
    res = robot.collision_distances(yumi, jnp.asarray(qs), obj, jnp.asarray(T_world_part))
    assert res.object_distance.shape == (6, len(yumi.geom.cap_names), 4)  # 2 boxes, then 2 capsules
    names = ["obj/ob0", "obj/ob1", "obj/oc0", "obj/oc1"]
    n_close = 0
    for k, q in enumerate(qs):
        d.qpos[:] = 0
        d.qpos[[m.jnt_qposadr[m.joint(n).id] for n in robot.JOINT_NAMES]] = q
        d.qpos[[m.jnt_qposadr[m.joint(f"{n}_m").id] for n in robot.GRIPPER_JOINTS]] = q[14:]
        mujoco.mj_kinematics(m, d)
        for i, name in enumerate(yumi.geom.cap_names):
            for j, oname in enumerate(names):
                ref = mujoco.mj_geomDistance(m, d, m.geom(name).id, m.geom(oname).id, 10.0, None)
                got = float(res.object_distance[k, i, j])
                n_close += ref < 0.05
                if ref > 0 or j >= 2:
                    assert abs(got - ref) < 1e-5, (k, name, oname, got, ref)
                else:  # box penetration depth conventions differ: the sign must agree
                    assert got < 0
    assert n_close > 0, "the object should come near the hand in some configurations"
    np.testing.assert_allclose(np.asarray(res.min_object), np.asarray(res.object_distance).min(axis=(1, 2)))
    # Hand capsules can be left out of min_object (grasping).
    res_h = robot.collision_distances(yumi, jnp.asarray(qs), obj, jnp.asarray(T_world_part),
                                      hand_touches_object=True)
    arm = ~np.asarray(yumi.geom.hand_mask)
    np.testing.assert_allclose(np.asarray(res_h.min_object), np.asarray(res_h.object_distance)[:, arm].min(axis=(1, 2)))


def test_collision_trajectory_batch_and_gradients(yumi, rng, two_part_object):
    """(trajectories, waypoints) batches with a moving object; gradients match finite differences."""
    _, _, obj, T_world_part = two_part_object
    n_traj, n_wp = 2, 3
    qs = jnp.asarray(_random_q(rng, n_traj * n_wp).reshape(n_traj, n_wp, 16))
    T = np.tile(T_world_part, (n_traj, n_wp, 1, 1))
    T[..., 4] += np.linspace(0, 0.1, n_wp)[None, :, None]
    res = robot.collision_distances(yumi, qs, obj, jnp.asarray(T))
    assert res.min_object.shape == (n_traj, n_wp) and res.in_collision.dtype == jnp.bool_
    assert res.object_distance.shape == (n_traj, n_wp, len(yumi.geom.cap_names), 4)
    # Waypoint (1, 2) equals the same configuration and part poses queried in another batch slot.
    one = robot.collision_distances(yumi, jnp.tile(qs[1, 2], (6, 1)), obj, jnp.asarray(T[1, 2]))
    np.testing.assert_allclose(np.asarray(one.object_distance[0]), np.asarray(res.object_distance[1, 2]), atol=1e-6)
    np.testing.assert_allclose(np.asarray(one.self_distance[3]), np.asarray(res.self_distance[1, 2]), atol=1e-6)
    # A static object broadcast over the batch gives the same as the explicit copy.
    T_static = np.tile(T_world_part, (n_traj, n_wp, 1, 1))
    res_b = robot.collision_distances(yumi, qs, obj, jnp.asarray(T_world_part))
    res_s = robot.collision_distances(yumi, qs, obj, jnp.asarray(T_static))
    np.testing.assert_allclose(np.asarray(res_b.object_distance), np.asarray(res_s.object_distance), atol=1e-6)

    # Gradient of a smooth penalty over all pairs, against central finite differences.
    q0 = jnp.asarray(robot.HOME_Q, jnp.float32) + jnp.asarray(rng.normal(size=16) * 0.2, jnp.float32)
    Tq = jnp.asarray(T_world_part)

    def penalty(q):  # (*b, 16) -> (*b,)
        r = robot.collision_distances(yumi, q, obj, Tq)
        d = jnp.concatenate([r.self_distance, r.table_distance,
                             r.object_distance.reshape(*r.object_distance.shape[:-2], -1)], axis=-1)
        return jnp.sum(jax.nn.softplus(-(d - 0.3) * 20.0), axis=-1)

    g = np.asarray(jax.grad(penalty)(q0))
    assert np.all(np.isfinite(g)) and np.abs(g).max() > 0
    eps = 2e-3
    # Perturbed configurations in batches of 6 (reuses the compiled batch size above).
    pert = np.concatenate([np.asarray(q0) + eps * np.eye(16), np.asarray(q0) - eps * np.eye(16)])
    pert = np.concatenate([pert, np.tile(np.asarray(q0), (4, 1))]).astype(np.float32)
    vals = np.concatenate([np.asarray(penalty(jnp.asarray(c))) for c in pert.reshape(6, 6, 16)])
    fd = (vals[:16] - vals[16:32]) / (2 * eps)
    np.testing.assert_allclose(g, fd, rtol=3e-2, atol=3e-2 * np.abs(fd).max())


def test_thin_slab_mjx_vs_distance():
    """A capsule through a thin slab: our capsule-box distance and MJX both report penetration."""
    from mujoco import mjx

    xml = """<mujoco><worldbody>
      <geom name="slab" type="box" size="0.3 0.3 0.001"/>
      <body name="c" pos="0 0 0"><freejoint/>
        <geom name="cap" type="capsule" fromto="0.02 0 -0.06 -0.02 0 0.06" size="0.01"/></body>
    </worldbody></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    dm = mjx.put_model(m)
    dd = jax.jit(lambda md, dx: mjx.collision(md, mjx.kinematics(md, dx)))(dm, mjx.put_data(m, d))
    mjx_dist = float(np.min(np.asarray(dd._impl.contact.dist)))
    ours = float(robot.capsule_box(jnp.array([0.02, 0, -0.06]), jnp.array([-0.02, 0, 0.06]), jnp.array(0.01),
                                   jnp.eye(3), jnp.zeros(3), jnp.array([0.3, 0.3, 0.001])))
    assert mjx_dist < 0 and ours < -0.01
    # Separated: exact distance (MJX's convex path would report 1.0 here).
    sep = float(robot.capsule_box(jnp.array([0.0, 0, 0.05]), jnp.array([0.0, 0.1, 0.2]), jnp.array(0.01),
                                  jnp.eye(3), jnp.zeros(3), jnp.array([0.3, 0.3, 0.001])))
    assert abs(sep - (0.05 - 0.001 - 0.01)) < 1e-5


@pytest.mark.slow
def test_mjx_penetration_agrees_with_distances(yumi, rng):
    qs = _random_q(rng, 24)
    qs[0] = robot.HOME_Q
    pen = robot.mjx_penetration(yumi, jnp.asarray(qs))
    res = robot.collision_distances(yumi, jnp.asarray(qs))
    assert not bool(pen.penetrating[0])
    # MJX agrees with MuJoCo C contacts (mj_collision) on which configurations penetrate.
    m = yumi.mj_model
    robot_bodies = {m.body(n).id for n in robot.LINK_NAMES}
    c_pen = []
    for q in qs:
        d = mujoco.MjData(m)
        d.qpos[:] = yumi.qpos(q.astype(float))
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        c_pen.append(any(c.dist < 0 and (m.geom_bodyid[c.geom1] in robot_bodies or m.geom_bodyid[c.geom2] in robot_bodies)
                         for c in d.contact[: d.ncon]))
    np.testing.assert_array_equal(np.asarray(pen.penetrating), c_pen)
    assert 0 < sum(c_pen) < len(c_pen)  # both outcomes occur
    clear = np.abs(np.asarray(res.min_table)) > 0.01  # finger pads are boxes inside finger capsules
    np.testing.assert_array_equal(np.asarray(pen.penetrating)[clear], np.asarray(res.table_collision)[clear])
    assert pen.dist.shape[-1] == pen.geom.shape[0] > 0


# ----------------------------------------------------------------------------------------------
# Scene and simulation


def test_scene_with_object_and_servo_tracking(yumi):
    spec = robot.build_scene_spec('<body name="cube"><freejoint/><geom type="box" size="0.02 0.02 0.02"/></body>',
                                  pos=(0.45, 0.0, 0.021))
    m = spec.compile()
    assert m.body("obj/cube").id > 0 and abs(m.geom("table").pos[2] + m.geom("table").size[2] - robot.TABLE_TOP_Z) < 1e-12
    yo = robot.load_yumi(spec)
    assert yo.qpos(robot.HOME_Q).shape == (m.nq,)
    d = mujoco.MjData(m)
    d.qpos[:] = yo.qpos(robot.HOME_Q)
    d.ctrl[:] = robot.HOME_Q
    act = [m.actuator(f"act_{n}").trnid[0] for n in robot.JOINT_NAMES[:14]]
    assert [m.joint(j).name for j in act] == list(robot.JOINT_NAMES[:14])
    # Track a smooth 1 s trajectory (0.3 rad sinusoid on every arm joint) and close the grippers.
    t_end, dt = 1.0, m.opt.timestep
    errs, q0 = [], robot.HOME_Q.copy()
    for step in range(int(t_end / dt)):
        t = step * dt
        target, qdot = q0.copy(), np.zeros(16)
        target[:14] += 0.3 * np.sin(np.pi * t)
        qdot[:14] = 0.3 * np.pi * np.cos(np.pi * t)
        target[14:] = 0.025 * (1 - t / t_end)
        d.ctrl[:] = robot.servo_ctrl(yo, target, qdot)
        mujoco.mj_step(m, d)
        q = d.qpos[list(yo.qpos_adr)]
        if t > 0.2:
            errs.append(np.abs(q[:14] - target[:14]).max())
    assert max(errs) < 0.01, max(errs)
    # Mimic finger follows the driven one.
    np.testing.assert_allclose(d.qpos[list(yo.mimic_qpos_adr)], d.qpos[list(yo.qpos_adr[14:])], atol=1e-3)
    assert np.all(d.qpos[list(yo.qpos_adr[14:])] < 0.006)
    # The cube rests on the table.
    assert abs(d.body("obj/cube").xpos[2] - 0.02) < 2e-3


def _ik_right(m: mujoco.MjModel, d: mujoco.MjData, adr: list[int], target: np.ndarray, q0: np.ndarray) -> np.ndarray:
    """Damped least squares IK of the right TCP to (target, pointing down) with MuJoCo C jacobians."""
    R_target = np.diag([1.0, -1.0, -1.0])
    sid = m.site("tcp_r").id
    dof = [m.jnt_dofadr[m.joint(n).id] for n in robot.RIGHT_ARM_JOINTS]
    q = q0.copy()
    for _ in range(200):
        d.qpos[adr] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        R = d.site_xmat[sid].reshape(3, 3)
        E = R_target @ R.T
        err = np.concatenate([target - d.site_xpos[sid], 0.5 * np.array([E[2, 1] - E[1, 2], E[0, 2] - E[2, 0], E[1, 0] - E[0, 1]])])
        jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
        mujoco.mj_jacSite(m, d, jp, jr, sid)
        J = np.vstack([jp, jr])[:, dof]
        q[:7] = np.clip(q[:7] + J.T @ np.linalg.solve(J @ J.T + 1e-4 * np.eye(6), err), robot.JOINT_LOWER[:7], robot.JOINT_UPPER[:7])
    assert np.linalg.norm(err) < 1e-4
    return q


def test_grasp_and_lift_cube():
    """Pads with friction hold a 4 cm cube: IK down, close the gripper, lift 12 cm."""
    spec = robot.build_scene_spec('<body name="cube"><freejoint/><geom type="box" size="0.02 0.02 0.02" '
                                  'rgba="0.8 0.2 0.2 1"/></body>', pos=(0.5, -0.2, 0.0201))
    yo = robot.load_yumi(spec)
    m = yo.mj_model
    d = mujoco.MjData(m)
    adr = list(yo.qpos_adr)
    q_above = _ik_right(m, d, adr, np.array([0.5, -0.2, 0.12]), robot.HOME_Q.copy())
    q_grasp = _ik_right(m, d, adr, np.array([0.5, -0.2, 0.025]), q_above)
    q_lift = _ik_right(m, d, adr, np.array([0.5, -0.2, 0.145]), q_grasp)
    q_closed = q_grasp.copy()
    q_closed[14] = 0.0
    q_lift[14] = 0.0
    mujoco.mj_resetData(m, d)
    d.qpos[:] = yo.qpos(q_above)
    mujoco.mj_forward(m, d)
    segments = [(q_above, q_above, 0.2), (q_above, q_grasp, 1.0), (q_grasp, q_closed, 0.6), (q_closed, q_lift, 1.0),
                (q_lift, q_lift, 0.4)]
    dt = m.opt.timestep
    for qa, qb, dur in segments:
        steps = int(dur / dt)
        for k in range(steps):
            s = (k + 1) / steps
            w = 3 * s**2 - 2 * s**3  # smooth step
            qdot = (qb - qa) * 6 * s * (1 - s) / dur
            d.ctrl[:] = robot.servo_ctrl(yo, qa + w * (qb - qa), qdot)
            mujoco.mj_step(m, d)
    cube = d.body("obj/cube").xpos
    tcp = d.site("tcp_r").xpos
    assert cube[2] > 0.10, cube  # lifted with the hand
    assert np.linalg.norm(cube - tcp) < 0.02, (cube, tcp)
    # Fingers stopped on the cube faces: jaw = 2 q ~ 4 cm.
    assert abs(2 * d.qpos[adr[14]] - 0.04) < 0.004, d.qpos[adr[14]]
