"""Forward kinematics of the YuMi tree in JAX (batched, differentiable)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Array, Float

from ._model import Kinematics, YumiModel, check_q

def _axis_angle(axis: Array, angle: Array) -> Array:
    """Rotation matrix of ``angle`` about unit ``axis`` (Rodrigues)."""
    x, y, z = axis
    K = jnp.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]], dtype=angle.dtype)
    return jnp.eye(3, dtype=angle.dtype) + jnp.sin(angle) * K + (1.0 - jnp.cos(angle)) * (K @ K)


def _fk_single(kin: Kinematics, q: Float[Array, "16"]) -> tuple[Array, Array, Array, Array]:
    """Rotations (21, 3, 3) and positions (21, 3) of the links in LINK_NAMES order, and of the
    two TCPs ((2, 3, 3), (2, 3)), world frame, for one configuration.

    Along each arm T_link_k = T_link_{k-1} T_body_k Rot(axis_k, q_k) (a ``lax.scan`` over the 7
    joints, the two arms vmapped); fingers add a translation axis * q_gripper (mimic pair).
    """

    def arm(aR, ap, aax, aq, gR, gp, fR, fp, fax, gq, tR, tp):
        def step(carry, xs):
            R, p = carry
            Rb, pb, ax, qk = xs
            p = p + R @ pb
            R = R @ Rb @ _axis_angle(ax, q[qk])
            return (R, p), (R, p)

        (R7, p7), (Rs, ps) = jax.lax.scan(step, (kin.base_R, kin.base_p), (aR, ap, aax, aq))
        Rg, pg = R7 @ gR, p7 + R7 @ gp
        Rf = Rg @ fR
        pf = pg + fp @ Rg.T + jnp.einsum("fij,fj->fi", Rf, fax * q[gq])
        links_R = jnp.concatenate([Rs, Rg[None], Rf])
        links_p = jnp.concatenate([ps, pg[None], pf])
        return links_R, links_p, R7 @ tR, p7 + R7 @ tp

    aR, ap, tR, tp = jax.vmap(arm)(kin.arm_R, kin.arm_p, kin.arm_axis, kin.arm_q, kin.grip_R,
                                   kin.grip_p, kin.finger_R, kin.finger_p, kin.finger_axis,
                                   kin.grip_q, kin.tcp_R, kin.tcp_p)
    R = jnp.concatenate([kin.base_R[None], aR.reshape(-1, 3, 3)])
    p = jnp.concatenate([kin.base_p[None], ap.reshape(-1, 3)])
    return R, p, tR, tp


def _check_finite(q: Array) -> Array:
    return eqx.error_if(q, ~jnp.all(jnp.isfinite(q)), "joint configuration q contains NaN/inf")


def _se3(R: Array, p: Array) -> jaxlie.SE3:
    return jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.from_matrix(R), p)


@eqx.filter_jit
def _fk_jit(kin: Kinematics, q: Array, check_finite: bool) -> tuple[Array, Array]:
    if check_finite:
        q = _check_finite(q)
    R, p, tR, tp = jax.vmap(lambda x: _fk_single(kin, x))(q)
    return _se3(R, p).wxyz_xyz, _se3(tR, tp).wxyz_xyz


class FKResult(eqx.Module):
    """Forward-kinematics output (world frame = robot base_link, metres)."""

    T_world_link: jaxlie.SE3
    """Poses of the 21 links in LINK_NAMES order, batch shape (*batch, 21)."""
    T_world_tcp: jaxlie.SE3
    """Poses of the two TCPs (right, left), batch shape (*batch, 2). TCP z points out of the hand."""


def forward_kinematics(
    model: YumiModel, q: Float[Array | np.ndarray, "*batch 16"], check_finite: bool = True
) -> FKResult:
    """Link and TCP poses for a batch of configurations (jit, vmap and grad compatible).

    Args:
        model: from :func:`load_yumi`.
        q: joint values in JOINT_NAMES order (rad; gripper entries in m), any batch shape.
        check_finite: raise (``eqx.error_if``) when q holds NaN/inf; turn off inside solvers
            that report non-finite iterates as values.

    Returns:
        :class:`FKResult` with ``T_world_link`` (*batch, 21) and ``T_world_tcp`` (*batch, 2).

    Raises:
        ValueError: if the last axis of q is not 16.
    """
    check_q(q)
    q = jnp.asarray(q)
    batch = q.shape[:-1]
    # Flatten on the host so every batch shape with the same size shares one compilation.
    links, tcp = _fk_jit(model.kin, q.reshape(-1, q.shape[-1]), check_finite)
    return FKResult(T_world_link=jaxlie.SE3(links.reshape(*batch, *links.shape[1:])),
                    T_world_tcp=jaxlie.SE3(tcp.reshape(*batch, *tcp.shape[1:])))


def tcp_poses(
    model: YumiModel, q: Float[Array | np.ndarray, "*batch 16"], check_finite: bool = True
) -> Float[Array, "*batch 2 7"]:
    """TCP poses (right, left) as wxyz_xyz 7-vectors, world frame; see :func:`forward_kinematics`."""
    return forward_kinematics(model, q, check_finite).T_world_tcp.wxyz_xyz


def _tcp_jacobian_single(kin: Kinematics, q: Float[Array, "16"]) -> tuple[Array, Array, Array]:
    """TCP rotations (2, 3, 3), positions (2, 3) and world-frame Jacobians (2, 6, 16) of one
    configuration: rows 0..2 the TCP point's linear velocity, 3..5 the angular velocity, per unit
    joint velocity (arm joint k of arm a turns about ``R_k axis_k`` through ``p_k``; the gripper
    joints do not move the TCP)."""
    R, p, tR, tp = _fk_single(kin, q)
    Rk = R[1:].reshape(2, -1, 3, 3)[:, : kin.arm_axis.shape[1]]  # (2, 7, 3, 3) arm links
    pk = p[1:].reshape(2, -1, 3)[:, : kin.arm_axis.shape[1]]
    w = jnp.einsum("akij,akj->aki", Rk, kin.arm_axis)  # (2, 7, 3) joint axes, world frame
    v = jnp.cross(w, tp[:, None] - pk)  # (2, 7, 3)
    cols = jax.nn.one_hot(kin.arm_q, q.shape[-1], dtype=q.dtype)  # (2, 7, 16): no scatter
    J = jnp.einsum("akr,akj->arj", jnp.concatenate([v, w], -1), cols)
    return tR, tp, J


def tcp_jacobian(
    model: YumiModel, q: Float[Array | np.ndarray, "*batch 16"], check_finite: bool = True
) -> tuple[Float[Array, "*batch 2 7"], Float[Array, "*batch 2 6 16"]]:
    """TCP poses (right, left; wxyz_xyz, world frame) and their geometric Jacobians: ``J[..., a,
    :3, j]`` is the velocity of arm a's TCP point and ``J[..., a, 3:, j]`` its angular velocity
    (world frame) per unit velocity of joint j (jit, vmap and grad compatible). One forward pass
    instead of 16 forward-mode tangents through :func:`forward_kinematics`."""
    check_q(q)
    q = jnp.asarray(q)
    if check_finite:
        q = _check_finite(q)
    batch = q.shape[:-1]
    tR, tp, J = jax.vmap(lambda x: _tcp_jacobian_single(model.kin, x))(q.reshape(-1, q.shape[-1]))
    T = _se3(tR, tp).wxyz_xyz
    return T.reshape(*batch, 2, 7), J.reshape(*batch, 2, 6, q.shape[-1])
