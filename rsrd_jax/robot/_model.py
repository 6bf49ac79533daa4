"""YumiModel: the robot model loaded once on the host (MJCF -> MjModel -> arrays + mjx.Model)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import mujoco
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ._constants import (
    HOME_Q,
    JOINT_LOWER,
    JOINT_NAMES,
    JOINT_UPPER,
    LEFT_ARM_JOINTS,
    LINK_NAMES,
    NUM_JOINTS,
    RIGHT_ARM_JOINTS,
    SELF_COLLISION_IGNORE,
    TABLE_CENTER,
    TABLE_HALF_EXTENTS,
)
from ._scene import build_scene_spec


class Kinematics(eqx.Module):
    """Kinematic tree of the YuMi as arrays: a fixed base, two 7-joint arms (vmapped), each ending in
    a gripper base with two prismatic fingers. Poses are (R, p) in the parent link frame (metres).
    Arm axis 0 = right, 1 = left."""

    base_R: Float[Array, "3 3"]
    """base_link orientation in the world."""
    base_p: Float[Array, "3"]
    """base_link position in the world."""
    arm_R: Float[Array, "2 7 3 3"]
    """Body frame of arm link k in its parent at q = 0 (rotation)."""
    arm_p: Float[Array, "2 7 3"]
    """Body frame of arm link k in its parent at q = 0 (translation)."""
    arm_axis: Float[Array, "2 7 3"]
    """Hinge axis of each arm joint in its link frame."""
    arm_q: Int[Array, "2 7"]
    """Index into the 16-vector of each arm joint."""
    grip_R: Float[Array, "2 3 3"]
    """Gripper base in link 7 (rotation)."""
    grip_p: Float[Array, "2 3"]
    """Gripper base in link 7 (translation)."""
    finger_R: Float[Array, "2 2 3 3"]
    """Finger body frames (finger_r, finger_l) in the gripper base (rotation)."""
    finger_p: Float[Array, "2 2 3"]
    """Finger body frames in the gripper base (translation)."""
    finger_axis: Float[Array, "2 2 3"]
    """Slide axis of each finger in its own frame; both fingers take the gripper's q (mimic)."""
    grip_q: Int[Array, "2"]
    """Index into the 16-vector of each gripper."""
    tcp_R: Float[Array, "2 3 3"]
    """TCP site in link 7 (rotation)."""
    tcp_p: Float[Array, "2 3"]
    """TCP site in link 7 (translation)."""


class RobotGeometry(eqx.Module):
    """Collision primitives of the robot (link frames) and the fixed pair lists."""

    cap_link: Int[Array, " caps"]
    """Link index of each capsule (spheres are capsules with p0 == p1)."""
    cap_p0: Float[Array, "caps 3"]
    """First end point of the capsule axis in its link frame (m)."""
    cap_p1: Float[Array, "caps 3"]
    """Second end point (m)."""
    cap_radius: Float[Array, " caps"]
    """Capsule radius (m)."""
    box_link: Int[Array, " boxes"]
    """Link index of each robot box (the body AABB on base_link)."""
    box_wxyz_xyz: Float[Array, "boxes 7"]
    """Box pose in its link frame."""
    box_half: Float[Array, "boxes 3"]
    """Box half extents (m)."""
    self_cc: Int[Array, "pairs_cc 2"]
    """Capsule-capsule self-collision pairs (indices into caps), ignore list applied."""
    self_cb: Int[Array, "pairs_cb 2"]
    """Capsule-box self-collision pairs (capsule index, robot box index)."""
    hand_mask: Bool[Array, " caps"]
    """True for capsules on the gripper base and fingers (the parts that touch a grasped object)."""
    cap_names: tuple[str, ...] = eqx.field(static=True)
    """MJCF geom name of each capsule."""
    box_names: tuple[str, ...] = eqx.field(static=True)
    """MJCF geom name of each robot box."""
    table_wxyz_xyz: Float[Array, "7"]
    """Table box pose in the world (m)."""
    table_half: Float[Array, "3"]
    """Table box half extents (m)."""

    def self_pair_names(self) -> list[tuple[str, str]]:
        """Geom names of each entry of ``CollisionResult.self_distance`` (host helper)."""
        cc = [(self.cap_names[i], self.cap_names[j]) for i, j in np.asarray(self.self_cc)]
        cb = [(self.cap_names[i], self.box_names[b]) for i, b in np.asarray(self.self_cb)]
        return cc + cb


class YumiModel(eqx.Module):
    """The YuMi loaded once on the host: kinematics and collision arrays for JAX, the C model and
    its MJX copy. Build with :func:`load_yumi`; pass to the query functions.
    """

    kin: Kinematics
    """Kinematic tree (JAX arrays)."""
    geom: RobotGeometry
    """Collision primitives and pair lists (JAX arrays)."""
    lower: Float[Array, "16"]
    """Joint lower limits in JOINT_NAMES order (rad, m)."""
    upper: Float[Array, "16"]
    """Joint upper limits."""
    home: Float[Array, "16"]
    """Home pose (RSRD YUMI_REST_POSE)."""
    qpos_adr: tuple[int, ...] = eqx.field(static=True)
    """MuJoCo qpos address of each of the 16 joints in ``mj_model``."""
    mimic_qpos_adr: tuple[int, int] = eqx.field(static=True)
    """qpos address of the mimic finger joints (gripper_r_joint_m, gripper_l_joint_m)."""
    mj_model: mujoco.MjModel = eqx.field(static=True)
    """The compiled scene (robot + table [+ object]) for MuJoCo C."""
    mjx_model: object
    """``mjx.put_model(mj_model)``, used by the MJX penetration query."""

    def qpos(self, q: np.ndarray) -> np.ndarray:
        """Host helper: a full MuJoCo qpos (model qpos0 elsewhere) from a 16-vector ``q``."""
        q = np.asarray(q, float)
        out = np.array(self.mj_model.qpos0, float)
        out[list(self.qpos_adr)] = q
        out[list(self.mimic_qpos_adr)] = q[14:16]
        return out


def _wxyz_xyz(quat, pos) -> np.ndarray:
    return np.concatenate([np.asarray(quat, float), np.asarray(pos, float)])


def load_yumi(spec: mujoco.MjSpec | None = None) -> YumiModel:
    """Load the YuMi scene once on the host.

    Args:
        spec: a scene spec from :func:`build_scene_spec` (e.g. with an object); default robot +
            table (``models/yumi_mjcf/scene.xml``).

    Returns:
        A :class:`YumiModel` (kinematics and collision arrays as float32 JAX arrays, the compiled
        ``MjModel`` and its ``mjx.Model``).
    """
    import contextlib
    import io

    with contextlib.redirect_stdout(io.StringIO()):  # mjx prints "Failed to import warp" (optional GPU backend)
        from mujoco import mjx

    spec = build_scene_spec() if spec is None else spec
    m = spec.compile()
    body_id = {n: m.body(n).id for n in LINK_NAMES}
    link_of_body = {b: i for i, b in enumerate(body_id.values())}

    def mat(quat) -> np.ndarray:
        out = np.zeros(9)
        mujoco.mju_quat2Mat(out, np.asarray(quat, float))
        return out.reshape(3, 3)

    def body(name: str) -> tuple[np.ndarray, np.ndarray, int | None, np.ndarray]:
        b = body_id[name]
        nj = int(m.body_jntnum[b])
        j = int(m.body_jntadr[b]) if nj else None
        if j is not None and not np.allclose(m.jnt_pos[j], 0.0):
            raise ValueError(f"joint {m.joint(j).name} must sit at its body origin")
        axis = np.array(m.jnt_axis[j], float) if j is not None else np.zeros(3)
        return mat(m.body_quat[b]), np.array(m.body_pos[b], float), j, axis

    def parent_of(name: str) -> str:
        return m.body(int(m.body_parentid[body_id[name]])).name

    arm_R, arm_p, arm_axis, arm_q = [], [], [], []
    grip_R, grip_p, fin_R, fin_p, fin_axis, grip_q, tcp_R, tcp_p = ([] for _ in range(8))
    for s, joints in (("r", RIGHT_ARM_JOINTS), ("l", LEFT_ARM_JOINTS)):
        links = [f"yumi_link_{k}_{s}" for k in range(1, 8)]
        Rs, ps, axs, qs = [], [], [], []
        for k, (lk, jn) in enumerate(zip(links, joints)):
            if parent_of(lk) != ("base_link" if k == 0 else links[k - 1]):
                raise ValueError(f"unexpected kinematic tree at {lk}")
            R, p, j, ax = body(lk)
            if j is None or m.joint(j).name != jn or m.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE:
                raise ValueError(f"{lk} must be driven by hinge {jn}")
            Rs.append(R), ps.append(p), axs.append(ax), qs.append(JOINT_NAMES.index(jn))
        arm_R.append(Rs), arm_p.append(ps), arm_axis.append(axs), arm_q.append(qs)
        R, p, j, _ = body(f"gripper_{s}_base")
        if j is not None or parent_of(f"gripper_{s}_base") != links[-1]:
            raise ValueError(f"gripper_{s}_base must be welded to {links[-1]}")
        grip_R.append(R), grip_p.append(p)
        fr, fp, fa = [], [], []
        for f, jn in (("finger_r", f"gripper_{s}_joint"), ("finger_l", f"gripper_{s}_joint_m")):
            R, p, j, ax = body(f"gripper_{s}_{f}")
            if j is None or m.joint(j).name != jn or m.jnt_type[j] != mujoco.mjtJoint.mjJNT_SLIDE:
                raise ValueError(f"gripper_{s}_{f} must be driven by slide {jn}")
            fr.append(R), fp.append(p), fa.append(ax)
        fin_R.append(fr), fin_p.append(fp), fin_axis.append(fa)
        grip_q.append(JOINT_NAMES.index(f"gripper_{s}_joint"))
        site = m.site(f"tcp_{s}")
        if int(m.site_bodyid[site.id]) != body_id[links[-1]]:
            raise ValueError(f"tcp_{s} must be a site on {links[-1]}")
        tcp_R.append(mat(m.site_quat[site.id])), tcp_p.append(np.array(m.site_pos[site.id]))
    bR, bp, bj, _ = body("base_link")
    if bj is not None:
        raise ValueError("base_link must be fixed to the world")
    f32 = lambda x: jnp.asarray(np.asarray(x), jnp.float32)  # noqa: E731
    kin = Kinematics(
        base_R=f32(bR), base_p=f32(bp), arm_R=f32(arm_R), arm_p=f32(arm_p),
        arm_axis=f32(arm_axis), arm_q=jnp.asarray(arm_q, jnp.int32), grip_R=f32(grip_R),
        grip_p=f32(grip_p), finger_R=f32(fin_R), finger_p=f32(fin_p), finger_axis=f32(fin_axis),
        grip_q=jnp.asarray(grip_q, jnp.int32), tcp_R=f32(tcp_R), tcp_p=f32(tcp_p),
    )

    # Collision primitives: MJCF geoms named c_<link>_<k> on robot bodies.
    caps, boxes = [], []
    for g in range(m.ngeom):
        name = m.geom(g).name
        if not name.startswith("c_") or int(m.geom_bodyid[g]) not in link_of_body:
            continue
        link = link_of_body[int(m.geom_bodyid[g])]
        pos, quat, size = m.geom_pos[g], m.geom_quat[g], m.geom_size[g]
        t = m.geom_type[g]
        if t == mujoco.mjtGeom.mjGEOM_SPHERE:
            caps.append((name, link, pos, pos, size[0]))
        elif t == mujoco.mjtGeom.mjGEOM_CAPSULE:
            rot = np.zeros(9)
            mujoco.mju_quat2Mat(rot, quat)
            ax = rot.reshape(3, 3)[:, 2] * size[1]
            caps.append((name, link, pos - ax, pos + ax, size[0]))
        elif t == mujoco.mjtGeom.mjGEOM_BOX:
            boxes.append((name, link, _wxyz_xyz(quat, pos), np.array(size, float)))
        else:
            raise ValueError(f"collision geom {name} must be a sphere, capsule or box")
    link_names = [LINK_NAMES[c[1]] for c in caps]
    cc = [(i, j) for i in range(len(caps)) for j in range(i + 1, len(caps))
          if caps[i][1] != caps[j][1]
          and frozenset((link_names[i], link_names[j])) not in SELF_COLLISION_IGNORE]
    cb = [(i, k) for i in range(len(caps)) for k in range(len(boxes))
          if caps[i][1] != boxes[k][1]
          and frozenset((link_names[i], LINK_NAMES[boxes[k][1]])) not in SELF_COLLISION_IGNORE]
    geom = RobotGeometry(
        cap_link=jnp.asarray([c[1] for c in caps], jnp.int32),
        cap_p0=jnp.asarray(np.stack([c[2] for c in caps]), jnp.float32),
        cap_p1=jnp.asarray(np.stack([c[3] for c in caps]), jnp.float32),
        cap_radius=jnp.asarray([c[4] for c in caps], jnp.float32),
        box_link=jnp.asarray([b[1] for b in boxes], jnp.int32),
        box_wxyz_xyz=jnp.asarray(np.stack([b[2] for b in boxes]), jnp.float32),
        box_half=jnp.asarray(np.stack([b[3] for b in boxes]), jnp.float32),
        self_cc=jnp.asarray(np.array(cc, np.int32).reshape(-1, 2)),
        self_cb=jnp.asarray(np.array(cb, np.int32).reshape(-1, 2)),
        hand_mask=jnp.asarray(["gripper" in n for n in link_names]),
        cap_names=tuple(c[0] for c in caps), box_names=tuple(b[0] for b in boxes),
        table_wxyz_xyz=jnp.asarray(_wxyz_xyz([1, 0, 0, 0], TABLE_CENTER), jnp.float32),
        table_half=jnp.asarray(TABLE_HALF_EXTENTS, jnp.float32),
    )
    qadr = tuple(int(m.jnt_qposadr[m.joint(n).id]) for n in JOINT_NAMES)
    madr = tuple(int(m.jnt_qposadr[m.joint(f"{n}_m").id]) for n in JOINT_NAMES[14:])
    return YumiModel(
        kin=kin, geom=geom,
        lower=jnp.asarray(JOINT_LOWER, jnp.float32), upper=jnp.asarray(JOINT_UPPER, jnp.float32),
        home=jnp.asarray(HOME_Q, jnp.float32), qpos_adr=qadr, mimic_qpos_adr=madr,
        mj_model=m, mjx_model=mjx.put_model(m),
    )


def check_q(q, name: str = "q") -> None:
    """Host-boundary check of a joint array: last axis must be 16 and floating point."""
    shape = getattr(q, "shape", None)
    if shape is None or len(shape) < 1 or shape[-1] != NUM_JOINTS:
        raise ValueError(
            f"{name} must have shape (*batch, {NUM_JOINTS}) in JOINT_NAMES order "
            f"(right arm 7, left arm 7, gripper_r, gripper_l); got shape {shape}"
        )
    if not jnp.issubdtype(getattr(q, "dtype", np.float64), jnp.floating):
        raise ValueError(f"{name} must be a floating-point array; got dtype {q.dtype}")
