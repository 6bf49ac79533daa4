"""The simulation scene: YuMi + table + the studio object with its real joints at the true pose."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import mujoco
import numpy as np

from ..io import ArtefactError, read_json, require
from ..robot import HOME_Q, JOINT_NAMES, build_scene_spec
from ._config import SimConfig

OBJECT_PREFIX = "obj/"
"""Prefix of every object name in the simulation scene."""
ROBOT_CAMERA = "robot_view"
"""Name of the robot-view camera added to the scene (studio's ROBOT_CAMERA_EYE/TARGET)."""
PAD_GEOMS = (("pad_r_finger_r", "pad_r_finger_l"), ("pad_l_finger_r", "pad_l_finger_l"))
"""Finger pad geoms of the right and left gripper (the geoms that grasp by friction)."""
_FINGER_MIMIC = ("gripper_r_joint_m", "gripper_l_joint_m")


def _mat(x7: np.ndarray) -> np.ndarray:
    x7 = np.asarray(x7, np.float64)
    T = np.eye(4)
    q = x7[:4] / np.linalg.norm(x7[:4])
    R = np.zeros(9)
    mujoco.mju_quat2Mat(R, q)
    T[:3, :3] = R.reshape(3, 3)
    T[:3, 3] = x7[4:]
    return T


def _vec(T: np.ndarray) -> np.ndarray:
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(T[:3, :3]).reshape(9))
    return np.concatenate([q, T[:3, 3]])


@dataclasses.dataclass(frozen=True)
class SimObject:
    """What the simulator needs of a studio object (read by :func:`load_sim_object`)."""

    name: str
    """Catalogue name (``rsrd_jax.studio.get_object``)."""
    seed: int
    """Studio seed (textures)."""
    num_parts: int
    """P parts; part 0 is the root."""
    T_robot_root: np.ndarray
    """(7,) true root pose in the robot base frame (wxyz_xyz, from ``robot_view/gt.json``)."""
    T_obj_part_demo: np.ndarray
    """(T, P, 7) demonstrated part poses in the object (root body) frame, per video frame."""
    directory: Path
    """The studio directory it was read from."""


def load_sim_object(studio_dir: str | Path) -> SimObject:
    """Reads a studio object's simulation inputs: ``object.json`` (name, seed, parts),
    ``robot_view/gt.json`` (``T_robot_root``) and ``demo/gt/part_poses.npz`` (``T_obj_part``).

    Raises:
        ArtefactError: naming the missing or malformed file and field.
    """
    d = Path(studio_dir)
    if not d.is_dir():
        raise ArtefactError(f"studio directory not found: {d}")
    meta = read_json(d / "object.json", "studio object.json")
    for f in ("name", "seed", "parts"):
        require(f in meta, d / "object.json", f, "present")
    gt = read_json(d / "robot_view" / "gt.json", "studio robot_view/gt.json")
    require("T_robot_root" in gt, d / "robot_view" / "gt.json", "T_robot_root", "present")
    T_rr = np.asarray(gt["T_robot_root"], float)
    require(T_rr.shape == (7,) and np.all(np.isfinite(T_rr)), d / "robot_view" / "gt.json", "T_robot_root",
            "7 finite numbers (wxyz_xyz)")  # fmt: skip
    npz = d / "demo" / "gt" / "part_poses.npz"
    if not npz.is_file():
        raise ArtefactError(f"demo ground truth not found: {npz}")
    with np.load(npz) as z:
        require("T_obj_part" in z.files, npz, "T_obj_part", "present")
        T_op = np.asarray(z["T_obj_part"], float)
    P = len(meta["parts"])
    require(T_op.ndim == 3 and T_op.shape[1:] == (P, 7) and T_op.shape[0] >= 2, npz, "T_obj_part",
            f"shape (T ≥ 2, {P}, 7) (object.json lists {P} parts), got {T_op.shape}")  # fmt: skip
    return SimObject(name=str(meta["name"]), seed=int(meta["seed"]), num_parts=P, T_robot_root=T_rr,
                     T_obj_part_demo=T_op, directory=d)  # fmt: skip


def _look_at_xyaxes(eye, target) -> list[float]:
    """MuJoCo camera ``xyaxes`` (right, up) of a camera at ``eye`` looking at ``target``."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    f = target - eye
    f /= np.linalg.norm(f)
    r = np.cross(f, [0.0, 0.0, 1.0])
    r /= np.linalg.norm(r)
    return np.concatenate([r, np.cross(r, f)]).tolist()


@dataclasses.dataclass
class SimScene:
    """A compiled simulation scene and the indices the executor needs (host, MuJoCo C)."""

    model: mujoco.MjModel
    data: mujoco.MjData
    obj: SimObject
    robot_qpos: np.ndarray
    """(16,) qpos addresses of JOINT_NAMES."""
    robot_dof: np.ndarray
    """(16,) dof addresses of JOINT_NAMES."""
    mimic_qpos: np.ndarray
    """(2,) qpos addresses of the coupled second fingers."""
    actuators: np.ndarray
    """(16,) actuator ids in JOINT_NAMES order."""
    kp: np.ndarray
    """(16,) servo stiffness."""
    kv: np.ndarray
    """(16,) servo damping."""
    ctrl_range: np.ndarray
    """(16, 2) control ranges."""
    part_bodies: np.ndarray
    """(P,) body ids of the object's parts."""
    part_geoms: list
    """P arrays of geom ids of each part."""
    pad_geoms: np.ndarray
    """(2, 2) geom ids of the finger pads (arm, finger)."""
    tcp_sites: np.ndarray
    """(2,) site ids of tcp_r, tcp_l."""
    object_joints: np.ndarray
    """(J,) joint ids of the object (including a free root joint when ``root="free"``)."""
    camera: int
    """Camera id of the robot view."""
    root: str = "free"
    """How the root is held in this scene: "free" or "weld"."""
    root_note: str = ""
    """Why (``root="auto"``: the rest test's result)."""

    def part_poses(self) -> np.ndarray:
        """(P, 4, 4) current world (= robot base) poses of the parts."""
        out = np.tile(np.eye(4), (self.obj.num_parts, 1, 1))
        out[:, :3, :3] = self.data.xmat[self.part_bodies].reshape(-1, 3, 3)
        out[:, :3, 3] = self.data.xpos[self.part_bodies]
        return out

    def tcp_poses(self) -> np.ndarray:
        """(2, 4, 4) current TCP poses (right, left) in the robot base frame."""
        out = np.tile(np.eye(4), (2, 1, 1))
        out[:, :3, :3] = self.data.site_xmat[self.tcp_sites].reshape(-1, 3, 3)
        out[:, :3, 3] = self.data.site_xpos[self.tcp_sites]
        return out

    def object_qpos_adr(self) -> np.ndarray:
        """qpos addresses of the object's joints (free joints: 7 entries, xyz + wxyz)."""
        m = self.model
        adr = [np.arange(m.jnt_qposadr[j], m.jnt_qposadr[j] + (7 if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE else 1))
               for j in self.object_joints]  # fmt: skip
        return np.concatenate(adr) if adr else np.zeros(0, int)

    def robot_q(self) -> np.ndarray:
        """(16,) current joints in JOINT_NAMES order."""
        return self.data.qpos[self.robot_qpos].copy()

    def servo_ctrl(self, q_ref: np.ndarray, qdot_ref: np.ndarray) -> None:
        """Writes the position-servo command that tracks (q_ref, qdot_ref) into ``data.ctrl``
        (ctrl = q_ref + kv/kp qdot_ref, as :func:`rsrd_jax.robot.servo_ctrl`)."""
        self.data.ctrl[self.actuators] = np.clip(q_ref + self.kv / self.kp * qdot_ref, self.ctrl_range[:, 0],
                                                 self.ctrl_range[:, 1])  # fmt: skip


def build_sim_scene(obj: SimObject, config: SimConfig = SimConfig(), T_robot_root: np.ndarray | None = None) -> SimScene:
    """YuMi + table + the object with its real joints, at the demo's first configuration.

    Args:
        obj: from :func:`load_sim_object`.
        config: physics options (root held free, welded or auto, joint damping/friction, friction).
        T_robot_root: (7,) root pose to place the object at (default: the true ``obj.T_robot_root``).

    Returns:
        A :class:`SimScene` with the robot at ``HOME_Q`` (grippers open) and the object at rest;
        ``scene.root`` says how the root is held ("free" or "weld").
    """
    if config.root == "auto":
        scene = _build(obj, config, T_robot_root, "free")
        moved = _rest_test(scene, config.stability_time)
        if moved <= config.stability_tolerance:
            scene.root_note = f"free (rests: {1000 * moved:.1f} mm in {config.stability_time:g} s alone)"
            return scene
        scene = _build(obj, config, T_robot_root, "weld")
        scene.root_note = (f"weld (free, the object moves {1000 * moved:.0f} mm in {config.stability_time:g} s "
                           "on its own: not a resting pose)")  # fmt: skip
        return scene
    if config.root not in ("free", "weld"):
        raise ValueError(f"config.root must be 'auto', 'free' or 'weld', got {config.root!r}")
    scene = _build(obj, config, T_robot_root, config.root)
    scene.root_note = config.root
    return scene


def _rest_test(scene: SimScene, seconds: float) -> float:
    """Largest displacement (m) of the root part's geom centres when the object is simulated with
    the robot holding home (on a copy of the state; moving parts may sag on their joints)."""
    m = scene.model
    d = mujoco.MjData(m)
    d.qpos[:], d.ctrl[:] = scene.data.qpos, scene.data.ctrl
    mujoco.mj_forward(m, d)
    geoms = scene.part_geoms[0]
    x0 = d.geom_xpos[geoms].copy()
    mujoco.mj_step(m, d, nstep=max(1, int(round(seconds / m.opt.timestep))))
    return float(np.linalg.norm(d.geom_xpos[geoms] - x0, axis=1).max())


def _build(obj: SimObject, config: SimConfig, T_robot_root: np.ndarray | None, root_mode: str) -> SimScene:
    from ..studio import ROBOT_CAMERA_EYE, ROBOT_CAMERA_TARGET, get_object, object_mjcf

    sobj = get_object(obj.name)
    if sobj.num_parts != obj.num_parts:
        raise ArtefactError(f"{obj.directory / 'object.json'}: {obj.num_parts} parts, but the catalogue's "
                            f"{obj.name!r} has {sobj.num_parts}")  # fmt: skip
    T_rr = obj.T_robot_root if T_robot_root is None else np.asarray(T_robot_root, float)
    if T_rr.shape != (7,) or not np.all(np.isfinite(T_rr)):
        raise ValueError(f"T_robot_root must be 7 finite numbers (wxyz_xyz), got {T_rr}")
    asset_xml, body_xml, files = object_mjcf(sobj, np.eye(4), obj.seed, joint_damping=config.joint_damping,
                                             joint_frictionloss=config.joint_frictionloss)  # fmt: skip
    # a whole document, so that the object's angles are read in radians (the MJCF default is degrees)
    doc = (f'<mujoco model="{obj.name}"><compiler angle="radian"/><asset>{asset_xml}</asset>'
           f"<worldbody>{body_xml}</worldbody></mujoco>")
    spec = build_scene_spec(doc, pos=T_rr[4:], quat_wxyz=T_rr[:4], prefix=OBJECT_PREFIX, assets=files)
    spec.option.timestep = config.timestep
    root = spec.body(f"{OBJECT_PREFIX}part0")
    if root_mode == "free":
        root.add_freejoint(name=f"{OBJECT_PREFIX}root")
    for k in range(obj.num_parts):
        for g in spec.body(f"{OBJECT_PREFIX}part{k}").geoms:
            g.friction = [config.object_friction, g.friction[1], g.friction[2]]
            if config.object_density is not None:
                g.density = config.object_density
    if config.pad_friction is not None:
        for pair in PAD_GEOMS:
            for name in pair:
                g = spec.geom(name)
                g.friction = [config.pad_friction, g.friction[1], g.friction[2]]
    # parts touching their parent at the joint do not collide with it (MuJoCo's parent filter
    # does not apply once the root is welded to the world)
    for k, part in enumerate(sobj.parts):
        if part.parent is not None:
            spec.add_exclude(bodyname1=f"{OBJECT_PREFIX}part{part.parent}", bodyname2=f"{OBJECT_PREFIX}part{k}")
    spec.worldbody.add_camera(name=ROBOT_CAMERA, pos=list(ROBOT_CAMERA_EYE), fovy=config.video_fovy_deg,
                              xyaxes=_look_at_xyaxes(ROBOT_CAMERA_EYE, ROBOT_CAMERA_TARGET))  # fmt: skip
    # no multisampling and coarser quadrics: 30 -> 5 ms per 320x240 frame on llvmpipe
    spec.visual.quality.offsamples = 0
    spec.visual.quality.numslices = 16
    spec.visual.quality.numstacks = 8
    spec.visual.global_.offwidth = max(640, int(config.video_size[0]))
    spec.visual.global_.offheight = max(480, int(config.video_size[1]))
    m = spec.compile()
    root_mass = float(m.body_mass[m.body(f"{OBJECT_PREFIX}part0").id])
    if root_mode == "free" and 0 < root_mass < config.min_root_mass:
        for g in root.geoms:
            g.density = g.density * config.min_root_mass / root_mass
        m = spec.compile()
    d = mujoco.MjData(m)

    jid = [m.joint(n).id for n in JOINT_NAMES]
    acts = np.array([m.actuator(f"act_{n}").id for n in JOINT_NAMES[:14]] +
                    [m.actuator("act_gripper_r").id, m.actuator("act_gripper_l").id])  # fmt: skip
    bodies = np.array([m.body(f"{OBJECT_PREFIX}part{k}").id for k in range(obj.num_parts)])
    geoms = [np.flatnonzero(m.geom_bodyid == b) for b in bodies]
    obj_joints = np.array([j for j in range(m.njnt) if m.jnt_bodyid[j] in set(bodies.tolist())], int)
    scene = SimScene(
        model=m, data=d, obj=obj,
        robot_qpos=m.jnt_qposadr[jid].copy(), robot_dof=m.jnt_dofadr[jid].copy(),
        mimic_qpos=np.array([m.jnt_qposadr[m.joint(n).id] for n in _FINGER_MIMIC]),
        actuators=acts, kp=m.actuator_gainprm[acts, 0].copy(), kv=-m.actuator_biasprm[acts, 2].copy(),
        ctrl_range=m.actuator_ctrlrange[acts].copy(), part_bodies=bodies, part_geoms=geoms,
        pad_geoms=np.array([[m.geom(n).id for n in pair] for pair in PAD_GEOMS]),
        tcp_sites=np.array([m.site("tcp_r").id, m.site("tcp_l").id]), object_joints=obj_joints,
        camera=m.camera(ROBOT_CAMERA).id, root=root_mode,
    )  # fmt: skip

    # robot at home, grippers open; object joints at the demo's first configuration
    d.qpos[scene.robot_qpos] = HOME_Q
    d.qpos[scene.mimic_qpos] = HOME_Q[14:16]
    mujoco.mj_kinematics(m, d)
    T_root = _mat(T_rr)
    for k, v in sobj.joint_values(0.0).items():
        j = m.body(f"{OBJECT_PREFIX}part{k}").jntadr[0]
        adr = m.jnt_qposadr[j]
        if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE:
            import jaxlie

            T_rest = T_root.copy()
            T_rest[:3, 3] = T_root[:3, :3] @ np.asarray(sobj.parts[k].pos) + T_root[:3, 3]
            T = T_rest @ np.asarray(jaxlie.SE3.exp(np.asarray(v, np.float32)).as_matrix(), np.float64)
            d.qpos[adr : adr + 7] = _vec(T)[[4, 5, 6, 0, 1, 2, 3]]
        else:
            d.qpos[adr] = float(v[0])
    d.ctrl[:] = 0.0
    scene.servo_ctrl(HOME_Q, np.zeros(16))
    mujoco.mj_forward(m, d)
    return scene
