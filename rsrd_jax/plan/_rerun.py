"""Rerun recording of a RobotPlan: the robot's collision capsules following the approach and the
joint trajectory, the object parts posed by the part trajectory, the grasp frames and the TCP
targets (rerun-sdk 0.41, written offline to a ``.rrd`` file)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import jax.numpy as jnp
import jaxlie
import numpy as np

from ..robot import YumiModel, forward_kinematics
from ._proxy import robot_proxy
from ._search import root_still_trajectory

_PART_COLOURS = np.array([[230, 120, 40], [60, 130, 220], [90, 190, 90], [200, 80, 200], [220, 200, 60],
                          [80, 200, 200], [150, 100, 60], [120, 120, 120]], np.uint8)  # fmt: skip


def _xyzw(wxyz: np.ndarray) -> np.ndarray:
    return np.concatenate([wxyz[..., 1:], wxyz[..., :1]], -1)


def _capsule_frames(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rerun capsules run along +z from their translation: quaternions (xyzw) turning z onto b - a."""
    v = b - a
    length = np.linalg.norm(v, axis=-1)
    d = v / np.maximum(length, 1e-9)[:, None]
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, d)
    s = np.linalg.norm(axis, axis=-1)
    c = d @ z
    ang = np.arctan2(s, c)
    axis = np.where(s[:, None] > 1e-9, axis / np.maximum(s, 1e-9)[:, None], np.array([1.0, 0.0, 0.0]))
    quat = np.concatenate([axis * np.sin(ang / 2)[:, None], np.cos(ang / 2)[:, None]], -1)
    return a, quat, length


def log_plan(
    robot: YumiModel,
    plan,
    part_points: Sequence[np.ndarray],
    T_obj_part: np.ndarray,
    rrd_path: str | Path,
    max_points: int = 1500,
) -> Path:
    """Writes a rerun recording of a successful plan.

    Timeline ``step``: the approach segment (parts at their first pose), then every video frame
    (``q_video``, parts at ``T_robot_obj · T_obj_part(t)``). Entities (robot base frame):
    ``world/robot`` capsules (the collision proxy: links, palms, finger pads), ``world/table``,
    ``world/object/part{k}`` points, ``world/object/part{k}/grasp`` the chosen grasp frame (x red =
    finger axis, z blue = approach), ``world/tcp_target/{arm}`` the target and ``world/tcp/{arm}``
    the reached TCP, plus scalars ``tcp_error_mm/{arm}``.

    Args:
        robot: from :func:`rsrd_jax.robot.load_yumi`.
        plan: a successful :class:`RobotPlan` (or a loaded plan artefact with the same fields).
        part_points: P point sets in their part frames (m), as given to the planner.
        T_obj_part: (T, P, 7) part poses per video frame, as given to the planner (held to the
            still root as the planner did when ``plan.info["root_still"]`` is set).
        rrd_path: output file (written via a temporary file, then renamed).
        max_points: points logged per part.

    Returns:
        The path written.

    Raises:
        ValueError: for a plan without a trajectory, or inconsistent shapes.
    """
    import rerun as rr

    qv = np.asarray(plan.q_video, np.float32)
    qa = np.asarray(plan.q_approach, np.float32)
    info = getattr(plan, "info", None) or {}
    if info.get("root_still") and np.ndim(T_obj_part) == 3 and np.shape(T_obj_part)[1:] == (len(part_points), 7):
        T_obj_part = root_still_trajectory(T_obj_part)[0]
    T_obj_part = np.asarray(T_obj_part, np.float32)
    if qv.ndim != 2 or qv.shape[0] == 0:
        raise ValueError("log_plan: the plan has no joint trajectory (failed plan?)")
    if T_obj_part.shape[0] != qv.shape[0] or T_obj_part.shape[1] != len(part_points):
        raise ValueError(f"log_plan: T_obj_part {T_obj_part.shape} does not match q_video {qv.shape} and "
                         f"{len(part_points)} parts")
    rrd_path = Path(rrd_path)
    rrd_path.parent.mkdir(parents=True, exist_ok=True)
    tmp = rrd_path.with_name(f".{rrd_path.name}.tmp")
    rec = rr.RecordingStream("rsrd_jax_plan")
    rec.save(str(tmp))

    proxy = robot_proxy(robot)
    q_all = np.concatenate([qa, qv]) if qa.size else qv
    fk = forward_kinematics(robot, jnp.asarray(q_all), check_finite=False)
    links = jaxlie.SE3(fk.T_world_link.wxyz_xyz[:, np.asarray(proxy.link)])
    A = jaxlie.SE3(links.wxyz_xyz) @ proxy.p0[None]
    B = jaxlie.SE3(links.wxyz_xyz) @ proxy.p1[None]
    A, B = np.asarray(A), np.asarray(B)
    tcp = np.asarray(fk.T_world_tcp.wxyz_xyz)  # (S, 2, 7)
    kind = np.asarray(proxy.kind)
    cap_col = np.array([[150, 150, 160], [60, 60, 70], [20, 20, 20]], np.uint8)[kind]
    radii = np.asarray(proxy.radius)

    g = robot.geom
    rec.log("world/table", rr.Boxes3D(half_sizes=[np.asarray(g.table_half)], centers=[np.asarray(g.table_wxyz_xyz[4:])],
                                      colors=[[200, 180, 150]], fill_mode="solid"), static=True)  # fmt: skip
    Tb = jaxlie.SE3(g.box_wxyz_xyz)
    rec.log("world/robot/body", rr.Boxes3D(half_sizes=np.asarray(g.box_half), centers=np.asarray(Tb.translation()),
                                           quaternions=_xyzw(np.asarray(Tb.rotation().wxyz)),
                                           colors=[[120, 120, 130]]), static=True)  # fmt: skip
    rng = np.random.default_rng(0)
    for k, p in enumerate(part_points):
        p = np.asarray(p, np.float32)
        if len(p) > max_points:
            p = p[rng.choice(len(p), max_points, replace=False)]
        rec.log(f"world/object/part{k}", rr.Points3D(p, colors=_PART_COLOURS[k % len(_PART_COLOURS)], radii=0.0015),
                static=True)  # fmt: skip
    arms = ("right", "left")
    active = np.asarray(plan.active, bool)
    for a in range(2):
        k = int(plan.part[a])
        if not active[a] or k < 0:
            continue
        T = np.asarray(plan.T_part_grasp[a], np.float32)
        R = np.asarray(jaxlie.SO3(jnp.asarray(T[:4])).as_matrix())
        o = T[4:]
        rec.log(f"world/object/part{k}/grasp_{arms[a]}",
                rr.Arrows3D(origins=[o, o, o], vectors=0.03 * R.T, colors=[[255, 0, 0], [0, 255, 0], [0, 0, 255]]),
                static=True)  # fmt: skip
        tgt = np.asarray(plan.tcp_target, np.float32)[:, a, 4:]
        rec.log(f"world/tcp_target_path/{arms[a]}", rr.LineStrips3D([tgt], colors=[[255, 60, 60]], radii=0.001),
                static=True)  # fmt: skip

    T_robot_obj = jaxlie.SE3(jnp.asarray(plan.T_robot_obj, jnp.float32))
    T_rp = np.asarray((T_robot_obj @ jaxlie.SE3(jnp.asarray(T_obj_part))).wxyz_xyz)  # (T, P, 7)
    n_app = len(qa) if qa.size else 0
    key_idx = np.asarray(plan.keyframe_indices)
    tgt_app = np.asarray(plan.tcp_approach_target, np.float32)
    tgt_key = np.asarray(plan.tcp_target, np.float32)
    for s in range(len(q_all)):
        rec.set_time("step", sequence=s)
        t = max(s - n_app, 0)
        for k in range(len(part_points)):
            T = T_rp[t, k]
            rec.log(f"world/object/part{k}", rr.Transform3D(translation=T[4:], quaternion=_xyzw(T[:4])))
        tr, quat, length = _capsule_frames(A[s], B[s])
        rec.log("world/robot/capsules", rr.Capsules3D(lengths=length, radii=radii, translations=tr, quaternions=quat,
                                                      colors=cap_col))  # fmt: skip
        # targets exist at approach waypoints and keyframes only
        if s < n_app:
            tg = tgt_app[s]
        else:
            hit = np.nonzero(key_idx == t)[0]
            tg = tgt_key[hit[0]] if len(hit) else None
        for a in range(2):
            if not active[a]:
                continue
            rec.log(f"world/tcp/{arms[a]}", rr.Points3D([tcp[s, a, 4:]], colors=[[0, 200, 0]], radii=0.004))
            if tg is not None:
                rec.log(f"world/tcp_target/{arms[a]}", rr.Points3D([tg[a, 4:]], colors=[[255, 0, 0]], radii=0.003))
                err = 1000.0 * float(np.linalg.norm(tcp[s, a, 4:] - tg[a, 4:]))
                rec.log(f"tcp_error_mm/{arms[a]}", rr.Scalars(err))
    rec.flush()
    del rec
    tmp.replace(rrd_path)
    return rrd_path
