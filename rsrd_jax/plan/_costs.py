"""Trajectory costs for the YuMi on the block-banded LM (RSRD's setup, robot.md §2.4).

Variables: one 16-vector of joints per keyframe (JOINT_NAMES order). Residual groups:

    pose      (unary)   per arm: w_pos (p_tcp - p_target) and w_rot log(R_target^T R_tcp) for an
                        active arm; w_hold (q_arm - home_arm) for an inactive one (held near home)
    limits    (unary)   w_limit (max(0, q - upper) + max(0, lower - q))
    rest      (unary)   w_rest (q - home)
    velocity  (band 1)  w_vel (q_t - q_{t-1})
    accel     (band 2)  w_acc (q_t - 2 q_{t-1} + q_{t-2})          [only when w_acc > 0]
    collision (unary)   w_coll max(0, margin - d) over self, table and (masked) object distances
                                                                   [only when w_coll > 0]

Residuals are weight × vector as in RSRD (the squared cost scales with weight²). Weights are array
leaves (changing them does not recompile); which groups exist is decided on the host.
"""

from __future__ import annotations

import dataclasses
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
from jaxtyping import Array, Bool, Float

from ..robot import (
    LEFT_ARM, RIGHT_ARM, ObjectGeometry, YumiModel, collision_distances, forward_kinematics, tcp_jacobian,
)  # fmt: skip
from ._lm import BandedProblem, Cost


def _as_float(x) -> Array:
    return jnp.asarray(x, dtype=jnp.float32)


class CostWeights(eqx.Module):
    """Residual weights (RSRD final planner defaults). Residual = weight × error."""

    position: Float[Array, ""] = eqx.field(converter=_as_float, default=5.0)
    """TCP position error weight (per metre)."""
    rotation: Float[Array, ""] = eqx.field(converter=_as_float, default=1.0)
    """TCP rotation error weight (per radian, SO(3) log)."""
    limits: Float[Array, ""] = eqx.field(converter=_as_float, default=100.0)
    """Joint-limit hinge weight."""
    rest: Float[Array, ""] = eqx.field(converter=_as_float, default=0.01)
    """Pull towards the home pose."""
    hold: Float[Array, ""] = eqx.field(converter=_as_float, default=1.0)
    """Pull of an inactive arm towards its home joints (single-arm problems)."""
    velocity: Float[Array, ""] = eqx.field(converter=_as_float, default=1.0)
    """Smoothness: first difference of joints between keyframes."""
    acceleration: Float[Array, ""] = eqx.field(converter=_as_float, default=0.0)
    """Smoothness: second difference (the group is left out when 0)."""
    collision: Float[Array, ""] = eqx.field(converter=_as_float, default=0.0)
    """Collision hinge weight (the group is left out when 0; RSRD filters collisions post hoc)."""
    collision_margin: Float[Array, ""] = eqx.field(converter=_as_float, default=0.01)
    """Distances below this (m) are penalised by the collision hinge."""


class CostParams(eqx.Module):
    """Everything the residuals share (the ``params`` of :func:`solve_lm`)."""

    robot: YumiModel
    """Robot (its MJX copy dropped; only kinematics and collision arrays are used)."""
    weights: CostWeights
    """Weights."""
    obj: ObjectGeometry | None
    """Object primitives in part frames for the collision cost, or None."""


class PoseData(eqx.Module):
    """Per-keyframe data of the pose cost (leading axis = keyframes)."""

    target: Float[Array, "*k 2 7"]
    """TCP targets (right, left), robot frame, wxyz_xyz."""
    active: Float[Array, "*k 2"]
    """Weight of an arm's pose rows: > 0 for an arm that tracks its target (1 = the configured
    position/rotation weights), 0 for an arm held near home."""
    q_ref: Float[Array, "*k 16"] | None = None
    """Optional per-keyframe joint reference (e.g. to end an approach at a given configuration)."""
    ref_weight: Float[Array, "*k"] | None = None
    """Weight of ``q - q_ref`` per keyframe (required with ``q_ref``)."""


class CollisionData(eqx.Module):
    """Per-keyframe data of the collision cost."""

    T_world_part: Float[Array, "*k p 7"]
    """Part poses in the robot frame at the keyframe."""
    object_mask: Bool[Array, "*k caps prims"]
    """Which robot-capsule/object-primitive distances count (False: hand vs grasped part)."""


def strip_robot(robot: YumiModel) -> YumiModel:
    """The robot without its MJX model (smaller pytree to pass through jit)."""
    return dataclasses.replace(robot, mjx_model=None)


def _pose_rows(q: Float[Array, "16"], d: PoseData, p: CostParams, T7: Float[Array, "2 7"],
               J: Float[Array, "2 6 16"] | None = None) -> tuple[Array, Array | None]:
    """The pose residual at TCP poses ``T7`` of ``q``, and with the TCPs' geometric Jacobians
    ``J`` (:func:`rsrd_jax.robot.tcp_jacobian`) its Jacobian d r / d q."""
    w = p.weights
    T, tgt = jaxlie.SE3(T7), jaxlie.SE3(d.target)
    pos = (T.translation() - tgt.translation()) * w.position
    R_err = tgt.rotation().inverse() @ T.rotation()
    rot = R_err.log() * w.rotation
    eye = jnp.eye(q.shape[-1], dtype=q.dtype)
    if J is not None:
        # a joint turns the TCP by a left increment in the world frame: d log(R_t^T R) =
        # J_l^{-1}(phi) R_t^T omega, and J_l^{-1} is the transpose of jaxlie's jlog (J_r^{-1})
        Jl_inv = jnp.swapaxes(R_err.jlog(), -1, -2)
        J_rot = jnp.einsum("aij,akj,akn->ain", Jl_inv, tgt.rotation().as_matrix(), J[:, 3:])
    out, jac = [], []
    for a, sl in enumerate((RIGHT_ARM, LEFT_ARM)):
        act = d.active[a]
        hold = (1.0 - jnp.clip(act, 0.0, 1.0)) * w.hold
        out += [act * pos[a], act * rot[a], hold * (q[sl] - p.robot.home[sl])]
        if J is not None:
            jac += [act * w.position * J[a, :3], act * w.rotation * J_rot[a], hold * eye[sl]]
    if d.q_ref is not None:
        out.append(d.ref_weight * (q - d.q_ref))
        jac.append(d.ref_weight * eye)  # unused without J
    return jnp.concatenate(out), (jnp.concatenate(jac) if J is not None else None)


def pose_residual(q: Float[Array, "16"], d: PoseData, p: CostParams) -> Float[Array, " r"]:
    """Pose residual of one keyframe: per arm 6 (active) + 7 (inactive hold) entries, 26 total,
    plus 16 ``ref_weight (q - q_ref)`` entries when the data has a joint reference."""
    return _pose_rows(q, d, p, forward_kinematics(p.robot, q, check_finite=False).T_world_tcp.wxyz_xyz)[0]


def pose_residual_jacobian(q: Float[Array, "16"], d: PoseData, p: CostParams) -> tuple[Array, Array]:
    """:func:`pose_residual` and its analytic Jacobian d r / d q (R, 16), from one FK pass
    (:func:`rsrd_jax.robot.tcp_jacobian`) instead of ``jacfwd``'s 16 tangents."""
    return _pose_rows(q, d, p, *tcp_jacobian(p.robot, q, check_finite=False))


def limit_residual(q: Float[Array, "16"], d: None, p: CostParams) -> Float[Array, "16"]:
    """Joint-limit hinge."""
    return p.weights.limits * (jax.nn.relu(q - p.robot.upper) + jax.nn.relu(p.robot.lower - q))


def rest_residual(q: Float[Array, "16"], d: None, p: CostParams) -> Float[Array, "16"]:
    """Pull towards home."""
    return p.weights.rest * (q - p.robot.home)


def velocity_residual(x: Float[Array, "2 16"], d: None, p: CostParams) -> Float[Array, "16"]:
    """First difference between consecutive keyframes."""
    return p.weights.velocity * (x[1] - x[0])


def acceleration_residual(x: Float[Array, "3 16"], d: None, p: CostParams) -> Float[Array, "16"]:
    """Second difference over three consecutive keyframes."""
    return p.weights.acceleration * (x[2] - 2.0 * x[1] + x[0])


def collision_residual(q: Float[Array, "16"], d: CollisionData, p: CostParams) -> Float[Array, " n"]:
    """Hinge max(0, margin - distance) on every self pair, robot capsule vs table, and masked
    robot capsule vs object primitive."""
    w = p.weights
    res = collision_distances(p.robot, q, p.obj, d.T_world_part, check_finite=False)
    d_obj = jnp.where(d.object_mask, res.object_distance, jnp.inf).reshape(-1)
    dist = jnp.concatenate([res.self_distance, res.table_distance, d_obj])
    return w.collision * jax.nn.relu(w.collision_margin - dist)


@functools.cache
def trajectory_problem(acceleration: bool = False, collision: bool = False) -> BandedProblem:
    """The (cached) banded problem: pose, limits, rest, velocity, and optionally acceleration and
    collision groups. Data tuple order: ``(PoseData, None, None, None[, None][, CollisionData])``;
    params: :class:`CostParams`."""
    costs = [
        Cost(pose_residual, 0, "pose", jac=pose_residual_jacobian),
        Cost(limit_residual, 0, "limits"),
        Cost(rest_residual, 0, "rest"),
        Cost(velocity_residual, 1, "velocity"),
    ]
    if acceleration:
        costs.append(Cost(acceleration_residual, 2, "acceleration"))
    if collision:
        costs.append(Cost(collision_residual, 0, "collision"))
    return BandedProblem(tuple(costs))


def problem_data(
    pose: PoseData, num_keyframes: int, acceleration: bool = False, collision: CollisionData | None = None
) -> tuple:
    """The data tuple aligned with :func:`trajectory_problem` ``(acceleration, collision is not None)``."""
    data: list = [pose, None, None, None]
    if acceleration:
        data.append(None)
    if collision is not None:
        data.append(collision)
    return tuple(data)


def tcp_errors(
    robot: YumiModel, q: Float[Array, "*b 16"], target: Float[Array, "*b 2 7"]
) -> tuple[Float[Array, "*b 2"], Float[Array, "*b 2"]]:
    """TCP position error (m) and rotation error (rad) of both arms against targets."""
    T = forward_kinematics(robot, q, check_finite=False).T_world_tcp
    tgt = jaxlie.SE3(target)
    pos = jnp.linalg.norm(T.translation() - tgt.translation(), axis=-1)
    rot = jnp.linalg.norm((tgt.rotation().inverse() @ T.rotation()).log(), axis=-1)
    return pos, rot
