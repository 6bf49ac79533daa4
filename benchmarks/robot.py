"""YuMi kinematics and collision throughput: JAX (batched, jitted) vs MuJoCo C in a Python loop.

Cases (batch = number of joint configurations):
- ``fk``: link + TCP poses (`forward_kinematics`) vs `mj_kinematics` per configuration.
- ``collision``: all signed distances robot-self (ignore list applied), robot-table and
  robot-object (a 2-box object) with `collision_distances` vs `mj_kinematics` + `mj_geomDistance`
  over the same pair list (the C loop includes Python's per-call overhead, ~1 µs per pair).
- ``mjx_penetration`` (full mode only): MJX kinematics + collision of the scene (contact slots in
  the metrics) vs `mj_kinematics` + `mj_collision`.
``ratio_c_over_jax`` > 1 means JAX is faster than the C loop.
"""

from __future__ import annotations

import statistics
import time

import numpy as np

from benchmarks._util import measure, record


def _c_loop(fn, qs: np.ndarray, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for q in qs:
            fn(q)
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times)


def run(quick: bool) -> list[dict]:
    import jax
    import jax.numpy as jnp
    import jaxlie
    import mujoco

    from rsrd_jax import robot

    yumi = robot.load_yumi()
    m = yumi.mj_model
    d = mujoco.MjData(m)
    rng = np.random.default_rng(0)
    batches = (1, 64) if quick else (1, 64, 1024)
    obj = robot.object_boxes_from_points(
        np.concatenate([rng.normal(size=(100, 3)) * [0.04, 0.01, 0.01],
                        rng.normal(size=(100, 3)) * [0.01, 0.03, 0.01] + [0, 0, 0.03]]),
        np.repeat([0, 1], 100), 2)
    T_parts = jnp.asarray(np.array([[1, 0, 0, 0, 0.45, -0.1, 0.05], [1, 0, 0, 0, 0.45, 0.1, 0.05]],
                                   np.float32))
    # C side of the collision case: the same geoms in one MuJoCo model (object boxes added as geoms).
    geoms = []
    for k in range(2):
        T = jaxlie.SE3(T_parts[k]) @ jaxlie.SE3(obj.box_wxyz_xyz[k])
        w = np.asarray(T.wxyz_xyz, float)
        geoms.append(f'<geom name="b{k}" type="box" size="{" ".join(map(str, np.asarray(obj.box_half[k])))}" '
                     f'quat="{" ".join(map(str, w[:4]))}" pos="{" ".join(map(str, w[4:]))}"/>')
    mo = robot.build_scene_spec('<body name="o">' + "".join(geoms) + "</body>", pos=(0, 0, 0)).compile()
    do = mujoco.MjData(mo)
    g = yumi.geom
    gid = lambda n: mo.geom(n).id  # noqa: E731
    pairs = [(gid(g.cap_names[i]), gid(g.cap_names[j])) for i, j in np.asarray(g.self_cc)]
    pairs += [(gid(g.cap_names[i]), gid(g.box_names[b])) for i, b in np.asarray(g.self_cb)]
    pairs += [(gid(n), gid("table")) for n in g.cap_names]
    pairs += [(gid(n), gid(f"obj/b{k}")) for n in g.cap_names for k in range(2)]
    adr = [mo.jnt_qposadr[mo.joint(n).id] for n in robot.JOINT_NAMES]
    madr = [mo.jnt_qposadr[mo.joint(f"{n}_m").id] for n in robot.GRIPPER_JOINTS]

    def c_fk(q):
        d.qpos[list(yumi.qpos_adr)] = q
        d.qpos[list(yumi.mimic_qpos_adr)] = q[14:]
        mujoco.mj_kinematics(m, d)

    def c_coll(q):
        do.qpos[adr] = q
        do.qpos[madr] = q[14:]
        mujoco.mj_kinematics(mo, do)
        return min(mujoco.mj_geomDistance(mo, do, a, b, 10.0, None) for a, b in pairs)

    def c_mjx(q):
        d.qpos[list(yumi.qpos_adr)] = q
        d.qpos[list(yumi.mimic_qpos_adr)] = q[14:]
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)

    out = []
    for n in batches:
        qs = rng.uniform(robot.JOINT_LOWER, robot.JOINT_UPPER, size=(n, 16)).astype(np.float32)
        qj = jnp.asarray(qs)
        rep = 20 if n < 1024 else 5
        crep = 5 if n < 1024 else 1

        def fk(q):
            return robot.forward_kinematics(yumi, q).T_world_link.wxyz_xyz

        comp, ms = measure(fk, qj, repeat=rep)
        c_ms = _c_loop(c_fk, qs.astype(float), crep)
        out.append(record("robot", {"what": "fk", "batch": n}, ms, comp, {
            "configs_per_s": n / ms * 1e3, "mujoco_c_ms": c_ms, "mujoco_c_configs_per_s": n / c_ms * 1e3,
            "ratio_c_over_jax": c_ms / ms, "links": robot.NUM_LINKS}))

        def coll(q):
            r = robot.collision_distances(yumi, q, obj, T_parts)
            return r.min_self, r.min_table, r.min_object

        comp, ms = measure(coll, qj, repeat=rep)
        c_ms = _c_loop(c_coll, qs.astype(float), crep if n < 1024 else 1) if n <= 1024 else float("nan")
        out.append(record("robot", {"what": "collision", "batch": n}, ms, comp, {
            "configs_per_s": n / ms * 1e3, "mujoco_c_ms": c_ms, "mujoco_c_configs_per_s": n / c_ms * 1e3,
            "ratio_c_over_jax": c_ms / ms, "pairs_total": len(pairs),
            "pairs_self": int(g.self_cc.shape[0] + g.self_cb.shape[0]), "pairs_table": len(g.cap_names),
            "pairs_object": 2 * len(g.cap_names)}))

    if not quick:
        for n in (1, 64):
            qs = rng.uniform(robot.JOINT_LOWER, robot.JOINT_UPPER, size=(n, 16)).astype(np.float32)

            def pen(q):
                return robot.mjx_penetration(yumi, q).penetrating

            comp, ms = measure(pen, jnp.asarray(qs), repeat=10)
            c_ms = _c_loop(c_mjx, qs.astype(float), 5)
            slots = int(robot.mjx_penetration(yumi, jnp.asarray(qs[:1])).dist.shape[-1])
            out.append(record("robot", {"what": "mjx_penetration", "batch": n}, ms, comp, {
                "configs_per_s": n / ms * 1e3, "mujoco_c_ms": c_ms, "ratio_c_over_jax": c_ms / ms,
                "contact_slots": slots}))
    jax.clear_caches()
    return out
