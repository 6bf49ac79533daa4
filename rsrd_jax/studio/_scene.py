"""A MuJoCo scene around one studio object: floor or table, lights, one movable camera, proxy hands.

Rendering is MuJoCo's OpenGL renderer (`MUJOCO_GL=egl`), never the project's rasterizer, so ground
truth cannot share the tracker's rendering errors.
"""

from __future__ import annotations

import dataclasses

import jaxlie
import mujoco
import numpy as np

from ._spec import StudioObject, object_mjcf, png_bytes

FINGER_RADIUS = 0.008
"""Radius of the proxy hand's finger capsules, metres."""
SKIN = (0.87, 0.67, 0.55)
HAND_LABEL = 255
"""Label of hand pixels in segmentation images."""


@dataclasses.dataclass(frozen=True)
class SceneOptions:
    width: int
    height: int
    fovy_deg: float
    seed: int
    hands: bool = False
    clutter: bool = False
    lighting: float = 1.0
    ground: str = "floor"  # "floor" (scan/demo) or "table" (robot view)


def _hand_xml(i: int, width: float) -> str:
    """A proxy hand in its own frame (x = thumb→index pinch axis, z = approach direction), with
    fingertip capsules touching the part surfaces `width` apart, and a forearm as a second mocap
    body that `StudioScene` points up and away from the object."""
    s = " ".join(f"{c:.3f}" for c in SKIN)
    t = width / 2 + FINGER_RADIUS
    geoms = [
        # fingers: capsules ending at the fingertips (±x), running back against the approach
        f'<geom name="hand{i}_thumb" type="capsule" size="{FINGER_RADIUS}" fromto="{-t:.4f} 0 0 {-t - 0.015:.4f} -0.008 -0.04" rgba="{s} 1"/>',
        f'<geom name="hand{i}_index" type="capsule" size="{FINGER_RADIUS}" fromto="{t:.4f} 0 0 {t + 0.015:.4f} 0.0 -0.045" rgba="{s} 1"/>',
        f'<geom name="hand{i}_palm" type="box" size="{max(0.03, t + 0.012):.4f} 0.012 0.022" pos="0 -0.004 -0.065" rgba="{s} 1"/>',
    ]
    arm = f'<geom name="hand{i}_arm" type="capsule" size="0.022" fromto="0 0 0 0 0 0.25" rgba="{s} 1"/>'
    return f'<body name="hand{i}" mocap="true">{"".join(geoms)}</body><body name="arm{i}" mocap="true">{arm}</body>'


def ground_texture(seed: int, size: int = 256) -> np.ndarray:
    """A low-contrast wood-grain texture for the floor/table (size×size×3 uint8)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:size, 0:size] / size
    warp = 0.03 * np.sin(2 * np.pi * (2 * yy + rng.uniform()))
    grain = 0.5 + 0.5 * np.sin(2 * np.pi * (18 * (xx + warp) + 3 * np.sin(2 * np.pi * yy)))
    base = np.array([0.62, 0.5, 0.38]) * (0.85 + 0.15 * grain)[..., None]
    img = base + rng.normal(0, 0.02, base.shape)
    return (np.clip(img, 0, 1) * 255).astype(np.uint8)


def build_scene(obj: StudioObject, T_world_root: np.ndarray, opts: SceneOptions) -> StudioScene:
    """Compiles the scene (object placed at `T_world_root`, 4×4) and returns a renderable handle."""
    asset_xml, body_xml, files = object_mjcf(obj, T_world_root, opts.seed)
    rng = np.random.default_rng(opts.seed + 7)
    files["ground.png"] = png_bytes(ground_texture(opts.seed + 99))
    li = opts.lighting
    extras = []
    if opts.ground == "floor":
        extras.append('<geom name="ground" type="plane" size="2 2 0.1" material="ground_mat"/>')
    else:  # a table whose top is the z = 0 plane
        extras.append('<geom name="ground" type="box" size="0.45 0.7 0.02" pos="0.45 0 -0.02" material="ground_mat"/>')
    if opts.clutter:
        centre = T_world_root[:3, 3]
        for j in range(6):
            ang = rng.uniform(0, 2 * np.pi)
            r = rng.uniform(0.2, 0.35)
            h = rng.uniform(0.01, 0.04)
            p = centre + np.array([r * np.cos(ang), r * np.sin(ang), 0])
            c = " ".join(f"{x:.3f}" for x in rng.uniform(0.1, 0.9, 3))
            extras.append(
                f'<geom name="clutter{j}" type="box" size="{rng.uniform(0.015, 0.04):.3f} {rng.uniform(0.015, 0.04):.3f} {h:.3f}" '
                f'pos="{p[0]:.3f} {p[1]:.3f} {h:.3f}" euler="0 0 {rng.uniform(0, 3):.3f}" rgba="{c} 1"/>'
            )
    if opts.hands:
        extras += [_hand_xml(i, c.width) for i, c in enumerate(obj.contacts)]
    xml = f"""<mujoco model="studio_{obj.name}">
  <compiler angle="radian"/>
  <statistic extent="1" center="0 0 0"/>
  <visual>
    <global offwidth="{max(opts.width, 640)}" offheight="{max(opts.height, 480)}" fovy="{opts.fovy_deg}"/>
    <map znear="0.005" zfar="20"/>
    <headlight ambient="{0.35 * li:.3f} {0.35 * li:.3f} {0.35 * li:.3f}" diffuse="{0.3 * li:.3f} {0.3 * li:.3f} {0.3 * li:.3f}" specular="0.05 0.05 0.05"/>
    <quality shadowsize="0"/>
  </visual>
  <asset>
    <texture name="sky" type="skybox" builtin="gradient" rgb1="0.75 0.8 0.85" rgb2="0.35 0.38 0.42" width="64" height="64"/>
    <texture name="ground_tex" type="2d" file="ground.png"/>
    <material name="ground_mat" texture="ground_tex" texrepeat="4 4" texuniform="true"/>
    {asset_xml}
  </asset>
  <worldbody>
    <light directional="true" pos="0 0 3" dir="-0.3 0.4 -1" diffuse="{0.5 * li:.3f} {0.5 * li:.3f} {0.48 * li:.3f}" castshadow="false"/>
    <light directional="true" pos="0 0 3" dir="0.5 -0.6 -0.6" diffuse="{0.3 * li:.3f} {0.3 * li:.3f} {0.32 * li:.3f}" castshadow="false"/>
    <camera name="studio_cam" pos="0 0 1" quat="1 0 0 0" fovy="{opts.fovy_deg}"/>
    {chr(10).join(extras)}
{body_xml}
  </worldbody>
</mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml, files)
    return StudioScene(obj, model, opts, xml, files)


class StudioScene:
    """Holds a compiled scene; poses parts, hands and the camera, and renders RGB/depth/labels."""

    def __init__(self, obj: StudioObject, model: mujoco.MjModel, opts: SceneOptions, xml: str, files: dict):
        self.obj, self.model, self.opts, self.xml, self.files = obj, model, opts, xml, files
        self.data = mujoco.MjData(model)
        m = model
        self.body_ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"part{k}") for k in range(obj.num_parts)]
        self.qpos_adr = {}
        for k, p in enumerate(obj.parts):
            if p.joint != "fixed":
                jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, f"joint{k}")
                self.qpos_adr[k] = int(m.jnt_qposadr[jid])
        # geom id -> label: part k -> k + 1, hand -> HAND_LABEL, everything else 0
        self.geom_label = np.zeros(m.ngeom + 1, np.uint8)
        for g in range(m.ngeom):
            b = int(m.geom_bodyid[g])
            if b in self.body_ids:
                self.geom_label[g] = self.body_ids.index(b) + 1
            elif mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b).startswith(("hand", "arm")):
                self.geom_label[g] = HAND_LABEL
        self.cam_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, "studio_cam")
        mocap = lambda name: int(m.body_mocapid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)])  # noqa: E731
        self.hand_mocap = [mocap(f"hand{i}") for i in range(len(obj.contacts))] if opts.hands else []
        self.arm_mocap = [mocap(f"arm{i}") for i in range(len(obj.contacts))] if opts.hands else []
        # rest poses of free parts (for their offsets)
        mujoco.mj_kinematics(m, self.data)
        self.T_world_part_rest = self.part_poses()
        self._renderer: mujoco.Renderer | None = None

    # ------------------------------------------------------------------ posing
    def set_configuration(self, s: float) -> None:
        """Puts every part at the demo's normalised time `s` and the hands at their contacts."""
        d = self.data
        for k, v in self.obj.joint_values(s).items():
            adr = self.qpos_adr[k]
            if self.obj.parts[k].joint == "free":
                T = self.T_world_part_rest[k] @ jaxlie.SE3.exp(np.concatenate([v[:3], v[3:]])).as_matrix()
                T = np.asarray(T, np.float64)
                d.qpos[adr : adr + 3] = T[:3, 3]
                q = np.zeros(4)
                mujoco.mju_mat2Quat(q, T[:3, :3].reshape(9))
                d.qpos[adr + 3 : adr + 7] = q
            else:
                d.qpos[adr] = float(v[0])
        mujoco.mj_kinematics(self.model, d)
        for i, mid in enumerate(self.hand_mocap):
            T = self.hand_pose(i)
            d.mocap_pos[mid] = T[:3, 3]
            q = np.zeros(4)
            mujoco.mju_mat2Quat(q, T[:3, :3].reshape(9))
            d.mocap_quat[mid] = q
            # forearm: from the palm, up and away from the object (less occlusion from above)
            palm = T[:3, :3] @ np.array([0.0, -0.004, -0.075]) + T[:3, 3]
            away = -T[:3, 2] * np.array([1.0, 1.0, 0.0])
            direction = away / max(np.linalg.norm(away), 1e-6) * 0.6 + np.array([0.0, 0.0, 1.0])
            z = direction / np.linalg.norm(direction)
            x = np.cross([0.0, 1.0, 0.0], z)
            x = x / max(np.linalg.norm(x), 1e-6) if np.linalg.norm(x) > 1e-6 else np.array([1.0, 0.0, 0.0])
            R = np.stack([x, np.cross(z, x), z], axis=1)
            d.mocap_pos[self.arm_mocap[i]] = palm
            mujoco.mju_mat2Quat(q, R.reshape(9))
            d.mocap_quat[self.arm_mocap[i]] = q
        if self.hand_mocap:
            mujoco.mj_kinematics(self.model, d)

    def part_poses(self) -> np.ndarray:
        """Current `T_world_part` of every part, P×4×4 (MuJoCo's body poses)."""
        out = np.zeros((self.obj.num_parts, 4, 4))
        for k, b in enumerate(self.body_ids):
            out[k, :3, :3] = self.data.xmat[b].reshape(3, 3)
            out[k, :3, 3] = self.data.xpos[b]
            out[k, 3, 3] = 1.0
        return out

    def exterior_part_points(self, n: int, seed: int) -> list[np.ndarray]:
        """≈n surface samples per part (part frame, `part_surface_points`) minus those buried inside
        another geom of the object at the current configuration."""
        T = self.part_poses()
        out = []
        for k, b in enumerate(self.body_ids):
            p = part_surface_points(self.model, b, n, seed + k)
            world = p @ T[k, :3, :3].T + T[k, :3, 3]
            out.append(p[~buried_points(self.model, self.data, world, self.body_ids)])
        return out

    def hand_pose(self, i: int) -> np.ndarray:
        """`T_world_hand` of hand i (x pinch axis, z approach) from its contact on the posed part."""
        c = self.obj.contacts[i]
        T_wp = self.part_poses()[c.part]
        x = T_wp[:3, :3] @ np.asarray(c.pinch_axis, float)
        z = T_wp[:3, :3] @ np.asarray(c.approach, float)
        z = z - x * (x @ z)
        x, z = x / np.linalg.norm(x), z / np.linalg.norm(z)
        T = np.eye(4)
        T[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
        T[:3, 3] = T_wp[:3, :3] @ np.asarray(c.point, float) + T_wp[:3, 3]
        return T

    def fingertips(self) -> np.ndarray:
        """World fingertip keypoints, H×2×3 (thumb, index) at the finger capsules' ends."""
        out = np.zeros((len(self.hand_mocap), 2, 3))
        for i in range(len(self.hand_mocap)):
            for j, name in enumerate(("thumb", "index")):
                g = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, f"hand{i}_{name}")
                # capsule axis is its local z; the tip is the end nearest the contact point
                c, R, h = self.data.geom_xpos[g], self.data.geom_xmat[g].reshape(3, 3), self.model.geom_size[g, 1]
                ends = np.stack([c + R[:, 2] * h, c - R[:, 2] * h])
                hand = self.hand_pose(i)[:3, 3]
                out[i, j] = ends[np.argmin(np.linalg.norm(ends - hand, axis=1))]
        return out

    def set_camera(self, T_cam_world: np.ndarray) -> None:
        """Places the studio camera at `T_cam_world` (4×4, OpenCV axes)."""
        T_world_cam = np.linalg.inv(T_cam_world)
        R_mj = T_world_cam[:3, :3] @ np.diag([1.0, -1.0, -1.0])  # OpenCV -> MuJoCo/OpenGL camera axes
        q = np.zeros(4)
        mujoco.mju_mat2Quat(q, R_mj.reshape(9))
        self.model.cam_pos[self.cam_id] = T_world_cam[:3, 3]
        self.model.cam_quat[self.cam_id] = q
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)

    # ------------------------------------------------------------------ rendering
    def _r(self) -> mujoco.Renderer:
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.model, self.opts.height, self.opts.width)
            self._renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
            self._renderer.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
        return self._renderer

    def render(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """RGB (H×W×3 uint8), z-depth (H×W float32 metres, 0 = background sky), labels (H×W uint8)."""
        r = self._r()
        r.update_scene(self.data, self.cam_id)
        rgb = r.render().copy()
        r.enable_depth_rendering()
        r.update_scene(self.data, self.cam_id)
        depth = r.render().astype(np.float32)
        r.disable_depth_rendering()
        r.enable_segmentation_rendering()
        r.update_scene(self.data, self.cam_id)
        seg = r.render()
        r.disable_segmentation_rendering()
        depth[depth > 0.99 * 20.0] = 0.0
        ids = np.where(seg[..., 1] == mujoco.mjtObj.mjOBJ_GEOM, seg[..., 0], -1)
        labels = self.geom_label[ids]  # -1 indexes the trailing 0
        return rgb, depth, labels

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __enter__(self) -> StudioScene:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def part_surface_points(model: mujoco.MjModel, body_id: int, n: int, seed: int) -> np.ndarray:
    """Samples ≈n points on the surfaces of a body's geoms, in the body frame (from MuJoCo's
    compiled geometry, area-weighted)."""
    rng = np.random.default_rng(seed)
    geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] == body_id]
    areas, samplers = [], []
    for g in geoms:
        t, s = model.geom_type[g], model.geom_size[g]
        if t == mujoco.mjtGeom.mjGEOM_BOX:
            a = 8 * (s[0] * s[1] + s[1] * s[2] + s[0] * s[2])

            def box(m, s=s):
                p = rng.uniform(-1, 1, (m, 3)) * s
                w = np.array([s[1] * s[2], s[0] * s[2], s[0] * s[1]])
                ax = rng.choice(3, m, p=w / w.sum())
                p[np.arange(m), ax] = np.sign(rng.uniform(-1, 1, m)) * s[ax]
                return p

            samplers.append(box)
        elif t == mujoco.mjtGeom.mjGEOM_SPHERE:
            a = 4 * np.pi * s[0] ** 2
            samplers.append(lambda m, s=s: _unit_sphere(rng, m) * s[0])
        elif t == mujoco.mjtGeom.mjGEOM_ELLIPSOID:
            a = 4 * np.pi * (s[0] * s[1] + s[1] * s[2] + s[0] * s[2]) / 3  # approximation for weights
            samplers.append(lambda m, s=s: _unit_sphere(rng, m) * s[:3])
        elif t == mujoco.mjtGeom.mjGEOM_CAPSULE:
            r, h = s[0], s[1]
            a = 4 * np.pi * r * r + 4 * np.pi * r * h

            def cap(m, r=r, h=h):
                side = rng.uniform(0, 1, m) < (4 * np.pi * r * h) / (4 * np.pi * r * r + 4 * np.pi * r * h)
                u = _unit_sphere(rng, m) * r
                u[:, 2] += np.where(u[:, 2] >= 0, h, -h)
                ang = rng.uniform(0, 2 * np.pi, m)
                cyl = np.stack([r * np.cos(ang), r * np.sin(ang), rng.uniform(-h, h, m)], 1)
                return np.where(side[:, None], cyl, u)

            samplers.append(cap)
        else:
            continue
        areas.append(a)
    areas = np.asarray(areas)
    counts = [int(c) for c in np.maximum(1, np.round(n * areas / areas.sum()))]
    pts = []
    for g, sampler, m in zip(geoms, samplers, counts):
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, model.geom_quat[g])
        pts.append(sampler(m) @ R.reshape(3, 3).T + model.geom_pos[g])
    return np.concatenate(pts).astype(np.float32)


def buried_points(model: mujoco.MjModel, data: mujoco.MjData, points: np.ndarray, bodies: list[int],
                  margin: float = 2e-4) -> np.ndarray:
    """Which world points lie inside a primitive geom (box, sphere, ellipsoid, capsule, cylinder)
    of `bodies` by more than `margin` metres, at `data`'s current kinematics: surface samples that
    are buried in another geom (a leg's capsule end inside the body) and no camera can see."""
    out = np.zeros(len(points), bool)
    for g in range(model.ngeom):
        if int(model.geom_bodyid[g]) not in bodies:
            continue
        t, s = model.geom_type[g], model.geom_size[g]
        q = (points - data.geom_xpos[g]) @ data.geom_xmat[g].reshape(3, 3)
        if t == mujoco.mjtGeom.mjGEOM_BOX:
            out |= np.all(np.abs(q) < s - margin, axis=1)
        elif t == mujoco.mjtGeom.mjGEOM_SPHERE:
            out |= np.linalg.norm(q, axis=1) < s[0] - margin
        elif t == mujoco.mjtGeom.mjGEOM_ELLIPSOID:
            out |= np.sum((q / (s[:3] - margin)) ** 2, axis=1) < 1.0
        elif t == mujoco.mjtGeom.mjGEOM_CAPSULE:
            axis = np.zeros_like(q)
            axis[:, 2] = np.clip(q[:, 2], -s[1], s[1])
            out |= np.linalg.norm(q - axis, axis=1) < s[0] - margin
        elif t == mujoco.mjtGeom.mjGEOM_CYLINDER:
            out |= (np.linalg.norm(q[:, :2], axis=1) < s[0] - margin) & (np.abs(q[:, 2]) < s[1] - margin)
    return out


def _unit_sphere(rng: np.random.Generator, m: int) -> np.ndarray:
    v = rng.normal(size=(m, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)
