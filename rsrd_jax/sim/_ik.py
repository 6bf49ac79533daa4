"""Damped least-squares inverse kinematics of one YuMi arm on MuJoCo C (host numpy).

Used for the retreat after release and for the oracle plans of tests and benchmarks; the planner
(``rsrd_jax.plan``) has its own trajectory solver.
"""

from __future__ import annotations

import mujoco
import numpy as np

from ..robot import JOINT_LOWER, JOINT_UPPER


def tcp_ik(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    qpos_adr: np.ndarray,
    dof_adr: np.ndarray,
    site: int | np.integer,
    arm: int | np.integer,
    q0: np.ndarray,
    T_target: np.ndarray,
    iterations: int = 100,
    damping: float = 1e-3,
    rot_weight: float = 0.2,
) -> tuple[np.ndarray, float, float]:
    """Joints of arm ``arm`` (0 right, 1 left) that put TCP ``site`` at ``T_target`` (4×4).

    Levenberg–Marquardt-style damped least squares on the 6-D pose error (position in m, rotation
    vector in rad scaled by ``rot_weight`` m/rad), joints clamped to their limits. ``data`` is used
    as scratch (kinematics only).

    Args:
        qpos_adr, dof_adr: (16,) qpos/dof addresses of the robot joints in JOINT_NAMES order.
        q0: (16,) start (the other arm and the grippers are kept).

    Returns:
        (q (16,), position error (m), rotation error (rad)).
    """
    site, arm = int(site), int(arm)
    sl = slice(7 * arm, 7 * arm + 7)
    q = np.asarray(q0, float).copy()
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    quat, qt, dq = np.zeros(4), np.zeros(4), np.zeros(3)
    mujoco.mju_mat2Quat(qt, np.ascontiguousarray(T_target[:3, :3]).reshape(9))
    pos_err = rot_err = np.inf
    for _ in range(iterations):
        data.qpos[qpos_adr] = q
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        ep = T_target[:3, 3] - data.site_xpos[site]
        mujoco.mju_mat2Quat(quat, data.site_xmat[site])
        mujoco.mju_subQuat(dq, qt, quat)  # rotation vector taking the current orientation to the target
        # mju_subQuat works in the local frame of `quat`: rotate it into the world
        er = data.site_xmat[site].reshape(3, 3) @ dq
        pos_err, rot_err = float(np.linalg.norm(ep)), float(np.linalg.norm(er))
        if pos_err < 1e-4 and rot_err < 1e-3:
            break
        mujoco.mj_jacSite(model, data, jacp, jacr, site)
        J = np.concatenate([jacp[:, dof_adr[sl]], rot_weight * jacr[:, dof_adr[sl]]])
        e = np.concatenate([ep, rot_weight * er])
        step = J.T @ np.linalg.solve(J @ J.T + damping * np.eye(6), e)
        q[sl] = np.clip(q[sl] + step, JOINT_LOWER[sl], JOINT_UPPER[sl])
    return q, pos_err, rot_err
