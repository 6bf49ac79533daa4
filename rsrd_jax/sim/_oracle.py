"""Oracle plans: the studio demo's own hand contacts followed by inverse kinematics.

A ground-truth stand-in for the planner (no grasp search, no collision checks) that makes a plan
in a second, for tests and benchmarks of the simulator and as a reference of what a perfect
plan achieves in simulation.
"""

from __future__ import annotations

import mujoco
import numpy as np

from ..io import PlanArtefact
from ..robot import HOME_Q
from ._ik import tcp_ik
from ._scene import SimObject, _mat, _vec, build_sim_scene


def contact_grasp(point, pinch_axis, approach) -> np.ndarray:
    """4×4 TCP pose in a part's frame for a pinch at ``point``: TCP z = ``approach`` (towards the
    part), x = ``pinch_axis`` (the jaw axis, made orthogonal to z), y = z × x."""
    z = np.asarray(approach, float)
    z /= np.linalg.norm(z)
    x = np.asarray(pinch_axis, float)
    x = x - z * (x @ z)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], 1)
    T[:3, 3] = point
    return T


def oracle_plan(
    obj: SimObject,
    T_robot_root: np.ndarray | None = None,
    approach_distance: float = 0.06,
    approach_steps: int = 4,
    grasp_offset: np.ndarray | None = None,
    position_tolerance: float = 0.01,
    rotation_tolerance_deg: float = 10.0,
    restarts: int = 8,
) -> PlanArtefact:
    """A plan that pinches the studio demo's contact points and follows the demonstrated part
    trajectory exactly (per-frame IK, warm-started), with the object at ``T_robot_root``.

    Each contact of the catalogue object (one per hand of the demo) goes to the arm on its side
    (one contact: right arm if it is at y < 0 in the robot frame; two: the one at smaller y to
    the right arm); of the two equivalent jaw orientations the one nearer the home TCP
    orientation is used.

    Args:
        obj: from :func:`rsrd_jax.sim.load_sim_object`.
        T_robot_root: (7,) object root pose the plan assumes (default: the true one).
        approach_distance: pre-grasp offset behind the grasp along −TCP z (m).
        approach_steps: waypoints of the approach, pre-grasp to grasp inclusive.
        grasp_offset: (3,) offset (m, robot frame) added to every TCP target (a deliberately wrong
            grasp for tests); None for none.
        restarts: IK starts for the first frame (home, then seeded perturbations of it).

    Returns:
        A :class:`rsrd_jax.io.PlanArtefact` (``result`` "success" or "unreachable"). Its
        ``T_part_grasp`` is in the part's body frame (``info["grasp_frame"] == "body"``) and
        ``min_distance`` is NaN (collisions are not checked).
    """
    from ..studio import get_object

    sobj = get_object(obj.name)
    scene = build_sim_scene(obj, T_robot_root=T_robot_root)
    m = scene.model
    d = mujoco.MjData(m)
    T_rr = _mat(obj.T_robot_root if T_robot_root is None else T_robot_root)
    T_op = np.stack([[_mat(x) for x in row] for row in obj.T_obj_part_demo])  # (T, P, 4, 4)
    n = T_op.shape[0]
    off = np.zeros(3) if grasp_offset is None else np.asarray(grasp_offset, float)
    contacts = list(sobj.contacts)
    # the right arm (y < 0 side of the robot) takes the contact with the smaller y in the robot frame
    ys = [float((T_rr @ T_op[0, c.part] @ np.append(c.point, 1.0))[1]) for c in contacts]
    if len(contacts) == 2:
        arms = [0, 1] if ys[0] <= ys[1] else [1, 0]
    else:
        arms = [0 if ys[0] < 0 else 1]
    d.qpos[scene.robot_qpos] = HOME_Q
    mujoco.mj_kinematics(m, d)
    home_R = [d.site_xmat[s].reshape(3, 3).copy() for s in scene.tcp_sites]

    q_video = np.tile(HOME_Q, (n, 1))
    tcp_t = np.tile(_vec(np.eye(4)), (n, 2, 1))
    q_app = np.tile(HOME_Q, (approach_steps, 1))
    tcp_a = np.tile(_vec(np.eye(4)), (approach_steps, 2, 1))
    pos_err, rot_err = np.full(2, np.nan), np.full(2, np.nan)
    active, part, width = np.zeros(2, bool), np.full(2, -1), np.full(2, np.nan)
    T_pg = np.full((2, 7), np.nan)
    for c, a in zip(contacts, arms):
        G = contact_grasp(c.point, c.pinch_axis, c.approach)
        flip = np.diag([-1.0, -1.0, 1.0, 1.0])  # the jaw is symmetric under a half turn about z
        R0 = (T_rr @ T_op[0, c.part] @ G)[:3, :3]
        if np.trace(home_R[a].T @ R0 @ flip[:3, :3]) > np.trace(home_R[a].T @ R0):
            G = G @ flip
        active[a], part[a], width[a], T_pg[a] = True, c.part, c.width, _vec(G)
        targets = T_rr[None] @ T_op[:, c.part] @ G[None]
        targets[:, :3, 3] += off
        # first frame: multi-start (home and seeded perturbations of it), keep the best
        rng = np.random.default_rng(0)
        best = None
        for i in range(restarts):
            q0 = HOME_Q.copy()
            if i:
                q0[7 * a : 7 * a + 7] += rng.uniform(-1.0, 1.0, 7)
            sol = tcp_ik(m, d, scene.robot_qpos, scene.robot_dof, scene.tcp_sites[a], a, q0, targets[0], iterations=300)
            if best is None or sol[1] + 0.1 * sol[2] < best[1] + 0.1 * best[2]:
                best = sol
            if best[1] < 1e-3 and best[2] < 1e-2:
                break
        q = best[0]
        pe = re = 0.0
        for t in range(n):
            q, e_p, e_r = tcp_ik(m, d, scene.robot_qpos, scene.robot_dof, scene.tcp_sites[a], a, q, targets[t],
                                 iterations=300 if t == 0 else 60)  # fmt: skip
            q_video[t, 7 * a : 7 * a + 7] = q[7 * a : 7 * a + 7]
            tcp_t[t, a] = _vec(targets[t])
            pe, re = max(pe, e_p), max(re, e_r)
        qa = q_video[0].copy()
        for i, s in enumerate(np.linspace(1.0, 0.0, approach_steps)):
            T = targets[0].copy()
            T[:3, 3] -= s * approach_distance * T[:3, 2]
            qa, e_p, e_r = tcp_ik(m, d, scene.robot_qpos, scene.robot_dof, scene.tcp_sites[a], a,
                                  q_video[0] if i == 0 else qa, T, iterations=200)  # fmt: skip
            q_app[i, 7 * a : 7 * a + 7] = qa[7 * a : 7 * a + 7]
            tcp_a[i, a] = _vec(T)
            pe, re = max(pe, e_p), max(re, e_r)
        pos_err[a], rot_err[a] = pe, re
    for a in range(2):
        if not active[a]:
            d.qpos[scene.robot_qpos] = HOME_Q
            mujoco.mj_kinematics(m, d)
            home = np.eye(4)
            home[:3, :3], home[:3, 3] = d.site_xmat[scene.tcp_sites[a]].reshape(3, 3), d.site_xpos[scene.tcp_sites[a]]
            tcp_t[:, a], tcp_a[:, a] = _vec(home), _vec(home)
    ok = bool(np.nanmax(pos_err) <= position_tolerance and np.nanmax(rot_err) <= np.deg2rad(rotation_tolerance_deg))
    return PlanArtefact(
        keyframe_indices=np.arange(n), q_keyframes=q_video.copy(), q_video=q_video, q_approach=q_app,
        tcp_target=tcp_t, tcp_approach_target=tcp_a, active=active, part=part,
        grasp_index=np.where(active, 0, -1), T_part_grasp=T_pg, grasp_width=width, T_robot_obj=_vec(T_rr),
        position_error=pos_err, rotation_error=rot_err, min_distance=np.full(3, np.nan),
        result="success" if ok else "unreachable",
        message="oracle plan (demo contacts + IK)" if ok else
        f"oracle IK missed its targets by {1000 * np.nanmax(pos_err):.1f} mm / {np.rad2deg(np.nanmax(rot_err)):.1f}°",
        info={"oracle": True, "grasp_frame": "body", "arms": [int(a) for a in arms],
              "grasp_offset": off.tolist(), "T_robot_root": _vec(T_rr).tolist()},
    )  # fmt: skip
