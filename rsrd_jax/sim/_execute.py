"""Executes a RobotPlan in MuJoCo C and scores it per stage (RSRD Table 1: Init, Traj, Grasp, Exec).

Sequence (position servos track a time-scaled joint reference; ``servo_ctrl`` feed-forward):
settle at home → transit home → pre-grasp (smooth point-to-point) → approach (pre-grasp → grasp,
grippers opened as the plan's approach says) → close the active grippers until the fingers stall,
each arm yielding along its jaw axis to the fingers' net force (compliant seating,
``SimConfig.seat_max_shift``) → follow ``q_video`` with the seating shift kept in the TCP frame
(piecewise linear, time-scaled so no arm joint exceeds ``joint_speed``) → open (further while a pad still
feels its part, ``SimConfig.release_step``) → retreat along
−TCP z → settle. The object is simulated with its real joints; nothing is welded to the gripper,
so a part moves only through finger contacts and friction.
"""

from __future__ import annotations

import time
from pathlib import Path

import equinox as eqx
import mujoco
import numpy as np
from tqdm.auto import tqdm

from ..io import ArtefactError
from ..robot import HOME_Q, VELOCITY_LIMIT
from ._config import SimConfig
from ._ik import tcp_ik
from ._scene import SimObject, SimScene, _mat, _vec, build_sim_scene, load_sim_object

STAGE_NAMES = ("init", "traj", "grasp", "exec")
"""Stages in the paper's order (Table 1); ``init`` (registration) is filled in by the caller."""
PHASES = ("settle", "transit", "approach", "close", "motion", "release", "retreat", "hold")
"""Execution phases, in order (``SimResult.phase`` indexes this)."""


class SimOutcome(eqx.Enumeration):
    """First stage that failed (or success)."""

    success = "every stage succeeded"
    init = "registration error above the thresholds"
    traj = "no feasible plan (not executed)"
    grasp = "the gripper did not hold the intended part when the motion started, or it slipped"
    exec = "the object did not end in the demonstration's final configuration, or moved differently"


class SimResult(eqx.Module):
    """Outcome of :func:`simulate_plan` (host numpy). N recorded states at ``config.fps``."""

    outcome: SimOutcome
    """First failed stage (or success)."""
    stages: dict = eqx.field(static=True)
    """{stage: True/False/None} for init, traj, grasp, exec (None = not evaluated)."""
    reasons: dict = eqx.field(static=True)
    """{stage: human-readable reason} for every evaluated stage."""
    metrics: dict = eqx.field(static=True)
    """JSON-able numbers: slip, contacts, final/path errors per part, base displacement,
    simulated and wall time, real-time factor."""
    executed: bool = eqx.field(static=True)
    """False when the plan was not run (failed or colliding plan)."""
    time: np.ndarray
    """(N,) simulated time of each record (s)."""
    phase: np.ndarray
    """(N,) index into ``PHASES``."""
    robot_q: np.ndarray
    """(N, 16) robot joints (JOINT_NAMES order)."""
    object_qpos: np.ndarray
    """(N, nq_obj) object joint positions (free joints as xyz + wxyz)."""
    part_poses: np.ndarray
    """(N, P, 7) part poses in the robot base frame (wxyz_xyz)."""
    tcp_poses: np.ndarray
    """(N, 2, 7) TCP poses in the robot base frame."""
    pad_contact: np.ndarray
    """(N, 2, 2) finger pad (arm, finger) touches the arm's intended part."""
    frames: np.ndarray | None
    """(F, H, W, 3) uint8 robot-view video frames, or None."""

    @property
    def success(self) -> bool:
        """All evaluated stages succeeded."""
        return bool(self.outcome == SimOutcome.success)

    @property
    def outcome_name(self) -> str:
        """Name of ``outcome`` ("success", "traj", "grasp", "exec", "init")."""
        for name, item in SimOutcome._name_to_item.items():
            if bool(item == self.outcome):
                return name
        raise ValueError(f"unknown SimOutcome {self.outcome!r}")

    def to_json(self) -> dict:
        """The JSON-able summary written to ``sim.json``."""
        return {"format": SIM_FORMAT, "outcome": self.outcome_name, "success": self.success,
                "executed": self.executed, "stages": self.stages, "reasons": self.reasons,
                "metrics": self.metrics}  # fmt: skip


SIM_FORMAT = "rsrd_jax.sim/1"


def _first_failure(stages: dict) -> SimOutcome:
    for s in STAGE_NAMES:
        if stages.get(s) is False:
            return getattr(SimOutcome, s)
    return SimOutcome.success


def with_init(result: SimResult, ok: bool, reason: str, **metrics) -> SimResult:
    """``result`` with the Init stage (registration, evaluated by the caller) filled in.

    Args:
        ok: registration error below the caller's thresholds.
        reason: e.g. "rotation error 3.1° ≤ 10°, translation 4 mm ≤ 20 mm".
        metrics: extra numbers stored under ``metrics["init"]``.
    """
    stages = dict(result.stages, init=bool(ok))
    reasons = dict(result.reasons, init=reason)
    m = dict(result.metrics, init=metrics) if metrics else dict(result.metrics)
    return SimResult(
        outcome=_first_failure(stages), stages=stages, reasons=reasons, metrics=m, executed=result.executed,
        time=result.time, phase=result.phase, robot_q=result.robot_q, object_qpos=result.object_qpos,
        part_poses=result.part_poses, tcp_poses=result.tcp_poses, pad_contact=result.pad_contact,
        frames=result.frames,
    )  # fmt: skip


def stage_summary(results) -> dict:
    """Paper Table 1 counts over trials: each stage's successes out of the trials that reached it.

    Args:
        results: SimResults or their ``to_json()`` dicts (``sim.json``). A stage that was not
            evaluated (None; e.g. Init without registration) counts as passed.

    Returns:
        {"trials": n, "<stage>": {"ok": k, "of": m, "rate": k / m}, ..., "end_to_end": {...}}.
    """
    out: dict = {"trials": 0}
    n = 0
    for s in STAGE_NAMES:
        out[s] = {"ok": 0, "of": 0}
    for r in results:
        st = r.stages if isinstance(r, SimResult) else r["stages"]
        n += 1
        for s in STAGE_NAMES:
            out[s]["of"] += 1
            if st.get(s) is False:
                break
            out[s]["ok"] += 1
    out["trials"] = n
    ok = out[STAGE_NAMES[-1]]["ok"]
    out["end_to_end"] = {"ok": ok, "of": n}
    for k in (*STAGE_NAMES, "end_to_end"):
        out[k]["rate"] = out[k]["ok"] / out[k]["of"] if out[k]["of"] else float("nan")
    return out


def _plan_fields(plan) -> tuple[bool, str, str]:
    name = getattr(plan, "result_name", None) or str(plan.result)
    return bool(plan.success), name, str(getattr(plan, "message", ""))


def _validate(plan, obj: SimObject) -> None:
    for f in ("q_video", "q_approach", "active", "part", "min_distance"):
        if not hasattr(plan, f):
            raise ValueError(f"plan has no field {f!r} (expected a RobotPlan or rsrd_jax.io.PlanArtefact)")
    ok, _, _ = _plan_fields(plan)
    if not ok:
        return
    qv, qa = np.asarray(plan.q_video), np.asarray(plan.q_approach)
    if qv.ndim != 2 or qv.shape[1] != 16 or len(qv) < 1 or qa.ndim != 2 or qa.shape[1] != 16 or len(qa) < 1:
        raise ValueError(f"plan: q_video {qv.shape} and q_approach {qa.shape} must be (n ≥ 1, 16)")
    if not (np.all(np.isfinite(qv)) and np.all(np.isfinite(qa))):
        raise ValueError("plan: q_video / q_approach contain non-finite joints")
    T = obj.T_obj_part_demo.shape[0]
    if len(qv) != T:
        raise ArtefactError(f"plan q_video has {len(qv)} frames but the demo of {obj.name!r} "
                            f"({obj.directory}) has {T}: the plan is for another demo")  # fmt: skip
    n_plan = (getattr(plan, "info", None) or {}).get("num_parts")
    if n_plan is not None and int(n_plan) != obj.num_parts:
        raise ArtefactError(f"plan was made for a {n_plan}-part object model but {obj.name!r} has "
                            f"{obj.num_parts} parts: the plan is for another object model")  # fmt: skip
    active, part = np.asarray(plan.active, bool), np.asarray(plan.part, int)
    if not active.any():
        raise ValueError("plan: no active arm")
    for a in np.flatnonzero(active):
        if not 0 <= part[a] < obj.num_parts:
            raise ArtefactError(f"plan: arm {a} grasps part {part[a]} but {obj.name!r} has {obj.num_parts} "
                                f"parts: the plan is for another object model")  # fmt: skip


def _angle(R: np.ndarray) -> float:
    return float(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0)))


def _pose_err(A: np.ndarray, B: np.ndarray) -> tuple[float, float]:
    return float(np.linalg.norm(A[:3, 3] - B[:3, 3])), _angle(A[:3, :3].T @ B[:3, :3])


def sim_progress(estimate_s: float, desc: str, **kw) -> tqdm:
    """Progress bar over simulated seconds (``estimate_s`` the expected total; see :func:`advance`)."""
    return tqdm(total=round(float(estimate_s), 2), unit="sim s", desc=desc, leave=False,
                bar_format="{l_bar}{bar}| {n:.1f}/{total:.1f} sim s [{elapsed}]", **kw)  # fmt: skip


def advance(pbar: tqdm, dt: float) -> None:
    """Advance a :func:`sim_progress` bar by ``dt`` simulated seconds, raising its total when the
    run outlasts the estimate (tqdm drops a total that ``n`` passes, and the bar's format then
    fails: four of session 46's scissors trials crashed in simulation that way)."""
    if pbar.total is not None and pbar.n + dt > pbar.total:
        pbar.total = pbar.n + dt
    pbar.update(dt)


class _Runner:
    """Steps the scene along reference segments, records states."""

    def __init__(self, scene: SimScene, plan, config: SimConfig, video: bool, pbar):
        self.s, self.cfg, self.m, self.d = scene, config, scene.model, scene.data
        self.active = np.asarray(plan.active, bool)
        self.part = np.asarray(plan.part, int)
        self.grip = np.array([HOME_Q[14], HOME_Q[15]])
        self.rec: dict[str, list] = {k: [] for k in ("time", "phase", "q", "oq", "parts", "tcp", "pads")}
        self.frames: list | None = [] if video else None
        self.renderer = mujoco.Renderer(self.m, config.video_size[1], config.video_size[0]) if video else None
        if self.renderer is not None:  # shadows and reflections cost ~100x on llvmpipe
            self.renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
            self.renderer.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
        self.next_rec = 0.0
        self.phase = 0
        self.pbar = pbar
        self.n_steps = 0
        self.oq = scene.object_qpos_adr()
        gid2part = np.full(self.m.ngeom, -1)
        for k, g in enumerate(scene.part_geoms):
            gid2part[g] = k
        self.gid2part = gid2part
        self.samples: list = []  # (index, part poses) at the motion's video-frame waypoints
        self.robot_object_contacts = 0
        # geoms of each gripper's two finger bodies: what a wrist force sensor feels
        pad_bodies = self.m.geom_bodyid[scene.pad_geoms]
        self.finger_geoms = [set(np.flatnonzero(np.isin(self.m.geom_bodyid, pad_bodies[a])).tolist()) for a in range(2)]
        self.scratch = mujoco.MjData(self.m)

    def close(self):
        if self.renderer is not None:
            self.renderer.close()

    def pad_contacts(self) -> np.ndarray:
        """(2, 2) pad touches its arm's intended part."""
        out = np.zeros((2, 2), bool)
        d, pads = self.d, self.s.pad_geoms
        for c in d.contact[: d.ncon]:
            for g, h in ((c.geom1, c.geom2), (c.geom2, c.geom1)):
                hit = np.argwhere(pads == g)
                if len(hit) and self.gid2part[h] >= 0:
                    a, f = hit[0]
                    if self.gid2part[h] == self.part[a]:
                        out[a, f] = True
        return out

    def pad_gaps(self, a: int | np.integer) -> np.ndarray:
        """(2,) distance (m) of arm ``a``'s two finger pads to its intended part (negative =
        penetration; 0.05 when farther than that)."""
        m, d, s = self.m, self.d, self.s
        return np.array([min(mujoco.mj_geomDistance(m, d, int(s.pad_geoms[a, f]), int(h), 0.05, None)
                             for h in s.part_geoms[self.part[a]]) for f in range(2)])  # fmt: skip

    def pad_outward(self, a: int | np.integer, f: int) -> np.ndarray:
        """(3,) world direction in which finger pad ``f`` of arm ``a`` moves as the jaw opens
        (± the TCP's x axis, away from the TCP)."""
        d, s = self.d, self.s
        x = d.site_xmat[s.tcp_sites[a]].reshape(3, 3)[:, 0]
        return np.sign((d.geom_xpos[s.pad_geoms[a, f]] - d.site_xpos[s.tcp_sites[a]]) @ x) * x

    def part_side(self, a: int | np.integer, f: int) -> float:
        """Which side of finger pad ``f`` of arm ``a`` its intended part's nearest surface lies on,
        along the pad's outward direction (``pad_outward``): negative inward (the side the pad
        holds the part from), positive outward; 0 when the part is farther than 0.05 m."""
        m, d, s = self.m, self.d, self.s
        g, fromto, best, side = int(s.pad_geoms[a, f]), np.zeros(6), 0.05, 0.0
        for h in s.part_geoms[self.part[a]]:
            dist = mujoco.mj_geomDistance(m, d, g, int(h), 0.05, fromto)
            if dist < best:
                # from the pad's point to the part's; penetrating geoms report the two points the
                # other way round (each inside the other geom)
                v = (fromto[3:] - fromto[:3]) * (1.0 if dist > 0.0 else -1.0)
                best, side = dist, float(v @ self.pad_outward(a, f))
        return side

    def pads_room(self, a: int | np.integer, reach: float) -> np.ndarray:
        """(2,) free distance (m) of each finger pad of arm ``a`` on its outer side, where the pad
        moves as the jaw opens: the distance to the nearest object surface lying outward of the
        pad's centre (a pad in a ring's hole before the far wall, a lower pad between a lid and its
        box), ``reach`` when none is nearer."""
        m, d, s = self.m, self.d, self.s
        fromto, out = np.zeros(6), np.full(2, float(reach))
        for f in range(2):
            g = int(s.pad_geoms[a, f])
            away = self.pad_outward(a, f)
            for h in np.concatenate(s.part_geoms):
                dist = mujoco.mj_geomDistance(m, d, g, int(h), reach, fromto)
                if dist < out[f] and (fromto[3:] - d.geom_xpos[g]) @ away > 0.0:
                    out[f] = dist
        return out

    def jaw_force(self, a: int | np.integer) -> float:
        """Net contact force (N) on arm ``a``'s fingers along its jaw axis (TCP x)."""
        d, f6, F = self.d, np.zeros(6), np.zeros(3)
        geoms = self.finger_geoms[a]
        for i in range(d.ncon):
            c = d.contact[i]
            on1, on2 = c.geom1 in geoms, c.geom2 in geoms
            if on1 == on2:  # not this gripper, or finger on finger
                continue
            mujoco.mj_contactForce(self.m, d, i, f6)
            f = c.frame.reshape(3, 3).T @ f6[:3]  # the force on geom2, in the world
            F += f if on2 else -f
        return float(F @ d.site_xmat[self.s.tcp_sites[a]].reshape(3, 3)[:, 0])

    def shifted(self, q: np.ndarray, shift: np.ndarray) -> np.ndarray:
        """``q`` with each arm's TCP moved by ``shift[a]`` (m) along its own x (jaw) axis, its
        orientation kept (IK from ``q``)."""
        s, out = self.s, np.asarray(q, float).copy()
        for a in np.flatnonzero(shift != 0.0):
            self.scratch.qpos[s.robot_qpos] = out
            mujoco.mj_kinematics(self.m, self.scratch)
            T = np.eye(4)
            T[:3, :3] = self.scratch.site_xmat[s.tcp_sites[a]].reshape(3, 3)
            T[:3, 3] = self.scratch.site_xpos[s.tcp_sites[a]] + shift[a] * T[:3, 0]
            out, _, _ = tcp_ik(self.m, self.scratch, s.robot_qpos, s.robot_dof, s.tcp_sites[a], a, out, T)
        return out

    def close_grippers(self, q: np.ndarray, arms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Closes the active grippers at ``q`` until the fingers stall, with compliant seating
        (``SimConfig.seat_max_shift``). Returns (per-arm jaw-axis shift (2,) in m, the shifted q)."""
        cfg, dt = self.cfg, self.m.opt.timestep
        fingers = self.s.robot_dof[14 + arms]
        shift, q_ref, block = np.zeros(2), q, 5
        self.grip[arms] = 0.0
        t0 = self.d.time
        while self.d.time - t0 < cfg.grip_timeout:
            if cfg.seat_max_shift > 0:
                for a in arms:
                    v = cfg.seat_speed * np.tanh(self.jaw_force(a) / cfg.seat_force)
                    shift[a] = np.clip(shift[a] + v * block * dt, -cfg.seat_max_shift, cfg.seat_max_shift)
                q_ref = self.shifted(q, shift)
            for _ in range(block):
                self.step(q_ref, np.zeros(16))
            if self.d.time - t0 < 0.15 or np.any(np.abs(self.d.qvel[fingers]) >= cfg.grip_stall_speed):
                continue
            if cfg.seat_max_shift <= 0 or all(abs(self.jaw_force(a)) < 0.25 * cfg.seat_force
                                              or abs(shift[a]) >= cfg.seat_max_shift for a in arms):  # fmt: skip
                break
        self.hold(q_ref, 0.1)
        return shift, q_ref

    def record(self):
        s, d = self.s, self.d
        self.rec["time"].append(d.time)
        self.rec["phase"].append(self.phase)
        self.rec["q"].append(s.robot_q())
        self.rec["oq"].append(d.qpos[self.oq].copy())
        self.rec["parts"].append(np.stack([_vec(T) for T in s.part_poses()]))
        self.rec["tcp"].append(np.stack([_vec(T) for T in s.tcp_poses()]))
        self.rec["pads"].append(self.pad_contacts())
        if self.renderer is not None:
            self.renderer.update_scene(d, camera=s.camera)
            self.frames.append(self.renderer.render().copy())

    def step(self, q_ref: np.ndarray, qdot_ref: np.ndarray):
        q_ref = q_ref.copy()
        q_ref[14:16] = self.grip
        qdot_ref = qdot_ref.copy()
        qdot_ref[14:16] = 0.0
        self.s.servo_ctrl(q_ref, qdot_ref)
        mujoco.mj_step(self.m, self.d)
        if self.d.time >= self.next_rec - 1e-9:
            self.record()
            self.next_rec += 1.0 / self.cfg.fps
        self.n_steps += 1
        if self.pbar is not None and self.n_steps % 50 == 0:
            advance(self.pbar, 50 * self.m.opt.timestep)

    def hold(self, q: np.ndarray, duration: float, until=None, min_time: float = 0.0):
        t0 = self.d.time
        while self.d.time - t0 < duration:
            self.step(q, np.zeros(16))
            if until is not None and self.d.time - t0 >= min_time and until():
                break

    def move(self, q0: np.ndarray, q1: np.ndarray, min_duration: float = 0.3):
        """Smooth point-to-point move (smoothstep profile, peak joint speed ≤ joint_speed)."""
        dq = q1 - q0
        D = max(min_duration, 1.5 * np.max(np.abs(dq[:14])) / self.cfg.joint_speed)
        if D <= 0.0:
            return
        t0 = self.d.time
        while (tau := (self.d.time - t0) / D) < 1.0:
            s, sd = tau * tau * (3 - 2 * tau), 6 * tau * (1 - tau) / D
            self.step(q0 + s * dq, sd * dq)
        self.step(q1, np.zeros(16))

    def path(self, Q: np.ndarray, sample: bool = False):
        """Piecewise-linear path through waypoints Q (n, 16), time-scaled; optionally samples part
        poses when each waypoint's time is reached (for the path-following test)."""
        dt = np.maximum(self.cfg.min_frame_time, np.max(np.abs(np.diff(Q[:, :14], axis=0)), axis=1) / self.cfg.joint_speed)
        t_way = np.concatenate([[0.0], np.cumsum(dt)])
        t0 = self.d.time
        i = 0
        if sample:
            self.samples.append(self.s.part_poses())
        while True:
            t = self.d.time - t0
            while i < len(dt) and t >= t_way[i + 1]:
                i += 1
                if sample:
                    self.samples.append(self.s.part_poses())
            if i >= len(dt):
                break
            u = (t - t_way[i]) / dt[i]
            self.step(Q[i] + u * (Q[i + 1] - Q[i]), (Q[i + 1] - Q[i]) / dt[i])
        self.step(Q[-1], np.zeros(16))


def _finish(stages, reasons, metrics, executed, run: _Runner | None, P, nq) -> SimResult:
    if run is None or not run.rec["time"]:
        z = np.zeros(0)
        return SimResult(outcome=_first_failure(stages), stages=stages, reasons=reasons, metrics=metrics,
                         executed=executed, time=z, phase=np.zeros(0, int), robot_q=np.zeros((0, 16)),
                         object_qpos=np.zeros((0, nq)), part_poses=np.zeros((0, P, 7)), tcp_poses=np.zeros((0, 2, 7)),
                         pad_contact=np.zeros((0, 2, 2), bool), frames=None)  # fmt: skip
    r = run.rec
    return SimResult(
        outcome=_first_failure(stages), stages=stages, reasons=reasons, metrics=metrics, executed=executed,
        time=np.asarray(r["time"]), phase=np.asarray(r["phase"], int), robot_q=np.stack(r["q"]),
        object_qpos=np.stack(r["oq"]), part_poses=np.stack(r["parts"]), tcp_poses=np.stack(r["tcp"]),
        pad_contact=np.stack(r["pads"]), frames=np.stack(run.frames) if run.frames else None,
    )  # fmt: skip


def simulate_plan(
    plan,
    obj: SimObject | str | Path,
    config: SimConfig = SimConfig(),
    T_robot_root: np.ndarray | None = None,
    video: bool = False,
    progress: bool = True,
) -> SimResult:
    """Executes a plan on the simulated YuMi with the studio object and scores each stage.

    Stages (RSRD Table 1):
      * **Traj**: the plan succeeded (``plan.success``) and does not collide
        (``min_distance`` ≥ 0 where known). Otherwise it is reported and *not* executed.
      * **Grasp**: when the motion starts (after the close and its compliant seating), both
        finger pads of every active arm touch the arm's intended part (contacts with that part's
        geoms; one may be within ``success.pad_gap``), the transit/approach did not disturb the
        object (``disturbance_tolerance``), and while held the part does not slip relative to the
        TCP beyond ``success.slip_position`` / ``slip_rotation_deg``.
      * **Exec**: after release and retreat every part's pose relative to the root matches the
        demo's final ``T_obj_part`` (``final_position`` / ``final_rotation_deg``), every part
        the demo moves stayed near the demo's pose at each video frame while the plan was followed
        (``path_position`` / ``path_rotation_deg``), i.e. it moved the same way, and the root was
        not knocked away or over (``base_position`` / ``base_rotation_deg``).
      * **Init** is the caller's (registration); see :func:`with_init`.

    Args:
        plan: a :class:`rsrd_jax.plan.RobotPlan` or :class:`rsrd_jax.io.PlanArtefact`.
        obj: a :class:`SimObject` or a studio directory (``rsrd_jax.studio.make_object`` output).
        config: physics, timing, recording and success thresholds.
        T_robot_root: (7,) where the object really is (default: the studio's true pose); the plan
            keeps whatever pose it was planned for.
        video: record robot-view RGB frames at ``config.fps`` (``SimResult.frames``).
        progress: show a progress bar over simulated time.

    Returns:
        :class:`SimResult` (stage results, reasons, metrics and the recorded states).

    Raises:
        ArtefactError / ValueError: a missing studio file, or a plan for another object/demo.
    """
    if not isinstance(obj, SimObject):
        obj = load_sim_object(obj)
    _validate(plan, obj)
    P = obj.num_parts
    cfg, sc = config, config.success
    ok, result_name, message = _plan_fields(plan)
    stages: dict = {s: None for s in STAGE_NAMES}
    reasons: dict = {}
    metrics: dict = {"plan_result": result_name}
    if not ok:
        stages["traj"] = False
        reasons["traj"] = f"plan failed ({result_name}): {message}; not executed"
        return _finish(stages, reasons, metrics, False, None, P, 0)
    md = np.asarray(plan.min_distance, float)
    if np.any(md[np.isfinite(md)] < 0):
        stages["traj"] = False
        reasons["traj"] = f"plan collides (min self/table/object distance {md.round(4).tolist()} m); not executed"
        return _finish(stages, reasons, metrics, False, None, P, 0)
    stages["traj"] = True
    reasons["traj"] = f"plan {result_name}: {message}"

    wall0 = time.perf_counter()
    scene = build_sim_scene(obj, cfg, T_robot_root)
    setup_s = time.perf_counter() - wall0
    m, d = scene.model, scene.data
    active, part = np.asarray(plan.active, bool), np.asarray(plan.part, int)
    arms = np.flatnonzero(active)
    qv, qa = np.asarray(plan.q_video, float).copy(), np.asarray(plan.q_approach, float).copy()
    # the approach's finger opening comes from the plan (its gripper columns; fully open for idle
    # arms or when the plan leaves them unset); the follow phase's are driven by the grip
    open_q = np.where(active & np.isfinite(qa[0, 14:16]), np.clip(qa[0, 14:16], 0.0, HOME_Q[14:16]), HOME_Q[14:16])
    qv[:, 14:16] = qa[:, 14:16] = open_q
    if cfg.start not in ("pregrasp", "home"):
        raise ValueError(f"config.start must be 'pregrasp' or 'home', got {cfg.start!r}")
    q_start = qa[0] if cfg.start == "pregrasp" else HOME_Q
    # a rough total for the progress bar
    est = (2 * cfg.settle_time + cfg.grip_timeout + 1.5 * np.abs(qa[0, :14] - q_start[:14]).max() / cfg.joint_speed
           + np.sum(np.maximum(cfg.min_frame_time, np.abs(np.diff(np.concatenate([qa, qv]), axis=0)[:, :14]).max(1)
                               / cfg.joint_speed)) + 2.0)  # fmt: skip
    pbar = sim_progress(est, f"simulate {obj.name}") if progress else None
    d.qpos[scene.robot_qpos] = q_start
    d.qpos[scene.mimic_qpos] = q_start[14:16]
    mujoco.mj_forward(m, d)
    geoms_start = d.geom_xpos[np.concatenate(scene.part_geoms)].copy()
    run = _Runner(scene, plan, cfg, video, pbar)
    run.grip = open_q.copy()
    try:
        # settle, transit to pre-grasp (from home only), approach with the plan's finger opening
        run.phase = 0
        run.hold(q_start, cfg.settle_time)
        run.phase = 1
        run.move(q_start, qa[0], min_duration=0.0 if cfg.start == "pregrasp" else 0.3)
        run.phase = 2
        run.path(qa)
        disturbed = float(np.linalg.norm(d.geom_xpos[np.concatenate(scene.part_geoms)] - geoms_start, axis=1).max())
        # close the active grippers until the fingers stall
        run.phase = 3
        shift, q_seated = run.close_grippers(qa[-1], arms)
        grip_width = 2 * d.qpos[scene.robot_qpos[14 + arms]]
        pads0 = run.pad_contacts()
        # gap of each pad to the arm's intended part (negative = penetration)
        gaps = {a: run.pad_gaps(a).tolist() for a in arms}
        T_tcp0, T_part0 = scene.tcp_poses(), scene.part_poses()
        rel0 = {a: np.linalg.inv(T_part0[part[a]]) @ T_tcp0[a] for a in arms}
        # follow the plan
        run.phase = 4
        n_before = len(run.rec["time"])
        if np.any(shift != 0.0):  # keep the seating shift, in the TCP frame, along the motion
            qv = np.stack([run.shifted(q, shift) for q in qv])
        run.path(np.concatenate([q_seated[None], qv]), sample=True)
        n_motion = (n_before, len(run.rec["time"]))
        T_end_motion = scene.part_poses()
        # release, retreat, settle
        run.phase = 5
        release_steps, sided_steps, release_shift = np.zeros(2, int), np.zeros(2, int), np.zeros(2)
        # open by release_clearance, then by release_step while a pad is still at the part (it may
        # rest on the lower pad); a sided release moves each finger only into free space (the arm
        # shifts along the jaw axis when one finger opens more than the other)
        run.grip[arms] = d.qpos[scene.robot_qpos[14 + arms]]
        q_rel, first = qv[-1], True
        while first or cfg.release_step > 0:
            opening = []
            for a in arms:
                if run.grip[a] >= HOME_Q[14 + a] or (not first and run.pad_gaps(a).min() >= cfg.release_gap):
                    continue
                want = min(cfg.release_clearance if first else cfg.release_step, 2 * (HOME_Q[14 + a] - run.grip[a]))
                u = np.full(2, want / 2)  # each finger's travel
                if cfg.release_sided:
                    room = np.maximum(run.pads_room(a, want + cfg.release_gap) - cfg.release_gap, 0.0)
                    u = np.minimum(u, room)
                    u = np.minimum(room, u + (want - u.sum()) * (u < room))  # the other gives what one cannot
                    if first and u.sum() < 1e-4:  # neither has room: both push once (the grip must let go)
                        u = np.full(2, want / 2)
                    if u.sum() < 1e-4:
                        continue
                    if abs(u[0] - u[1]) > 1e-6:  # toward pad 1 when it opens more (shift: along TCP x)
                        sided_steps[a] += 1
                        x = d.site_xmat[scene.tcp_sites[a]].reshape(3, 3)[:, 0]
                        release_shift[a] += (run.pad_outward(a, 1) @ x) * (u[1] - u[0]) / 2
                run.grip[a] += u.sum() / 2
                release_steps[a] += 0 if first else 1
                opening.append(a)
            if not opening:
                break
            q_rel = run.shifted(qv[-1], release_shift) if np.any(release_shift != 0.0) else qv[-1]
            run.hold(q_rel, cfg.settle_time if first else cfg.release_settle)
            first = False
        # a part still resting on a pad once the opening has stopped (fully open, or no room to
        # open further; lifted by the motion, it followed the lower pad down as the jaw opened) is
        # set down: the arm moves along the jaw axis toward that pad's outer side, away from the
        # part, while the other pad keeps its distance and nothing is in the way
        lowered = np.zeros(2)
        step = min(cfg.release_step, cfg.release_lower)
        reach = step + cfg.release_gap
        while step > 0.0:
            lowering = False
            for a in arms:
                g = run.pad_gaps(a)
                f = int(np.argmin(g))
                if (g[f] >= cfg.release_gap or g[1 - f] < reach or lowered[a] + step > cfg.release_lower + 1e-9
                        or run.part_side(a, f) >= 0.0 or run.pads_room(a, reach)[f] < reach):  # fmt: skip
                    continue
                x = d.site_xmat[scene.tcp_sites[a]].reshape(3, 3)[:, 0]
                release_shift[a] += (run.pad_outward(a, f) @ x) * step
                lowered[a] += step
                lowering = True
            if not lowering:
                break
            q_rel = run.shifted(qv[-1], release_shift)
            run.hold(q_rel, cfg.release_settle)
        release_open = d.qpos[scene.robot_qpos[14:16]].copy()
        release_gaps = {a: run.pad_gaps(a) for a in arms}
        run.phase = 6
        q_ret = q_rel.copy()
        scratch = mujoco.MjData(m)
        for a in arms:
            T = scene.tcp_poses()[a]
            T[:3, 3] -= cfg.retreat_distance * T[:3, 2]
            scratch.qpos[:] = d.qpos
            q_ret, _, _ = tcp_ik(m, scratch, scene.robot_qpos, scene.robot_dof, scene.tcp_sites[a], a, q_ret, T)
        run.move(q_rel, q_ret)
        run.phase = 7
        run.hold(q_ret, cfg.settle_time)
        run.record()
    finally:
        run.close()
        if pbar is not None:
            pbar.close()
    wall = time.perf_counter() - wall0 - setup_s

    # ---------------- Grasp
    rec_parts = np.stack(run.rec["parts"])
    rec_tcp = np.stack(run.rec["tcp"])
    rec_pads = np.stack(run.rec["pads"])
    slip_p, slip_r, held = {}, {}, {}
    lo, hi = n_motion
    for a in arms:
        sp = sr = 0.0
        for i in range(lo, hi):
            rel = np.linalg.inv(_mat(rec_parts[i, part[a]])) @ _mat(rec_tcp[i, a])
            e_p, e_r = _pose_err(rel0[a], rel)
            sp, sr = max(sp, e_p), max(sr, e_r)
        slip_p[a], slip_r[a] = sp, sr
        held[a] = float(np.mean(rec_pads[lo:hi, a].all(-1))) if hi > lo else 0.0
    # a pinch: both pads at the part (one pressing, the other within pad_gap: the coupled jaw stalls
    # on the first finger when the part cannot shift sideways, e.g. a welded root or a hinge along
    # the jaw axis, and a slightly off-centre grasp leaves a gap at the other) with the jaw open
    # (shut fingers pressing on a surface with their tips touch it with both pads too)
    jaw = {a: float(w) for a, w in zip(arms, grip_width)}
    near = {a: np.array([pads0[a][f] or gaps[a][f] <= sc.pad_gap for f in range(2)]) for a in arms}
    touching = {a: bool(pads0[a].any() and near[a].all()) and jaw[a] >= sc.min_jaw for a in arms}
    why = []
    for a in arms:
        name = ("right", "left")[a]
        if not touching[a]:
            which = [f"{f} ({1000 * g:.1f} mm away)" for f, t, g in zip(("finger_r", "finger_l"), near[a], gaps[a])
                     if not t]  # fmt: skip
            what = f"{', '.join(which)} not touching part {part[a]}" if which else f"jaw shut on part {part[a]}"
            if not pads0[a].any() and not which:
                what = f"no pad touching part {part[a]}"
            why.append(f"{name} gripper: {what} when the motion starts (jaw {1000 * jaw[a]:.1f} mm)")
        elif slip_p[a] > sc.slip_position or slip_r[a] > np.deg2rad(sc.slip_rotation_deg):
            why.append(f"{name} gripper: part {part[a]} slipped {1000 * slip_p[a]:.1f} mm / "
                       f"{np.rad2deg(slip_r[a]):.1f}° (limits {1000 * sc.slip_position:.0f} mm / "
                       f"{sc.slip_rotation_deg:.0f}°)")  # fmt: skip
    if disturbed > cfg.disturbance_tolerance:
        why.insert(0, f"object disturbed by {1000 * disturbed:.1f} mm before the grasp (transit/approach contact)")
    stages["grasp"] = not why
    reasons["grasp"] = "; ".join(why) if why else (
        "pinch on the intended part(s); max slip " +
        ", ".join(f"{1000 * slip_p[a]:.1f} mm/{np.rad2deg(slip_r[a]):.1f}°" for a in arms))  # fmt: skip

    # ---------------- Exec
    T_fin = np.stack([_mat(x) for x in rec_parts[-1]])
    T_demo = np.stack([[_mat(x) for x in row] for row in obj.T_obj_part_demo])  # (T, P, 4, 4)
    root_rel = lambda Ts: np.linalg.inv(Ts[0])[None] @ Ts  # noqa: E731
    fin_rel, end_rel = root_rel(T_fin), root_rel(T_end_motion)
    # a free part (separable: usb_plug's plug) is still in the demonstrator's hand on the video's
    # last frame, in the air; released, it falls. It is scored where the motion ends, still held.
    free = [k for k in range(1, P) if m.body_jntnum[scene.part_bodies[k]] == 1
            and m.jnt_type[m.body_jntadr[scene.part_bodies[k]]] == mujoco.mjtJoint.mjJNT_FREE]  # fmt: skip
    final_err = [_pose_err((end_rel if k in free else fin_rel)[k], T_demo[-1, k]) for k in range(P)]
    def _moves(k: int) -> bool:
        errs = [_pose_err(T_demo[0, k], T_demo[t, k]) for t in range(len(T_demo))]
        return bool(max(e[0] for e in errs) > sc.moving_threshold or max(e[1] for e in errs) > np.deg2rad(3.0))

    moved = [k for k in range(1, P) if _moves(k)]
    samples = run.samples[1:]  # the first sample is the grasp pose before frame 0
    path_err = {}
    for k in moved:
        errs = [_pose_err(root_rel(S)[k], T_demo[t, k]) for t, S in enumerate(samples[: len(T_demo)])]
        path_err[k] = (max(e[0] for e in errs), max(e[1] for e in errs)) if errs else (np.inf, np.inf)
    why = []
    for k in range(1, P):
        e_p, e_r = final_err[k]
        if e_p > sc.final_position or e_r > np.deg2rad(sc.final_rotation_deg):
            when = " at the end of the motion (a free part, still held)" if k in free else ""
            why.append(f"part {k} ends{when} {1000 * e_p:.1f} mm / {np.rad2deg(e_r):.1f}° from the demo's final pose")
    for k, (e_p, e_r) in path_err.items():
        if e_p > sc.path_position or e_r > np.deg2rad(sc.path_rotation_deg):
            why.append(f"part {k} strays {1000 * e_p:.1f} mm / {np.rad2deg(e_r):.1f}° from the demo's path")
    T0 = np.stack([_mat(x) for x in rec_parts[0]])
    base_p, base_r = _pose_err(T0[0], T_fin[0])
    if base_p > sc.base_position or base_r > np.deg2rad(sc.base_rotation_deg):
        why.append(f"the object's base moved {1000 * base_p:.1f} mm / turned {np.rad2deg(base_r):.1f}° "
                   f"(limits {1000 * sc.base_position:.0f} mm / {sc.base_rotation_deg:.0f}°)")  # fmt: skip
    stages["exec"] = not why
    reasons["exec"] = "; ".join(why) if why else "every part within tolerance of the demo's final pose and path"
    end_err = [_pose_err(end_rel[k], T_demo[-1, k]) for k in range(P)]
    sim_t = float(d.time)
    metrics.update({
        "grasp": {"pads_touching": {("right", "left")[a]: pads0[a].tolist() for a in arms},
                  "pad_gap_mm": {("right", "left")[a]: [round(1000 * g, 2) for g in gaps[a]] for a in arms},
                  "jaw_mm": {("right", "left")[a]: round(1000 * float(w), 2) for a, w in zip(arms, grip_width)},
                  "slip_mm": {("right", "left")[a]: round(1000 * slip_p[a], 2) for a in arms},
                  "slip_deg": {("right", "left")[a]: round(float(np.rad2deg(slip_r[a])), 2) for a in arms},
                  "held_fraction": {("right", "left")[a]: round(held[a], 3) for a in arms},
                  "disturbance_mm": round(1000 * disturbed, 2),
                  "seat_shift_mm": {("right", "left")[a]: round(1000 * float(shift[a]), 2) for a in arms}},
        "release": {"jaw_mm": {("right", "left")[a]: round(2000 * float(release_open[a]), 2) for a in arms},
                    "further_openings": {("right", "left")[a]: int(release_steps[a]) for a in arms},
                    "sided_openings": {("right", "left")[a]: int(sided_steps[a]) for a in arms},
                    "shift_mm": {("right", "left")[a]: round(1000 * float(release_shift[a]), 2) for a in arms},
                    "lowered_mm": {("right", "left")[a]: round(1000 * float(lowered[a]), 2) for a in arms},
                    "pad_gap_mm": {("right", "left")[a]: [round(1000 * float(g), 2) for g in release_gaps[a]] for a in arms}},
        "exec": {"final_error_mm": [round(1000 * e[0], 2) for e in final_err],
                 "final_error_deg": [round(float(np.rad2deg(e[1])), 2) for e in final_err],
                 "moving_parts": moved,
                 "path_error_mm": {str(k): round(1000 * v[0], 2) for k, v in path_err.items()},
                 "path_error_deg": {str(k): round(float(np.rad2deg(v[1])), 2) for k, v in path_err.items()},
                 "end_of_motion_error_mm": [round(1000 * e[0], 2) for e in end_err],
                 "end_of_motion_error_deg": [round(float(np.rad2deg(e[1])), 2) for e in end_err]},
        "base_displacement_mm": round(1000 * base_p, 2),
        "base_rotation_deg": round(float(np.rad2deg(base_r)), 2),
        "root": scene.root, "root_note": scene.root_note,
        "sim_time_s": round(sim_t, 3), "wall_time_s": round(wall, 3), "setup_s": round(setup_s, 3),
        "realtime_factor": round(sim_t / max(wall, 1e-9), 2), "steps": int(round(sim_t / m.opt.timestep)),
    })  # fmt: skip
    return _finish(stages, reasons, metrics, True, run, P, len(run.oq))
