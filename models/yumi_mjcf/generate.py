"""Generate ``yumi.xml`` (ABB YuMi IRB 14000 MJCF) from ``yumi_kinematics.json``.

Run ``python models/yumi_mjcf/generate.py`` to rewrite ``yumi.xml`` next to this file. The JSON holds
only numbers measured from RSRD's URDF (kerrj/rsrd data/yumi_description/urdf/yumi.urdf @ 0c04783)
and RSRD's cuRobo sphere file; no meshes are used. Everything the generator decides on top of the
JSON (collision primitives for the wrist/gripper, masses, gains) is written here and documented in
the XML comments.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
FACTS = json.loads((HERE / "yumi_kinematics.json").read_text())

ARM_LINKS = ["yumi_link_1", "yumi_link_2", "yumi_link_3", "yumi_link_4", "yumi_link_5",
             "yumi_link_6", "yumi_link_7"]
# Physical order of the joints from the body outwards (ABB numbering quirk: 7 is third).
ARM_JOINTS = ["yumi_joint_1", "yumi_joint_2", "yumi_joint_7", "yumi_joint_3", "yumi_joint_4",
              "yumi_joint_5", "yumi_joint_6"]

# Rough link masses (kg); ABB publishes only the total (38 kg). Used for simulation only.
MASS = {"yumi_link_1": 2.0, "yumi_link_2": 2.0, "yumi_link_3": 1.5, "yumi_link_4": 1.5,
        "yumi_link_5": 1.0, "yumi_link_6": 0.6, "yumi_link_7": 0.3, "gripper_base": 0.5,
        "finger": 0.03}
# Position-servo gains per physical joint (N m/rad, N m s/rad) and force limits (N m).
KP = [1500.0, 1500.0, 1000.0, 1000.0, 500.0, 500.0, 300.0]
KV = [60.0, 60.0, 35.0, 35.0, 12.0, 12.0, 6.0]
FORCE = [150.0, 150.0, 100.0, 100.0, 50.0, 50.0, 30.0]
ARMATURE = [0.1, 0.1, 0.05, 0.05, 0.02, 0.02, 0.01]


def rpy_to_quat(rpy) -> np.ndarray:
    """URDF fixed-axis roll-pitch-yaw (R = Rz(y) Ry(p) Rx(r)) to a wxyz quaternion."""
    r, p, y = (0.5 * float(a) for a in rpy)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    q = np.array([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                  cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy])
    return q if q[0] >= 0 else -q


def fmt(v, nd=6) -> str:
    return " ".join(f"{float(x):.{nd}g}" if abs(float(x)) > 1e-12 else "0" for x in v)


def joint(name: str) -> dict:
    return next(j for j in FACTS["joints"] if j["name"] == name)


def capsule_geoms(link: str) -> list[tuple]:
    """Collision primitives of one arm link in the link frame: (kind, p0, p1, radius).

    Links 1-5 use the capsules that RSRD's cuRobo spheres really are (JSON capsule_equivalent);
    link 5 adds its first sphere. Links 6, 7, the gripper base and the fingers are sphere clusters in
    cuRobo; we cover each cluster with one or two capsules (coverage of every sphere is checked in
    ``check_coverage``; the union over-covers by a few millimetres).
    """
    base = link.rsplit("_", 1)[0]
    side = link.rsplit("_", 1)[1]
    caps = FACTS["collision_spheres"]["capsule_equivalent"]
    out = []
    if base in ("yumi_link_1", "yumi_link_2", "yumi_link_3", "yumi_link_4", "yumi_link_5"):
        c = caps[f"{base}_{side}"]
        for s in c["extra_spheres_before"]:
            out.append(("sphere", s["center"], s["center"], s["radius"]))
        out.append(("capsule", c["p0"], c["p1"], c["radius"]))
    elif base == "yumi_link_6":
        out.append(("capsule", [0.0, -0.035, 0.0], [0.0, 0.0, -0.038], 0.031))
        out.append(("capsule", [0.031, -0.032, -0.005], [0.041, 0.008, 0.0], 0.031))
        out.append(("capsule", [0.0, 0.007, 0.0], [0.028, 0.005, -0.013], 0.031))
        out.append(("capsule", [0.0, 0.0, -0.038], [0.014, 0.003, -0.025], 0.031))
    elif base == "yumi_link_7":
        out.append(("sphere", [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], 0.037))
    return out


GRIPPER_BASE_GEOMS = [("capsule", [0.0, 0.0, 0.035], [0.0, 0.0, 0.056], 0.051)]
FINGER_GEOMS = [("capsule", [-0.009, 0.0065, 0.019], [-0.004, 0.0065, 0.052], 0.0135)]


def check_coverage() -> None:
    """Every cuRobo sphere must lie inside the union of our primitives (within 2 mm)."""

    def seg_dist(p, a, b):
        a, b, p = map(np.asarray, (a, b, p))
        ab = b - a
        t = 0.0 if ab @ ab < 1e-12 else np.clip((p - a) @ ab / (ab @ ab), 0, 1)
        return np.linalg.norm(p - (a + t * ab))

    for link, spheres in FACTS["collision_spheres"]["spheres"].items():
        if "gripper" in link and "finger" in link:
            prims = FINGER_GEOMS
        elif "gripper" in link:
            prims = GRIPPER_BASE_GEOMS
        else:
            prims = capsule_geoms(link)
        for s in spheres:
            slack = max(r - seg_dist(s["center"], a, b) - s["radius"] for _, a, b, r in prims)
            assert slack > -0.002, (link, s, slack)


def inertial(mass: float, prims: list[tuple]) -> str:
    pts = np.array([np.add(a, b) / 2 for _, a, b, _ in prims]) if prims else np.zeros((1, 3))
    c = pts.mean(0)
    r = max(r for *_, r in prims) if prims else 0.05
    i = 0.4 * mass * r * r + 1e-5
    return f'<inertial pos="{fmt(c)}" mass="{mass}" diaginertia="{i:.3g} {i:.3g} {i:.3g}"/>'


def geom_xml(prims, link, ind, collide=True, rgba="0.85 0.85 0.85 1") -> list[str]:
    lines = []
    for k, (kind, a, b, r) in enumerate(prims):
        name = f'c_{link}_{k}'
        cls = "collision" if collide else "query_only"
        if kind == "sphere":
            lines.append(f'{ind}<geom name="{name}" class="{cls}" type="sphere" pos="{fmt(a)}" size="{r}"/>')
            lines.append(f'{ind}<geom class="visual" type="sphere" pos="{fmt(a)}" size="{r * 0.97:.4g}" rgba="{rgba}"/>')
        else:
            lines.append(f'{ind}<geom name="{name}" class="{cls}" type="capsule" fromto="{fmt(a)} {fmt(b)}" size="{r}"/>')
            lines.append(f'{ind}<geom class="visual" type="capsule" fromto="{fmt(a)} {fmt(b)}" size="{r * 0.97:.4g}" rgba="{rgba}"/>')
    return lines


def arm_xml(side: str) -> list[str]:
    lines: list[str] = []
    ind = "    "
    closers = []
    for i, (lk, jn) in enumerate(zip(ARM_LINKS, ARM_JOINTS)):
        j = joint(f"{jn}_{side}")
        q = rpy_to_quat(j["origin_rpy"])
        jq = np.asarray(j["origin_quat_wxyz_computed"])
        assert min(np.abs(q - jq).max(), np.abs(q + jq).max()) < 1e-5, j["name"]
        link = f"{lk}_{side}"
        prims = capsule_geoms(link)
        lim = j["limit"]
        lines.append(f'{ind}<body name="{link}" pos="{fmt(j["origin_xyz"])}" quat="{fmt(q, 9)}" gravcomp="1">')
        lines.append(f'{ind}  {inertial(MASS[lk], prims)}')
        lines.append(f'{ind}  <joint name="{j["name"]}" class="arm" armature="{ARMATURE[i]}" '
                     f'range="{lim["lower"]:.9g} {lim["upper"]:.9g}"/>')
        rgba = "0.9 0.9 0.9 1" if i % 2 == 0 else "0.55 0.55 0.6 1"
        lines += geom_xml(prims, link, ind + "  ", rgba=rgba)
        closers.append(f"{ind}</body>")
        ind += "  "
    # link_7 children: TCP site, gripper base with two coupled fingers.
    tcp = FACTS["tcp_frames"][f"{'right' if side == 'r' else 'left'}_dummy_point"]
    lines.append(f'{ind}<!-- TCP (URDF {"right" if side == "r" else "left"}_dummy_point): 0.13 m along link_7 z, yaw pi. -->')
    lines.append(f'{ind}<site name="tcp_{side}" pos="{fmt(tcp["xyz"])}" quat="{fmt(rpy_to_quat(tcp["rpy"]))}" size="0.006" rgba="1 0 0 1" group="2"/>')
    gb = FACTS["gripper"]["base_mount"]
    lines.append(f'{ind}<body name="gripper_{side}_base" pos="{fmt(gb["xyz"])}" quat="{fmt(rpy_to_quat(gb["rpy"]))}" gravcomp="1">')
    lines.append(f'{ind}  {inertial(MASS["gripper_base"], GRIPPER_BASE_GEOMS)}')
    lines += geom_xml(GRIPPER_BASE_GEOMS, f"gripper_{side}_base", ind + "  ", rgba="0.25 0.25 0.3 1")
    fj = FACTS["gripper"]["finger_joints"]
    for fname, jname in (("finger_r", f"gripper_{side}_joint"), ("finger_l", f"gripper_{side}_joint_m")):
        jd = fj[jname.replace(f"_{side}_", "_r_")]
        link = f"gripper_{side}_{fname}"
        lines.append(f'{ind}  <body name="{link}" pos="{fmt(jd["xyz"])}" quat="{fmt(rpy_to_quat(jd["rpy"]))}" gravcomp="1">')
        lines.append(f'{ind}    {inertial(MASS["finger"], FINGER_GEOMS)}')
        lines.append(f'{ind}    <joint name="{jname}" class="finger"/>')
        lines += geom_xml(FINGER_GEOMS, link, ind + "    ", collide=False, rgba="0.2 0.2 0.2 1")
        # Finger pad: inner face at finger-frame x = 0 (stock ABB fingers => jaw = 2 q).
        lines.append(f'{ind}    <geom name="pad_{side}_{fname}" class="pad" pos="-0.004 0.0065 0.0345" size="0.004 0.0125 0.025"/>')
        lines.append(f'{ind}    <geom class="visual" type="box" pos="-0.004 0.0065 0.0345" size="0.004 0.0125 0.025" rgba="0.1 0.1 0.1 1"/>')
        lines.append(f"{ind}  </body>")
    lines.append(f"{ind}</body>")
    lines += closers[::-1]
    return lines


def body_geoms() -> list[str]:
    bb = FACTS["links"]["base_link"]["collision_mesh_aabb"]
    lo, hi = np.array(bb["min"]), np.array(bb["max"])
    lo[2] = 0.0  # clipped at the table top (scene.xml mounts base_link flush with the table)
    c, h = (lo + hi) / 2, (hi - lo) / 2
    return [f'      <geom name="c_base_link_0" class="collision" type="box" pos="{fmt(c)}" size="{fmt(h)}"/>',
            f'      <geom class="visual" type="box" pos="{fmt(c)}" size="{fmt(h * 0.995)}" rgba="0.85 0.85 0.85 1"/>']


def generate() -> str:
    check_coverage()
    hp = FACTS["home_pose"]
    home = dict(zip(hp["order"], hp["values"]))
    qpos = []
    for side in "rl":
        qpos += [home[f"{jn}_{side}"] for jn in ARM_JOINTS]
        g = home[f"gripper_{side}_joint"]
        qpos += [g, g]
    ctrl = [home[f"{jn}_r"] for jn in ARM_JOINTS] + [home[f"{jn}_l"] for jn in ARM_JOINTS]
    ctrl += [home["gripper_r_joint"], home["gripper_l_joint"]]
    acts = []
    for side in "rl":
        for i, jn in enumerate(ARM_JOINTS):
            j = joint(f"{jn}_{side}")
            lim = j["limit"]
            acts.append(f'    <position name="act_{jn}_{side}" joint="{jn}_{side}" kp="{KP[i]}" kv="{KV[i]}" '
                        f'ctrlrange="{lim["lower"]:.9g} {lim["upper"]:.9g}" forcerange="{-FORCE[i]} {FORCE[i]}"/>')
    for side in "rl":
        acts.append(f'    <position name="act_gripper_{side}" joint="gripper_{side}_joint" kp="800" kv="20" '
                    f'ctrlrange="0 0.025" forcerange="-20 20"/>')
    out = [
        '<mujoco model="yumi">',
        "  <!--",
        "  ABB YuMi (IRB 14000), generated by models/yumi_mjcf/generate.py from yumi_kinematics.json",
        "  (numbers from RSRD's URDF kerrj/rsrd data/yumi_description/urdf/yumi.urdf @ 0c04783). No meshes.",
        "",
        "  Frames: world = base_link (robot base frame, x forward, y left, z up). The URDF body mesh",
        "  spans z in [-0.100, 0.471] m of this frame; the body collision box (its AABB) is clipped to",
        "  z >= 0 because scene.xml puts the table top at z = 0 (robot mounted flush with the table).",
        "  Arm joints are named as in the URDF; physical order from the body outwards is",
        "  1, 2, 7, 3, 4, 5, 6 (ABB numbering quirk). All arm joints rotate about their local +z.",
        "  TCP sites tcp_r / tcp_l = URDF right_dummy_point / left_dummy_point: 0.13 m along link_7 +z,",
        "  yaw pi (RSRD plans to these). Gripper: gripper_X_joint (0..0.025 m per finger) drives",
        "  finger_r; finger_l (gripper_X_joint_m) is coupled to it by a joint equality; jaw = 2 q.",
        "",
        "  Geom groups: 1 = visual (no contact), 3 = collision primitives named c_<link>_<k>, 2 = sites.",
        "  Collision primitives: links 1-5 = the capsules RSRD's cuRobo spheres are (link 5 + one",
        "  sphere); the sphere clusters of link 6 / link 7 / gripper base / finger are covered by",
        "  4 capsules / 1 sphere / 1 capsule / 1 capsule (every cuRobo sphere inside, 2 mm tolerance,",
        "  checked by generate.py); the body is its mesh AABB (a box, over-covers the torso).",
        "  Self-collision ignore list: rsrd_jax.robot.SELF_COLLISION_IGNORE (cuRobo's, symmetrised).",
        "  Finger collision capsules are query-only (contype 0); the simulator grasps with the",
        "  box pads pad_<side>_<finger> (friction 1.5). Robot geoms have contype 2 / conaffinity 1,",
        "  so the simulator skips robot-robot contacts (self-collision is a planning query, see",
        "  rsrd_jax.robot) but robot-table and robot-object contacts (contype 1 objects) are on.",
        "  Bodies have gravcomp=1 (the real controller compensates gravity). Masses are rough guesses.",
        "  -->",
        '  <compiler angle="radian" autolimits="true"/>',
        '  <option timestep="0.002" integrator="implicitfast" cone="elliptic" impratio="10"/>',
        "  <default>",
        '    <default class="arm">',
        '      <joint type="hinge" axis="0 0 1" damping="0.5"/>',
        "    </default>",
        '    <default class="finger">',
        '      <joint type="slide" axis="-1 0 0" range="0 0.025" damping="5" armature="0.01"/>',
        "    </default>",
        '    <default class="visual">',
        '      <geom group="1" contype="0" conaffinity="0" density="0"/>',
        "    </default>",
        '    <default class="collision">',
        '      <geom group="3" contype="2" conaffinity="1" density="0" rgba="0.9 0.4 0.1 0.4"/>',
        "    </default>",
        '    <default class="query_only">',
        '      <geom group="3" contype="0" conaffinity="0" density="0" rgba="0.9 0.4 0.1 0.4"/>',
        "    </default>",
        '    <default class="pad">',
        '      <geom group="3" type="box" contype="2" conaffinity="1" density="0" condim="4" '
        'friction="1.5 0.02 0.0001" solref="0.004 1" solimp="0.95 0.99 0.001" rgba="0.1 0.6 0.1 0.6"/>',
        "    </default>",
        "  </default>",
        "  <worldbody>",
        '    <body name="base_link">',
        body_geoms()[0].replace("      ", "      ", 1),
        body_geoms()[1],
    ]
    for side in "rl":
        out.append(f"      <!-- {'right' if side == 'r' else 'left'} arm -->")
        out += ["  " + ln for ln in arm_xml(side)]
    out += [
        "    </body>",
        "  </worldbody>",
        "  <equality>",
        '    <joint name="couple_gripper_r" joint1="gripper_r_joint_m" joint2="gripper_r_joint" polycoef="0 1 0 0 0" solref="0.005 1"/>',
        '    <joint name="couple_gripper_l" joint1="gripper_l_joint_m" joint2="gripper_l_joint" polycoef="0 1 0 0 0" solref="0.005 1"/>',
        "  </equality>",
        "  <!-- Position servos: 14 arm joints (right then left, physical order) + one per gripper",
        "       (commands finger travel in m; 20 N grip force limit as Dex-Net's YuMi gripper).",
        "       force = kp (ctrl - q) - kv qdot, so to track a reference with velocity feed-forward",
        "       command ctrl = q_ref + (kv / kp) qdot_ref (rsrd_jax.robot.servo_ctrl does this);",
        "       then force = kp (q_ref - q) + kv (qdot_ref - qdot). -->",
        "  <actuator>",
        *acts,
        "  </actuator>",
        "  <keyframe>",
        "    <!-- RSRD YUMI_REST_POSE (URDF order) - both TCPs at (0.5, -/+0.2, 0.133), pointing down. -->",
        f'    <key name="home" qpos="{fmt(qpos, 9)}" ctrl="{fmt(ctrl, 9)}"/>',
        "  </keyframe>",
        "</mujoco>",
    ]
    return "\n".join(out) + "\n"


if __name__ == "__main__":
    (HERE / "yumi.xml").write_text(generate())
    print("wrote", HERE / "yumi.xml")
