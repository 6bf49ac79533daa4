"""Outputs of a simulated execution: sim.json (stages, metrics), sim.npz (recorded states),
sim.mp4 (robot-view video) and sim.rrd (rerun recording of robot + object over time)."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from ..io import atomic_write_json, atomic_write_npz, write_video
from ._config import SimConfig
from ._execute import PHASES, SimResult
from ._scene import SimObject, build_sim_scene, load_sim_object


def save_sim_result(result: SimResult, out_dir: str | Path, fps: float = 30.0) -> dict[str, Path]:
    """Writes ``sim.json`` (``result.to_json()``), ``sim.npz`` (time, phase, robot_q, object_qpos,
    part_poses, tcp_poses, pad_contact) and, when frames were recorded, ``sim.mp4`` into
    ``out_dir``, each atomically.

    Returns:
        {"json": path, "npz": path[, "mp4": path]}.
    """
    out = Path(out_dir)
    paths = {"json": atomic_write_json(out / "sim.json", dict(result.to_json(), phases=list(PHASES)))}
    paths["npz"] = atomic_write_npz(
        out / "sim.npz", time=result.time, phase=result.phase, robot_q=result.robot_q,
        object_qpos=result.object_qpos, part_poses=result.part_poses, tcp_poses=result.tcp_poses,
        pad_contact=result.pad_contact,
    )  # fmt: skip
    if result.frames is not None and len(result.frames):
        paths["mp4"] = write_video(out / "sim.mp4", result.frames, fps)
    return paths


def _geom_archetype(rr, m: mujoco.MjModel, g: int, color):
    t, s = int(m.geom_type[g]), m.geom_size[g]
    T = mujoco.mjtGeom
    if t == T.mjGEOM_BOX:
        return rr.Boxes3D(half_sizes=[s], colors=[color], fill_mode="solid")
    if t == T.mjGEOM_SPHERE:
        return rr.Ellipsoids3D(half_sizes=[[s[0]] * 3], colors=[color], fill_mode="solid")
    if t == T.mjGEOM_ELLIPSOID:
        return rr.Ellipsoids3D(half_sizes=[s], colors=[color], fill_mode="solid")
    if t == T.mjGEOM_CAPSULE:
        return rr.Capsules3D(lengths=[2 * s[1]], radii=[s[0]], translations=[[0, 0, -s[1]]], colors=[color])
    if t == T.mjGEOM_CYLINDER:
        return rr.Cylinders3D(lengths=[2 * s[1]], radii=[s[0]], colors=[color], fill_mode="solid")
    return None


def log_sim_rerun(
    result: SimResult,
    obj: SimObject | str | Path,
    rrd_path: str | Path,
    config: SimConfig = SimConfig(),
    T_robot_root: np.ndarray | None = None,
) -> Path:
    """Rerun recording of a simulated execution: robot (visual geoms), table and object as 3D
    shapes over simulated time (replayed from the recorded joints with MuJoCo kinematics), the
    object's joint values and finger contacts as scalars, and the video frames if recorded.

    Args:
        result: from :func:`simulate_plan` (executed).
        obj, config, T_robot_root: the same as given to :func:`simulate_plan` (to rebuild the scene).
        rrd_path: output ``.rrd`` (written atomically).
    """
    import rerun as rr

    if not isinstance(obj, SimObject):
        obj = load_sim_object(obj)
    scene = build_sim_scene(obj, config, T_robot_root)
    m, d = scene.model, scene.data
    oq = scene.object_qpos_adr()
    part_of = {int(g): k for k, gs in enumerate(scene.part_geoms) for g in gs}
    palette = np.array([[230, 80, 60], [60, 120, 230], [80, 190, 90], [230, 180, 40], [170, 90, 200], [60, 200, 200]])
    geoms = []
    for g in range(m.ngeom):
        if g in part_of:
            color = palette[part_of[g] % len(palette)]
        elif m.geom_group[g] in (0, 1) and m.geom_rgba[g, 3] > 0:
            color = (np.clip(m.geom_rgba[g, :3], 0, 1) * 255).astype(int)
        else:
            continue
        geoms.append((g, color))
    rrd_path = Path(rrd_path)
    rrd_path.parent.mkdir(parents=True, exist_ok=True)
    tmp = rrd_path.with_name(f".{rrd_path.name}.tmp")
    rec = rr.RecordingStream("rsrd_jax_sim")
    rec.save(str(tmp))
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    names = {}
    for g, color in geoms:
        arch = _geom_archetype(rr, m, g, color)
        if arch is not None:
            name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or f"g{g}"
            names[g] = f"world/geoms/{name.replace('/', '_')}"
            rec.log(names[g], arch, static=True)
    for i in range(len(result.time)):
        rec.set_time("sim_time", duration=float(result.time[i]))
        d.qpos[scene.robot_qpos] = result.robot_q[i]
        d.qpos[scene.mimic_qpos] = result.robot_q[i, 14:16]
        d.qpos[oq] = result.object_qpos[i]
        mujoco.mj_kinematics(m, d)
        for g, path in names.items():
            rec.log(path, rr.Transform3D(translation=d.geom_xpos[g], mat3x3=d.geom_xmat[g].reshape(3, 3)))
        for j, v in enumerate(result.object_qpos[i]):
            rec.log(f"object_qpos/{j}", rr.Scalars(float(v)))
        rec.log("phase", rr.TextLog(PHASES[int(result.phase[i])]))
        rec.log("pads_on_part", rr.Scalars(float(result.pad_contact[i].sum())))
        if result.frames is not None and i < len(result.frames):
            rec.log("camera/image", rr.Image(result.frames[i]).compress())
    rec.flush()
    del rec
    tmp.replace(rrd_path)
    return rrd_path
