"""The whole pipeline on a studio object: scan → model → track → register → plan → simulate.

Used by `rsrd-jax demo` and `experiments/robot_trials.py`. Every stage reads the previous stage's
artefact from disk (as the separate CLI commands do) and writes its own under `out/`:

    out/studio/      scan, demo video, robot view, MJCF, ground truth (MuJoCo renders)
    out/contact_sheet.png, out/studio.rrd   what the studio made
    out/model/       ObjectModel (+ build.rrd)
    out/track/       PartTrajectory (+ overlay.mp4, track.rrd)
    out/register/    registration.json (estimate, error against the studio's ground truth)
    out/plan/        RobotPlan (+ plan.rrd)
    out/sim/         sim.json / sim.npz (+ sim.mp4, sim.rrd)
    out/summary.json stage results, metrics and times

Nothing downstream reads ground truth: tracking uses the studio's hand masks, 2D fingertips and
relative-depth oracle (labelled as oracles), planning uses hand keypoints given in the demo
camera's frame (the output a hand detector would give) moved into the object frame by the
*tracked* object pose, and the plan is made for the *registered* object pose while the
simulation places the object at its true pose. Ground truth is only read to score the stages.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from .io import atomic_write_json


@dataclasses.dataclass(frozen=True)
class PipelineConfig:
    """Sizes and options of the end-to-end run (defaults sized for ≤ 10 min on a 2-core CPU)."""

    seed: int = 0
    """Studio seed (textures, cameras, demo placement)."""
    scan_views: int = 16
    """Scan views."""
    scan_size: tuple[int, int] = (160, 120)
    """Scan image size (W, H)."""
    demo_frames: int | None = 30
    """Demo frames (None: the object's own 90–120)."""
    demo_size: tuple[int, int] = (320, 240)
    """Demo video size (W, H)."""
    robot_yaw_deg: float | None = None
    """Object yaw on the table (None: the studio's random yaw for the seed)."""
    fit_iterations: int = 400
    """3DGS iterations."""
    field_iterations: int = 300
    """Feature-field iterations."""
    max_gaussians: int = 6000
    """Gaussian capacity of the model."""
    track_steps: int = 50
    """Adam steps per tracked frame."""
    track_roi: int = 224
    """Tracking ROI crop side (pixels)."""
    track_joints: bool = True
    """Joint discovery in tracking (`TrackConfig.joints`): on 30-frame studio demos it took the
    stapler from 10.2 / 12.3 mm to 2.5 / 5.6 mm object-frame ADD."""
    track_lr_start: float = 0.01
    """Tracking's initial learning rate (`TrackConfig.lr_start`; RSRD's 5e-3 is the library
    default). One frame's Adam solve moves a part by at most about Σ lr (≈ 7° at 5e-3), and the
    30-frame demos compress a 90–120-frame motion, so fast parts fell behind. Measured with joint
    discovery, object-frame ADD per part: stapler 2.6 / 6.0 → 2.1 / 4.5 mm, red_box 2.4 / 10.2
    → 2.8 / 7.5, sunglasses 1.3 / 56.4 / 8.0 → 1.9 / 32.6 / 4.5, frog mean 6.9 → 7.1, nerf_gun
    3.3 / 17.8 → 2.8 / 20.8."""
    track_hinge_axes: bool = True
    """Hinge axes in joint discovery (`TrackConfig.hinge_axes`): a part with a joint point turns
    about a fitted axis instead of a ball joint, so a thin part cannot roll about its own length
    (session 24, `experiments/results/hinge_axes_s24.md`: scissors 7.85 → 4.66 mm, wire_cutter
    7.64 → 4.77; robot trials wire_cutter 10/10 (6/10 in session 22), frog
    6/10 (0/10 on the same build without))."""
    track_hinge_refine_deg: float | None = None
    """`TrackConfig.hinge_refine_deg`: the hinge axis turned from its candidate toward the first
    pass's motion by up to this angle (degrees); None keeps the candidate."""
    track_hands: bool = True
    """Tracking's hand term (`LossWeights.hand`) with the studio's 2D fingertips (an oracle for a
    2D hand detector, `track.StudioFingertips`): each hand's pinched part point follows the
    midpoint of its thumb and index tips."""
    track_hand_noise_px: float = 0.0
    """Gaussian pixel noise on the studio's fingertips (a detector's error)."""
    track_hand_depth: float = 0.2
    """Tracking's hand depth term (`LossWeights.hand_depth`; needs the hand term, the mono-depth
    oracle and the model's support plane): the held part's surface at the pinch point lies at the
    depth the mono-depth gives the hand, read off the table around the object. The studio
    usb_plug's plug, lifted towards the camera under the hand, was tracked back along its
    viewing ray (38.6 mm; 34.6 mm with RSRD's ARAP weight for separable objects,
    `TrackConfig.separable_arap`); with both 9.9 mm (robot trials' build). It acts on separable
    objects only (`TrackConfig.hand_depth_attached`): on the jointed nerf_gun it pulled the held
    slide off (4.22 -> 10.84 mm)."""
    track_motion: float = 0.1
    """Tracking's per-frame motion prior (`LossWeights.motion`; RSRD has none, the library
    default is 0): a part the data say little about stays where the extrapolation put it."""
    track_motion_separable: float = 3.0
    """Tracking's motion prior on separable objects (`TrackConfig.separable_motion`). Studio
    usb_plug (robot trials' build, the one separable studio object, so the value is fitted to
    it): object-frame ADD 11.35 mm at `track_motion` (0.1), 7.59 at 0.3, 5.81 at 1, 4.45 at 3,
    10.84 at 10 (the brick 1.7 mm, but the plug lags its pull: 20.0 mm)."""
    track_still_root: bool = True
    """`TrackConfig.still_root`: the root held at its frame-0 pose from the joint discovery's
    second pass on (the studio's camera is still and its roots never move; the first pass,
    which the joints are fitted from, tracks it freely: `TrackConfig.still_root_first`). See
    `track_slide_baseline`, which it needs, and README's tracking results (session 49)."""
    track_slide_baseline: str = "joint"
    """`TrackConfig.slide_baseline`. With the root held in the second pass the first pass, whose
    root moves freely, is no baseline for the slide hypotheses: "joint" compares them with a pass
    on the joint point that holds the root too (one pass more where a part has slide candidates).
    Session 48 (root held in the first pass as well): nerf_gun's slide lost to the first pass
    (9.58 mm), with "joint" it won (1.22 mm)."""
    init_iters: int = 80
    """Tracking initialisation iterations per seed."""
    plan_collision_margin: float = 0.003
    """Clearance (m) the plan must keep from the object along the trajectory and approach: the
    plan sees the registered pose (2–3 mm off) and alpha-shape part meshes, the simulation the
    true geometry. With 0 the stapler's approach brushed the arm (16.9 mm disturbance, Grasp
    failed); with 3 mm every stage passed."""
    plan_extent_meshes: bool = False
    """Build the grasp meshes from the Gaussians' extents (`ObjectModel.part_extent_points`)
    instead of their centres: the studio sunglasses' 4 mm arms have their centres on a sheet
    (no grasp fits it) and get grasps 2.2–3 mm wide this way. Off until measured over the robot
    trials; on the session-21 sunglasses trial alone the plan is found, but the arm turns 34° in
    the jaw (Grasp fails)."""
    plan_extent_fallback: bool = True
    """When no plan is found on the meshes of the Gaussian centres, plan again on those of their
    extents (as `plan_extent_meshes`; `summary.json`'s `plan.meshes` says which). A thin part has
    its centres on a sheet (the studio sunglasses' 4 mm temple) and no grasp seats on it; every
    plan found on the centres stays as it was. On the tracked sunglasses (session 43, table yaw
    0, with the sided release of `SimConfig.release_sided`) the extents' plan passes every stage."""
    plan_scan_surface: bool = False
    """Plan on the parts' surfaces as the scan's depth saw them (`parts.scan_surface_points`: the
    depth maps back-projected inside each part's mask, plus the Gaussian centres no scan view
    sees through) instead of the Gaussian centres, whose outer tail fattens the parts by 2-8 mm
    where the pads must pass (the studio led_light: no grasp on its panel seats with the 3 mm
    clearance). Needs a scan with depth maps. Off: on the tracked led_light over 10 table
    orientations (session 38, `experiments/results/robot_trials_s38_led_light_scan_surface.md`)
    6/10 plans are found (0/10 on the centres) but every one pinches the panel's tab with the
    fingertips (backed off 19 mm), the approach moves the lamp 6-8 mm, and the jaw shuts 10-14 mm
    from the panel: 0/10 Grasp."""
    plan_hand_grasps: bool = False
    """Also sample grasps near where the tracker anchored each hand (`anchored_hand_points`,
    `PlanConfig.hand_grasp_config`), tried when no best-scored grasp survives
    (`PlanConfig.hand_grasp_tier`). Off: on session 46's machine (robot-trial builds, 10 table
    orientations) led_light 0 → 5/10 with them (pinches of the panel's tab where the hand held it,
    instead of top-down pinches that slip or shut beside it), but scissors 5 → 0/10 (pinches near
    the hand on the thin ring shut on nothing, instead of the top-down pinches)."""
    plan_root_still: bool = False
    """`PlanConfig.root_still`: plan the parts' motion relative to the root held still (off: the
    object-frame track; see there for what each gives on the robot trials' tracks)."""
    plan_grasp_keyframe_weight: float = 3.0
    """`PlanConfig.grasp_keyframe_weight`: weight of the grasp keyframe's pose rows (its default)."""
    plan_square_grasps: bool = True
    """Prefer square pinches (`PlanConfig.with_square_grasps`: contact normals averaged over
    8 mm, contacts within `plan_square_cone_deg` of the axis; the spread set keeps RSRD's rule).
    On since session 38 with RSRD's 45° cone: the tracked frog's round legs turned 16–19° in
    tilted pinches (2/10 end to end over 10 table orientations, session 31) and pass 10/10 with
    it (`experiments/results/robot_trials_s35_frog_cone45.md`); stapler, wire_cutter, nerf_gun,
    toy_drawer and red_box keep their results (see README, Limitations, session 38). From ground
    truth at 30 demo frames the frog's bimanual plan then takes a spread (single-face) grasp whose
    leg turns 22° (the slow simulation test's xfail)."""
    plan_square_cone_deg: float = 45.0
    """With `plan_square_grasps`: the friction cone (degrees) of the best-scored and near-hand
    grasp samplings. Session 35, tracked frog over 10 table orientations: 45° (RSRD's cone, patch
    normals only) 10/10 end to end, 15° 5/10 (`experiments/results/robot_trials_s35_frog_cone45.md`,
    `robot_trials_s34_frog_square.md`)."""
    register_seeds: int = 16
    """Registration yaw seeds."""
    register_feature_window: float = 0.05
    """Registration seed selection: the lowest feature loss among the seeds whose total loss is
    within this fraction of the lowest (0: the lowest total), see `track.select_seed`."""
    init_position_tol_m: float = 0.02
    """Init stage: registration centroid error below this (m)."""
    init_rotation_tol_deg: float = 10.0
    """Init stage: registration rotation error below this (degrees)."""
    sim_video: bool = True
    """Write sim.mp4 of the simulated robot."""
    rerun: bool = True
    """Write rerun recordings of the stages."""

    def __post_init__(self):
        if not 0.0 < self.plan_square_cone_deg < 90.0:  # also refuses NaN
            raise ValueError(f"plan_square_cone_deg: expected degrees in (0, 90), got {self.plan_square_cone_deg}")

    def build_config(self):
        """The `BuildConfig` of the pipeline's object model (also used by the experiments and
        benchmarks that measure at the demo's size)."""
        from .parts import BuildConfig, FieldConfig, FitConfig

        return BuildConfig(fit=FitConfig(iterations=self.fit_iterations, max_gaussians=self.max_gaussians, seed=self.seed),
                           field=FieldConfig(iterations=self.field_iterations, seed=self.seed))  # fmt: skip

    def register_config(self):
        """The registration's `InitConfig` (robot view, metric depth)."""
        from .track import InitConfig

        return InitConfig(yaw_seeds=self.register_seeds, iters=50, refine_iters=0, lr_start=2e-2, lr_end=2e-3)

    def track_config(self):
        """The `TrackConfig` of the pipeline's tracking stage (also used by the experiments)."""
        from .track import LossWeights, TrackConfig

        return TrackConfig(steps_per_frame=self.track_steps, roi_size=self.track_roi, seed=self.seed, joints=self.track_joints,
                           hinge_axes=self.track_hinge_axes, hinge_refine_deg=self.track_hinge_refine_deg,
                           lr_start=self.track_lr_start, separable_motion=self.track_motion_separable,
                           still_root=self.track_still_root, slide_baseline=self.track_slide_baseline,
                           weights=LossWeights(motion=self.track_motion, hand_depth=self.track_hand_depth if self.track_hands else 0.0))  # fmt: skip


def studio_hands_in_object_frame(studio_dir: Path, T_cam_obj: np.ndarray) -> np.ndarray:
    """Fingertip keypoints in the object frame from the studio's hand oracle and the *tracked*
    object pose.

    The studio's keypoints are moved into the demo camera's frame (what a 3D hand detector such as
    HaMeR gives), then into the object frame by the tracked `T_cam_obj` of each frame.

    Args:
        studio_dir: studio object directory (needs `demo/gt/hand_keypoints.npz`, `part_poses.npz`).
        T_cam_obj: (T, 7) tracked object poses in the demo camera.

    Returns:
        (T, H, 2, 3) keypoints (m), contact order.
    """
    import jax.numpy as jnp
    import jaxlie

    d = Path(studio_dir) / "demo" / "gt"
    with np.load(d / "hand_keypoints.npz") as z:
        kw = np.asarray(z["keypoints_world"], np.float64)  # T, H, 2, 3 (demo world)
    with np.load(d / "part_poses.npz") as z:
        T_cw = np.asarray(jaxlie.SE3(jnp.asarray(z["T_cam_world"], jnp.float32)).as_matrix(), np.float64)
    T_co = np.asarray(jaxlie.SE3(jnp.asarray(T_cam_obj, jnp.float32)).as_matrix(), np.float64)
    n = min(len(kw), len(T_co))
    kc = kw[:n] @ T_cw[:3, :3].T + T_cw[:3, 3]
    T_oc = np.linalg.inv(T_co[:n])
    return np.einsum("tij,thkj->thki", T_oc[:, :3, :3], kc) + T_oc[:, None, None, :3, 3]


def anchored_hand_parts(traj) -> tuple[int, int] | None:
    """The (left hand, right hand) parts the tracker's hand term anchored (``trajectory.json``'s
    ``hand_anchors``), or None unless both hands were anchored.

    The planner's bimanual decision takes these: the anchors are found in 2D (the part under each
    pinch point), while the 3D fingertips moved into the object frame by the tracked pose inherit
    its depth error (1–8 %; on the frog both hands then lie 19–26 mm from the legs they hold)."""
    parts = [a.get("part") for a in traj.meta.get("hand_anchors", [])]
    return (int(parts[0]), int(parts[1])) if len(parts) == 2 and None not in parts else None


def _plan_config(cfg: PipelineConfig) -> PlanConfig:
    """The planner's options of a pipeline run."""
    from .plan import PlanConfig

    out = PlanConfig(seed=cfg.seed, collision_margin=cfg.plan_collision_margin,
                     grasp_keyframe_weight=cfg.plan_grasp_keyframe_weight, root_still=cfg.plan_root_still)
    return out.with_square_grasps(cone_deg=cfg.plan_square_cone_deg) if cfg.plan_square_grasps else out


def anchored_hand_points(traj) -> list[tuple[int, np.ndarray]]:
    """(part, point) of every hand the tracker's hand term anchored (``trajectory.json``'s
    ``hand_anchors``): where the hand held that part, in its rest-centroid frame (m), the frame
    the planner's part points use. The planner samples grasps near them."""
    return [(int(a["part"]), np.asarray(a["point_mm"], np.float64) / 1000.0)
            for a in traj.meta.get("hand_anchors", []) if a.get("part") is not None]  # fmt: skip


def free_parts(traj) -> list[int] | None:
    """The parts no joint holds, for the planner: every part of an object tracked as separable
    (``trajectory.json``'s ``separable``), else None."""
    return list(range(traj.num_parts)) if traj.meta.get("separable") else None


def studio_separable(studio_dir: Path) -> bool:
    """The studio object's ``separable`` flag (``object.json``): its parts come apart (usb_plug).
    A scan does not record it, so the pipeline passes it to tracking."""
    p = Path(studio_dir) / "object.json"
    if not p.is_file():
        raise FileNotFoundError(f"{p}: studio object.json missing (expected the output of make_object)")
    with open(p) as f:
        meta = json.load(f)
    if not isinstance(meta.get("separable"), bool):
        raise ValueError(f"{p}: field 'separable' must be true or false, got {meta.get('separable')!r}")
    return meta["separable"]


def _stage(name: str, report: dict, log):
    class _Timer:
        def __enter__(self):
            report.setdefault(name, {})
            log(f"[{name}] ...")
            self.t0 = time.perf_counter()
            return self

        def __exit__(self, *exc):
            report.setdefault(name, {})["time_s"] = round(time.perf_counter() - self.t0, 2)
            if exc[0] is None:
                log(f"[{name}] done in {report[name]['time_s']:.1f} s: {report[name].get('summary', '')}")
            return False

    return _Timer()


def plan_on_meshes(run_plan, extents, cfg: PipelineConfig, log=print):
    """The pipeline's plan: on the Gaussian centres' meshes (``run_plan(None)``), or on their
    extents' (``run_plan(extents())``) with ``cfg.plan_extent_meshes``, or after a failure on the
    centres with ``cfg.plan_extent_fallback``. Returns (plan, which meshes, the failed plan on
    the centres or None)."""
    if cfg.plan_extent_meshes:
        return run_plan(extents()), "extents", None
    plan = run_plan(None)
    if plan.success or not cfg.plan_extent_fallback:
        return plan, "centres", None
    log(f"plan: {plan.result_name} on the Gaussian centres' meshes; planning on their extents")
    return run_plan(extents()), "extents (fallback)", plan


def run_pipeline(object_name: str, out: str | Path, cfg: PipelineConfig = PipelineConfig(), log=print,
                 studio_dir: str | Path | None = None, model_dir: str | Path | None = None,
                 track_dir: str | Path | None = None) -> dict:  # fmt: skip
    """Runs every stage on one studio object and returns (and writes) the summary.

    Args:
        object_name: studio object (``rsrd-jax studio list``).
        out: output directory (created; existing stage outputs inside are replaced).
        cfg: sizes and options.
        log: progress messages (each stage also shows a progress bar).
        studio_dir, model_dir, track_dir: reuse these artefacts instead of making them (robot
            trials reuse one object's model and trajectory across table placements).

    Returns:
        The summary: per stage its time and result, the paper's stage successes
        (init/traj/grasp/exec) and ``end_to_end``.
    """
    from .io import load_plan, load_trajectory, read_demo, read_demo_gt, save_plan, save_trajectory, write_video
    from .parts import build_object_model, load_object_model, model_scan_surface, save_object_model
    from .plan import PlanConfig, plan_robot, read_robot_object_pose
    from .robot import load_yumi
    from .sim import SimConfig, log_sim_rerun, save_sim_result, simulate_plan, with_init
    from .studio import StudioConfig, make_object
    from .track import InitConfig, StudioDepthOracle, StudioFingertips, StudioHandMasks, add_metrics, track_video
    from .track import read_robot_view, register_object, registration_error

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rep: dict = {"object": object_name, "config": dataclasses.asdict(cfg)}
    t_all = time.perf_counter()

    # ---- studio (MuJoCo renders with ground truth)
    if studio_dir is None:
        studio_dir = out / "studio"
        with _stage("studio", rep, log):
            meta = make_object(object_name, studio_dir, StudioConfig(
                seed=cfg.seed, scan_views=cfg.scan_views, scan_size=cfg.scan_size, demo_frames=cfg.demo_frames,
                demo_size=cfg.demo_size, robot_object_yaw_deg=cfg.robot_yaw_deg), overwrite=True)  # fmt: skip
            from .viz import log_studio, studio_contact_sheet

            rep["studio"]["contact_sheet"] = str(studio_contact_sheet(studio_dir, out / "contact_sheet.png"))
            if cfg.rerun:
                rep["studio"]["rerun"] = str(log_studio(studio_dir, out / "studio.rrd"))
            prod = meta.get("products", {})
            rep["studio"]["summary"] = (f"{len(meta.get('parts', []))} parts, {prod.get('demo', {}).get('frames')} demo frames, "
                                        f"robot-view yaw {prod.get('robot_view', {}).get('yaw_deg')}°")  # fmt: skip
    studio_dir = Path(studio_dir)

    # ---- build the object model from the scan
    if model_dir is None:
        model_dir = out / "model"
        with _stage("build", rep, log):
            bcfg = cfg.build_config()
            model = build_object_model(studio_dir / "scan", bcfg, progress=True,
                                       rrd_path=model_dir / "build.rrd" if cfg.rerun else None)  # fmt: skip
            save_object_model(model, model_dir)
            m = model.meta["metrics"]
            rep["build"].update(num_gaussians=int(model.gaussians.num_gaussians), num_parts=model.num_parts,
                                metrics={k: v for k, v in m.items() if isinstance(v, (int, float))})  # fmt: skip
            rep["build"]["summary"] = f"{model.gaussians.num_gaussians} Gaussians, {model.num_parts} parts"
    model = load_object_model(model_dir)

    # ---- track the demo video
    demo = read_demo(studio_dir / "demo" / "demo.mp4")
    if track_dir is None:
        track_dir = out / "track"
        with _stage("track", rep, log):
            tcfg = cfg.track_config()
            tips = StudioFingertips(studio_dir / "demo", cfg.track_hand_noise_px, cfg.seed) if cfg.track_hands else None
            traj = track_video(model, demo, tcfg, InitConfig(iters=cfg.init_iters),
                               StudioHandMasks(studio_dir / "demo"), StudioDepthOracle(studio_dir / "demo", seed=cfg.seed),
                               separable=studio_separable(studio_dir), fingertips=tips)  # fmt: skip
            save_trajectory(traj, track_dir)
            if cfg.rerun:
                from .viz import log_tracking, overlay_frames

                ov = overlay_frames(model, traj, demo)
                write_video(track_dir / "overlay.mp4", ov, demo.fps)
                log_tracking(model, traj, demo, track_dir / "track.rrd", ov)
    traj = load_trajectory(track_dir)
    gt = read_demo_gt(studio_dir / "demo")
    pts = [np.asarray(model.part_points(k)) for k in range(model.num_parts)]
    add = add_metrics(traj.T_cam_world_part, gt["T_cam_world_part"][: traj.num_frames], pts)
    rep.setdefault("track", {}).update(
        add_obj_mm=[round(x, 2) for x in add["add_obj_mm"]], add_obj_mean_mm=round(add["mean_add_obj_mm"], 2),
        add_cam_mean_mm=round(add["mean_add_mm"], 2), frames=traj.num_frames,
        frames_per_second=traj.meta.get("frames_per_second"), timings_s=traj.meta.get("timings_s"),
    )  # fmt: skip
    rep["track"]["summary"] = f"ADD (object frame) per part {rep['track']['add_obj_mm']} mm"
    log(f"[track] {rep['track']['summary']}")

    # ---- register the object in the robot's workspace (robot-view RGB + metric depth)
    with _stage("register", rep, log):
        view = read_robot_view(studio_dir)
        reg = register_object(model, view, cfg.register_config(), feature_window=cfg.register_feature_window)
        T_gt = read_robot_object_pose(studio_dir)
        all_pts = np.concatenate(pts)
        err = registration_error(reg.T_robot_obj, T_gt, all_pts)
        init_ok = err["translation_mm"] <= cfg.init_position_tol_m * 1e3 and err["rotation_deg"] <= cfg.init_rotation_tol_deg
        rep["register"].update(status=reg.status_name, error=err, residual_mm=reg.residual_mm, init_ok=bool(init_ok),
                               T_robot_obj=reg.T_robot_obj.tolist(), T_robot_obj_gt=np.asarray(T_gt).tolist())  # fmt: skip
        seed_err = [registration_error(np.asarray(T), T_gt, all_pts) for T in reg.info["seed_poses_robot"]]
        atomic_write_json(out / "register" / "registration.json", {**rep["register"], "info": reg.info, "seed_errors": [
            {k: round(v, 2) for k, v in e.items()} for e in seed_err]})  # each seed's pose (before ICP) against the truth
        rep["register"]["summary"] = (f"{err['translation_mm']:.1f} mm, {err['rotation_deg']:.1f}° "
                                      f"({'ok' if init_ok else 'above'} {cfg.init_position_tol_m * 1e3:.0f} mm / {cfg.init_rotation_tol_deg:.0f}°)")  # fmt: skip

    # ---- plan the robot's grasps and joint trajectory for the registered pose
    with _stage("plan", rep, log):
        cents = np.asarray(traj.meta.get("part_centroids", np.asarray(model.part_centroids)), float)
        part_points = [p - cents[k] for k, p in enumerate(pts)]
        if cfg.plan_scan_surface:
            part_points = [p - cents[k] for k, p in enumerate(model_scan_surface(model, studio_dir / "scan"))]
        hands = studio_hands_in_object_frame(studio_dir, traj.T_cam_obj)
        hand_parts = anchored_hand_parts(traj)
        hand_points = anchored_hand_points(traj) if cfg.plan_hand_grasps else None
        run_plan = lambda mesh: plan_robot(  # noqa: E731
            load_yumi(), part_points, traj.T_obj_part, reg.T_robot_obj, hands=hands, config=_plan_config(cfg),
            mesh_points=mesh, hand_parts=hand_parts, hand_points=hand_points, free_parts=free_parts(traj))
        extents = lambda: [np.asarray(model.part_extent_points(k)) - cents[k] for k in range(model.num_parts)]  # noqa: E731
        plan, rep["plan"]["meshes"], first = plan_on_meshes(run_plan, extents, cfg, log)
        if first is not None:
            rep["plan"]["centres_result"] = f"{first.result_name} ({first.message})"
        save_plan(plan, out / "plan")
        if cfg.rerun and plan.success:
            from .plan import log_plan

            log_plan(load_yumi(), plan, part_points, traj.T_obj_part, out / "plan" / "plan.rrd")
        rep["plan"].update(result=plan.result_name, message=plan.message, parts=np.asarray(plan.part).tolist(),
                           rejections=plan.info.get("rejections"), bimanual=plan.info.get("bimanual"))  # fmt: skip
        rep["plan"]["summary"] = f"{plan.result_name} ({plan.message})"

    # ---- simulate the plan with the object at its TRUE pose
    with _stage("simulate", rep, log):
        scfg = SimConfig()
        res = simulate_plan(load_plan(out / "plan"), studio_dir, scfg, video=cfg.sim_video, progress=True)
        reason = f"{err['translation_mm']:.1f} mm / {err['rotation_deg']:.1f}°"
        res = with_init(res, init_ok, reason, **err)
        paths = save_sim_result(res, out / "sim", fps=scfg.fps)
        if cfg.rerun and res.executed:
            log_sim_rerun(res, studio_dir, out / "sim" / "sim.rrd", scfg)
        rep["simulate"].update(outcome=res.outcome_name, stages=res.stages, reasons=res.reasons,
                               outputs={k: str(v) for k, v in paths.items()})  # fmt: skip
        rep["simulate"]["summary"] = res.outcome_name
    st = res.stages
    rep["stages"] = {k: st.get(k) for k in ("init", "traj", "grasp", "exec")}
    rep["end_to_end"] = bool(all(st.get(k) for k in ("init", "traj", "grasp", "exec")))
    rep["total_time_s"] = round(time.perf_counter() - t_all, 1)
    atomic_write_json(out / "summary.json", _jsonable(rep))
    return rep


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    return x
