"""`rsrd-jax`: the command-line entry point. Every stage is a subcommand; `--help` documents options.

Recipes that combine stages live here, not in the library.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")


def _add_studio_options(p: argparse.ArgumentParser) -> None:
    from .studio import StudioConfig

    d = StudioConfig()
    p.add_argument("--seed", type=int, default=d.seed, help="seed for textures, cameras, placements")
    p.add_argument("--views", type=int, default=d.scan_views, help="number of scan views (≥ 48 recommended)")
    p.add_argument("--scan-size", type=int, nargs=2, default=d.scan_size, metavar=("W", "H"), help="scan image size")
    p.add_argument("--frames", type=int, default=None, help="demo frames (default: the object's own, 90–120)")
    p.add_argument("--demo-size", type=int, nargs=2, default=d.demo_size, metavar=("W", "H"), help="demo video size")
    p.add_argument("--demo-yaw", type=float, default=None, help="object yaw in the demo relative to the scan, degrees")
    p.add_argument("--robot-size", type=int, nargs=2, default=d.robot_size, metavar=("W", "H"), help="robot view size")
    p.add_argument("--robot-xy", type=float, nargs=2, default=d.robot_object_xy, metavar=("X", "Y"),
                   help="object position on the table, robot base frame (m)")  # fmt: skip
    p.add_argument("--robot-yaw", type=float, default=None, help="object yaw on the table, degrees")
    p.add_argument("--pose-noise-deg", type=float, default=d.pose_noise_deg, help="scan pose rotation noise std (deg)")
    p.add_argument("--pose-noise-m", type=float, default=d.pose_noise_m, help="scan pose translation noise std (m)")
    p.add_argument("--clutter", action="store_true", help="scatter distractor objects around the object")
    p.add_argument("--lighting", type=float, default=d.lighting, help="light intensity multiplier")
    p.add_argument("--only", nargs="+", choices=("scan", "demo", "robot_view"), default=None, help="make only these")


def _studio_config(a: argparse.Namespace):
    from .studio import StudioConfig

    d = StudioConfig()
    return StudioConfig(
        seed=a.seed, scan_views=a.views, scan_size=tuple(a.scan_size), demo_frames=a.frames,
        demo_size=tuple(a.demo_size), demo_yaw_deg=a.demo_yaw, robot_size=tuple(a.robot_size),
        robot_object_xy=tuple(a.robot_xy), robot_object_yaw_deg=a.robot_yaw, pose_noise_deg=a.pose_noise_deg,
        pose_noise_m=a.pose_noise_m, clutter=a.clutter, lighting=a.lighting,
        parts=tuple(a.only) if a.only else d.parts,
    )  # fmt: skip


def _summary(meta: dict, out: Path) -> str:
    lines = [f"{meta['name']}: {meta['description']}  ->  {out}"]
    parts = ", ".join(f"{p['name']} ({p['joint']})" for p in meta["parts"])
    lines.append(f"  parts: {parts}; moving: {[meta['parts'][k]['name'] for k in meta['moving_parts']]}")
    lines.append(f"  {'bimanual' if meta['bimanual'] else 'single-hand'} demo; separable: {meta['separable']}")
    for k, v in meta["products"].items():
        lines.append(f"  {k}: {v}")
    t = meta["timings_s"]
    lines.append("  timings: " + ", ".join(f"{k} {v:.1f} s" for k, v in t.items()))
    return "\n".join(lines)


def cmd_studio(a: argparse.Namespace) -> int:
    from .studio import get_object, list_objects, make_object

    if a.studio_cmd == "list":
        for name in list_objects():
            obj = get_object(name)
            kind = "bimanual" if obj.bimanual else "one hand"
            print(f"{name:<12} {obj.num_parts} parts, {kind:<9} {obj.description}")
        return 0
    names = list_objects() if a.object == ["all"] else a.object
    for name in names:
        if name not in list_objects():
            print(f"error: unknown studio object {name!r}; known: {', '.join(list_objects())}", file=sys.stderr)
            return 2
    cfg = _studio_config(a)
    for name in names:
        out = Path(a.out) / name if len(names) > 1 else Path(a.out)
        if out.exists() and not a.overwrite:
            print(f"error: {out} exists; pass --overwrite to replace it", file=sys.stderr)
            return 2
        meta = make_object(name, out, cfg, overwrite=a.overwrite)
        print(_summary(meta, out))
        if a.rerun or a.sheet:
            from .viz import log_studio, studio_contact_sheet

            if a.sheet:
                print(f"  contact sheet: {studio_contact_sheet(out, out / 'contact_sheet.png')}")
            if a.rerun:
                print(f"  rerun recording: {log_studio(out, out / 'studio.rrd')}")
    return 0


def cmd_demo(a: argparse.Namespace) -> int:
    """The whole pipeline on one embedded studio object: scan → model → track → register → plan →
    simulate, with each stage's result and time."""
    from .pipeline import PipelineConfig, run_pipeline

    out = Path(a.out)
    cfg = PipelineConfig(seed=a.seed, demo_frames=a.frames, robot_yaw_deg=a.robot_yaw, rerun=not a.no_rerun,
                         plan_extent_meshes=not a.centre_meshes)  # fmt: skip
    print(f"rsrd-jax demo: {a.object!r} end to end -> {out}  (stages: studio, build, track, register, plan, simulate)")
    rep = run_pipeline(a.object, out, cfg, log=lambda m: print(m, flush=True))
    print("\nstage     time      result")
    for k in ("studio", "build", "track", "register", "plan", "simulate"):
        r = rep.get(k, {})
        print(f"{k:9s} {r.get('time_s', 0):6.1f} s  {r.get('summary', '')}")
    st = rep["stages"]
    print("paper stages (Table 1): " + ", ".join(f"{k} {'ok' if v else ('-' if v is None else 'FAILED')}" for k, v in st.items()))
    print(f"end to end: {'SUCCESS' if rep['end_to_end'] else 'failure'} in {rep['total_time_s']:.0f} s")
    sim = rep["simulate"].get("outputs", {})
    for k in ("mp4", "rrd"):
        if k in sim:
            print(f"  simulated robot {k}: {sim[k]}")
    print(f"  summary: {out / 'summary.json'}")
    return 0


def cmd_register(a: argparse.Namespace) -> int:
    """Registers the object in the robot frame from a robot-view RGB + metric depth."""
    import numpy as np

    from .io import ArtefactError, atomic_write_json
    from .parts import load_object_model
    from .track import InitConfig
    from .track import read_robot_view, register_object, registration_error

    out = Path(a.out)
    if (out / "registration.json").exists() and not a.overwrite:
        print(f"error: {out / 'registration.json'} exists; pass --overwrite to replace it", file=sys.stderr)
        return 2
    try:
        model = load_object_model(a.model)
        view = read_robot_view(a.view)
        reg = register_object(model, view, InitConfig(yaw_seeds=a.yaw_seeds, iters=a.iters, refine_iters=0,
                                                       lr_start=2e-2, lr_end=2e-3), feature_window=a.feature_window)  # fmt: skip
    except (ArtefactError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    rec = {"status": reg.status_name, "T_robot_obj": reg.T_robot_obj.tolist(), "T_cam_obj": reg.T_cam_obj.tolist(), "loss": reg.loss,
           "residual_mm": reg.residual_mm, "info": reg.info}  # fmt: skip
    gt_path = Path(a.view) / "gt.json" if (Path(a.view) / "gt.json").is_file() else Path(a.view) / "robot_view" / "gt.json"
    if gt_path.is_file():
        from .plan import read_robot_object_pose

        pts = np.concatenate([np.asarray(model.part_points(k)) for k in range(model.num_parts)])
        rec["error_vs_studio_gt"] = registration_error(reg.T_robot_obj, read_robot_object_pose(gt_path), pts)
    atomic_write_json(out / "registration.json", rec)
    print(f"registration: {reg.status_name} -> {out / 'registration.json'} in {reg.info['time_s']:.1f} s")
    print(f"  T_robot_obj (wxyz_xyz): {np.round(reg.T_robot_obj, 4).tolist()}")
    print(f"  residual {reg.residual_mm:.1f} mm (median distance of the {reg.info['blob_pixels']} observed object points to the model)")
    if "error_vs_studio_gt" in rec:
        e = rec["error_vs_studio_gt"]
        print(f"  error vs studio ground truth: {e['translation_mm']:.1f} mm, {e['rotation_deg']:.2f}°, ADD {e['add_mm']:.1f} mm")
    print(f"  use with: rsrd-jax plan MODEL TRAJ --object-pose {' '.join(f'{v:.6f}' for v in reg.T_robot_obj)} ...")
    return 0


def cmd_track(a: argparse.Namespace) -> int:
    """Tracks a demo video with an ObjectModel; writes the PartTrajectory, overlay video, rerun."""
    from .io import read_demo, save_trajectory
    from .parts import load_object_model
    from .track import (
        InitConfig, LossWeights, NoMonoDepth, NoOccluder, OnnxDepthAnything, StudioDepthOracle,
        StudioFingertips, StudioHandMasks, TrackConfig, track_video,
    )  # fmt: skip
    from .viz import log_tracking, overlay_frames
    from .io import write_video

    out = Path(a.out)
    if (out / "trajectory.npz").exists() and not a.overwrite:
        print(f"error: {out / 'trajectory.npz'} exists; pass --overwrite to replace it", file=sys.stderr)
        return 2
    if a.w_motion_separable is not None and not 0.0 <= a.w_motion_separable < float("inf"):
        print(f"error: --w-motion-separable {a.w_motion_separable}: expected a finite weight ≥ 0", file=sys.stderr)
        return 2
    model = load_object_model(a.model)
    demo = read_demo(a.video, a.camera)
    demo_dir = Path(a.video).parent if Path(a.video).is_file() else Path(a.video)
    occluder = StudioHandMasks(demo_dir) if a.occluder == "studio" else NoOccluder()
    if a.mono_depth == "studio-oracle":
        mono = StudioDepthOracle(demo_dir, seed=a.seed)
    elif a.mono_depth == "none":
        mono = NoMonoDepth()
    else:
        mono = OnnxDepthAnything(a.mono_depth)
    fingertips = StudioFingertips(demo_dir, noise_px=a.hand_noise, seed=a.seed) if a.hands == "studio" else None
    weights = LossWeights(feature=a.w_feature, depth_rank=a.w_depth, arap=a.w_arap, touch=a.w_touch, rgb=a.w_rgb, support=a.w_support,
                          hand=a.w_hand, motion=a.w_motion, hand_depth=a.w_hand_depth)  # fmt: skip
    cfg = TrackConfig(weights=weights, roi_size=a.roi_size, steps_per_frame=a.steps, smooth_iters=a.smooth_iters,
                      max_gaussians=a.max_gaussians, lod_cells=a.lod_cells, seed=a.seed, joints=a.joints,
                      slides=not a.no_slides, slide_held_only=not a.slides_unheld, hinge_axes=a.hinge_axes,
                      hinge_refine_deg=a.hinge_refine, velocity_hypothesis=a.velocity_hypothesis,
                      separable_motion=a.w_motion_separable, still_root=a.still_root, still_root_first=a.still_root_first,
                      slide_baseline="joint" if a.still_root else "first")  # fmt: skip
    init = InitConfig(yaw_seeds=a.yaw_seeds, distance_m=a.distance, iters=a.init_iters)
    traj = track_video(model, demo, cfg, init, occluder, mono, separable=a.separable, fingertips=fingertips)
    save_trajectory(traj, out)
    t = traj.meta["timings_s"]
    print(f"tracked {traj.num_frames} frames × {traj.num_parts} parts -> {out / 'trajectory.npz'}")
    print("  timings: " + ", ".join(f"{k} {v:.1f} s" for k, v in t.items()) + f"; {traj.meta['frames_per_second']:.2f} frames/s")
    if not a.no_video:
        ov = overlay_frames(model, traj, demo)
        write_video(out / "overlay.mp4", ov, demo.fps)
        print(f"  overlay video: {out / 'overlay.mp4'}")
        if a.rerun:
            print(f"  rerun recording: {log_tracking(model, traj, demo, out / 'track.rrd', ov)}")
    return 0


def cmd_build(a: argparse.Namespace) -> int:
    """Builds an ObjectModel (3DGS fit, feature field, parts) from a scan capture."""
    from .parts import BuildConfig, FieldConfig, FitConfig, build_object_model, save_object_model

    out = Path(a.out)
    if (out / "model.json").exists() and not a.overwrite:
        print(f"error: {out} already holds a model; pass --overwrite to replace it", file=sys.stderr)
        return 2
    box = None if a.crop_box is None else (tuple(a.crop_box[:3]), tuple(a.crop_box[3:]))
    fd, dd = FitConfig(), FieldConfig()
    cfg = BuildConfig(
        fit=FitConfig(iterations=a.iterations or fd.iterations, max_gaussians=a.max_gaussians or fd.max_gaussians,
                      refine_poses=a.refine_poses, seed=a.seed),
        field=FieldConfig(iterations=a.field_iterations or dd.iterations, seed=a.seed),
        onnx_path=a.onnx, pca_dim=a.pca_dim, holdout_every=a.holdout_every, num_parts=a.num_parts,
        group_scale=a.scale, crop_box=box, use_masks=not a.no_masks,
    )  # fmt: skip
    t0 = time.perf_counter()
    model = build_object_model(a.capture, cfg, progress=True, rrd_path=None if a.no_rerun else out / "build.rrd")
    save_object_model(model, out)
    m = model.meta["metrics"]
    print(f"ObjectModel -> {out}: {model.gaussians.num_gaussians} Gaussians, {model.num_parts} parts "
          f"({model.meta['grouping']}), {len(model.arap_pairs)} ARAP pairs")  # fmt: skip
    for k, v in m.items():
        print(f"  {k}: {v:.4g}" if isinstance(v, float) else f"  {k}: {v}")
    print("  stage times: " + ", ".join(f"{k} {v:.1f}" for k, v in model.meta["stage_times_s"].items()))
    if not a.no_rerun:
        print(f"  rerun recording: {out / 'build.rrd'}")
    print(f"build finished in {time.perf_counter() - t0:.1f} s")
    return 0


def _clearance(value: str) -> float | None:
    """``--approach-clearance`` item: metres, or 'open' (None: fully open)."""
    if value.lower() == "open":
        return None
    try:
        v = float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected metres or 'open', got {value!r}") from None
    if not v >= 0 or v == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a clearance ≥ 0 m, got {value!r}")
    return v


def _parse_object_pose(value: list[str]):
    import numpy as np

    if len(value) == 1:
        from .plan import read_robot_object_pose

        return read_robot_object_pose(value[0])
    if len(value) != 7:
        raise ValueError(f"--object-pose: 7 numbers (wxyz_xyz) or one gt.json path, got {value}")
    return np.asarray([float(v) for v in value])


def cmd_plan(a: argparse.Namespace) -> int:
    """Plans the YuMi trajectory (parts, arms, grasps, joints) and writes the RobotPlan."""
    import numpy as np

    from .grasp import GraspConfig
    from .io import ArtefactError, save_plan
    from .plan import PlanConfig, plan_robot, studio_plan_inputs
    from .robot import load_yumi

    out = Path(a.out)
    if (out / "plan.npz").exists() and not a.overwrite:
        print(f"error: {out / 'plan.npz'} exists; pass --overwrite to replace it", file=sys.stderr)
        return 2
    if not all(np.isfinite(a.end_slack)) or min(a.end_slack) < 0:
        print(f"error: --end-slack {a.end_slack}: expected degrees and mm ≥ 0", file=sys.stderr)
        return 2
    if not 0.0 <= a.short_lever < 1.0:
        print(f"error: --short-lever {a.short_lever}: expected a fraction in [0, 1) (0: off)", file=sys.stderr)
        return 2
    hands = hand_parts = hand_points = None
    mesh_points = None
    if a.studio_gt:
        try:
            inp = studio_plan_inputs(a.studio_gt)
        except ArtefactError as e:
            print(f"error: {e}", file=sys.stderr)
            return 2
        part_points, T_obj_part, hands = inp.part_points, inp.T_obj_part, inp.hands
        T_robot_obj = inp.T_robot_obj if a.object_pose is None else _parse_object_pose(a.object_pose)
        free = inp.free_parts
    else:
        from .io import load_trajectory
        from .parts import load_object_model

        if a.model is None or a.traj is None or a.object_pose is None:
            print("error: MODEL, TRAJ and --object-pose are required (or --studio-gt DIR)", file=sys.stderr)
            return 2
        model = load_object_model(a.model)
        traj = load_trajectory(a.traj)
        if traj.num_parts != model.num_parts:
            print(f"error: {a.traj} has {traj.num_parts} parts but the model {a.model} has {model.num_parts}",
                  file=sys.stderr)  # fmt: skip
            return 2
        cents = np.asarray(traj.meta.get("part_centroids", np.asarray(model.part_centroids)), float)
        part_points = [np.asarray(model.part_points(k)) - cents[k] for k in range(model.num_parts)]
        if a.scan_surface is not None:
            from .parts import model_scan_surface

            try:
                surf = model_scan_surface(model, a.scan_surface)
            except ArtefactError as e:
                print(f"error: {e}", file=sys.stderr)
                return 2
            part_points = [p - cents[k] for k, p in enumerate(surf)]
        if a.extent_meshes:
            mesh_points = [np.asarray(model.part_extent_points(k)) - cents[k] for k in range(model.num_parts)]
        T_obj_part = traj.T_obj_part
        T_robot_obj = _parse_object_pose(a.object_pose)
        from .pipeline import anchored_hand_parts, anchored_hand_points, free_parts

        free = free_parts(traj)
        hand_parts = anchored_hand_parts(traj)
        hand_points = anchored_hand_points(traj) if a.hand_grasps else None
    if a.hands == "none":
        hands = hand_parts = hand_points = None
    cfg = PlanConfig(
        num_keyframes=a.keyframes, bimanual={"auto": "auto", "yes": True, "no": False}[a.bimanual], parts=tuple(a.parts) if a.parts else None,
        max_parts=a.max_parts, chunk_size=a.chunk, max_iterations=a.max_iterations, seed=a.seed,
        approach_distance=a.approach, position_tolerance=a.pos_tol, rotation_tolerance_deg=a.rot_tol,
        grasp_position_tolerance=a.grasp_pos_tol, grasp_rotation_tolerance_deg=a.grasp_rot_tol,
        grasp_keyframe_weight=a.grasp_keyframe_weight,
        hand_tolerance=a.hand_tolerance, approach_steps=a.approach_steps, max_candidates=a.max_candidates,
        grasp_config=GraspConfig(num_grasps=a.grasps), collision_margin=a.collision_margin,
        pad_table_margin=a.pad_table_margin, approach_clearance=tuple(a.approach_clearance),
        end_slack_deg=None if a.no_end_slack else a.end_slack[0], end_slack_m=a.end_slack[1] / 1000.0,
        short_lever_fraction=a.short_lever or None, root_still=a.root_still,
    )  # fmt: skip
    if a.square_grasps:
        cfg = cfg.with_square_grasps(cone_deg=a.square_cone)
    if a.no_topdown_grasps:
        cfg = dataclasses.replace(cfg, topdown_grasp_config=None)
    t0 = time.perf_counter()
    robot = load_yumi()
    if a.free_parts is not None:
        free = a.free_parts or None
        bad = [k for k in a.free_parts if not 0 <= k < len(part_points)]
        if bad:
            print(f"error: --free-parts {bad}: expected part indices 0..{len(part_points) - 1}", file=sys.stderr)
            return 2
    plan = plan_robot(robot, part_points, T_obj_part, T_robot_obj, hands=hands, config=cfg, mesh_points=mesh_points,
                      hand_parts=hand_parts, hand_points=hand_points, free_parts=free)  # fmt: skip
    save_plan(plan, out)
    print(f"plan: {plan.result_name} ({plan.message}) in {time.perf_counter() - t0:.1f} s -> {out / 'plan.npz'}")
    if a.rerun and plan.success:
        from .plan import log_plan

        print(f"  rerun: {log_plan(robot, plan, part_points, T_obj_part, out / 'plan.rrd')}")
    print(f"  rejections: {plan.info['rejections']}")
    if plan.success:
        arms = ", ".join(f"{n} arm -> part {int(k)} (grasp {int(g)})" for n, k, g in
                         zip(("right", "left"), plan.part, plan.grasp_index) if k >= 0)  # fmt: skip
        print(f"  {arms}; max TCP error {1000 * np.nanmax(plan.position_error):.1f} mm, "
              f"{np.rad2deg(np.nanmax(plan.rotation_error)):.1f} deg")  # fmt: skip
    return 0 if plan.success else 1


def cmd_simulate(a: argparse.Namespace) -> int:
    """Executes a RobotPlan in MuJoCo with the studio object and writes sim.json (+ mp4, rrd)."""
    from .io import ArtefactError, load_plan
    from .sim import SimConfig, log_sim_rerun, save_sim_result, simulate_plan

    out = Path(a.out)
    if (out / "sim.json").exists() and not a.overwrite:
        print(f"error: {out / 'sim.json'} exists; pass --overwrite to replace it", file=sys.stderr)
        return 2
    try:
        plan = load_plan(a.plan)
        if not 0.0 <= a.seat_shift < float("inf"):
            raise ValueError(f"--seat-shift: expected a shift ≥ 0 m, got {a.seat_shift}")
        cfg = SimConfig(root=a.root, start=a.start, joint_speed=a.joint_speed, seat_max_shift=a.seat_shift,
                        release_sided=not a.symmetric_release)  # fmt: skip
        t0 = time.perf_counter()
        res = simulate_plan(plan, a.studio, cfg, video=a.video, progress=not a.quiet)
        paths = save_sim_result(res, out, fps=cfg.fps)
        if a.rerun and res.executed:
            paths["rrd"] = log_sim_rerun(res, a.studio, out / "sim.rrd", cfg)
    except (ArtefactError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"simulate: {res.outcome_name} in {time.perf_counter() - t0:.1f} s -> {paths['json']}")
    for stage in ("traj", "grasp", "exec"):
        ok = res.stages[stage]
        mark = "not evaluated" if ok is None else ("ok" if ok else "FAILED")
        print(f"  {stage:5s} {mark}: {res.reasons.get(stage, '')}")
    if res.executed:
        mt = res.metrics
        print(f"  {mt['sim_time_s']:.1f} s simulated, {mt['realtime_factor']:.1f}x real time; "
              f"object base moved {mt['base_displacement_mm']:.1f} mm")  # fmt: skip
    for k in ("mp4", "rrd"):
        if k in paths:
            print(f"  {k}: {paths[k]}")
    return 0 if res.success else 1


def cmd_bench(a: argparse.Namespace) -> int:
    root = Path(__file__).resolve().parent.parent
    if not (root / "benchmarks" / "run.py").is_file():
        print("error: benchmarks/ is part of the source checkout, not the installed package", file=sys.stderr)
        return 2
    sys.path.insert(0, str(root))
    from benchmarks.run import main as bench_main

    return bench_main(a.args)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="rsrd-jax", description="Robot See Robot Do in JAX.")
    sub = parser.add_subparsers(dest="cmd", required=True)

    st = sub.add_parser("studio", help="synthetic articulated objects rendered by MuJoCo, with ground truth")
    st_sub = st.add_subparsers(dest="studio_cmd", required=True)
    st_sub.add_parser("list", help="list the studio objects")
    mk = st_sub.add_parser("make", help="make an object's scan, demo video and robot view")
    mk.add_argument("object", nargs="+", help="object name(s), or 'all'")
    mk.add_argument("--out", required=True, help="output directory (one subdirectory per object if several)")
    mk.add_argument("--overwrite", action="store_true", help="replace an existing output directory")
    mk.add_argument("--rerun", action="store_true", help="also write studio.rrd (rerun recording)")
    mk.add_argument("--sheet", action="store_true", help="also write contact_sheet.png")
    _add_studio_options(mk)
    st.set_defaults(func=cmd_studio)

    dm = sub.add_parser("demo", help="run the whole pipeline end to end on an embedded studio object")
    dm.add_argument("--object", default="stapler", help="studio object")
    dm.add_argument("--out", default="demo_out", help="output directory")
    dm.add_argument("--seed", type=int, default=0, help="studio seed")
    dm.add_argument("--frames", type=int, default=30, help="demo video frames")
    dm.add_argument("--robot-yaw", type=float, default=None, help="object yaw on the robot's table (degrees)")
    dm.add_argument("--no-rerun", action="store_true", help="skip the rerun recordings and overlay video")
    dm.add_argument("--centre-meshes", action="store_true",
                    help="plan on the meshes of the Gaussian centres, with the extents as the fallback (the "
                         "pipeline's default); the demo plans on the extents' meshes, which keep the open pads "
                         "off the stapler's arm on the approach")  # fmt: skip
    dm.set_defaults(func=cmd_demo)

    rg = sub.add_parser("register", help="register the object in the robot frame from a robot-view RGB-D image")
    rg.add_argument("model", help="ObjectModel directory (from `rsrd-jax build`)")
    rg.add_argument("view", help="robot view directory (rgb.png, depth.png in mm, camera.json with T_robot_cam)")
    rg.add_argument("--out", required=True, help="output directory (registration.json)")
    rg.add_argument("--yaw-seeds", type=int, default=16, help="yaw seeds over 360°")
    rg.add_argument("--feature-window", type=float, default=0.05,
                    help="pick the lowest feature loss among seeds within this fraction of the lowest total loss (0: lowest total)")
    rg.add_argument("--iters", type=int, default=50, help="Adam iterations per seed and for the refinement")
    rg.add_argument("--overwrite", action="store_true", help="replace an existing registration")
    rg.set_defaults(func=cmd_register)

    tr = sub.add_parser("track", help="track every part of an ObjectModel through a demo video (4D-DPM)")
    tr.add_argument("model", help="ObjectModel directory (from `rsrd-jax build`)")
    tr.add_argument("video", help="demo video (mp4) or its directory")
    tr.add_argument("--out", required=True, help="output directory (trajectory.npz/json, overlay.mp4, track.rrd)")
    tr.add_argument("--camera", default=None, help="camera.json (default: next to the video)")
    tr.add_argument("--occluder", choices=("studio", "none"), default="none",
                    help="hand masks: the studio's ground truth (oracle) or none")  # fmt: skip
    tr.add_argument("--mono-depth", default="none",
                    help="'studio-oracle' (labelled oracle), 'none', or a Depth-Anything ONNX file")  # fmt: skip
    tr.add_argument("--hands", choices=("studio", "none"), default="none",
                    help="2D fingertips for the hand term: the studio's projected keypoints (oracle) or none")  # fmt: skip
    tr.add_argument("--hand-noise", type=float, default=0.0, help="with --hands studio: Gaussian pixel noise on the fingertips")
    tr.add_argument("--w-hand", type=float, default=0.01,
                    help="hand term weight: each hand's pinched part point follows its fingertips' midpoint (needs --hands)")  # fmt: skip
    tr.add_argument("--w-hand-depth", type=float, default=0.0,
                    help="hand depth term weight: each held part's surface at the pinch point lies at the hand's depth, read "
                         "off the table with the mono-depth's order (needs --hands, --mono-depth and a model with a support "
                         "plane; rsrd-jax demo: 0.2)")  # fmt: skip
    tr.add_argument("--w-motion", type=float, default=0.0,
                    help="per-frame motion prior weight: squared pose update away from the extrapolated guess (rsrd-jax demo: 0.1)")  # fmt: skip
    tr.add_argument("--w-motion-separable", type=float, default=None, metavar="W",
                    help="motion prior weight on a separable object (TrackConfig.separable_motion; default --w-motion; "
                         "rsrd-jax demo: 3.0)")  # fmt: skip
    tr.add_argument("--still-root", action="store_true",
                    help="hold the root (part 0) at its frame-0 pose: a still camera and an object resting where it "
                         "stands (TrackConfig.still_root; with --joints from the second pass on, and slide "
                         "hypotheses compared with a pass on the joint point, slide_baseline='joint')")  # fmt: skip
    tr.add_argument("--still-root-first", action="store_true",
                    help="with --still-root and --joints: hold the root in the first pass too, which the joints are "
                         "fitted from (TrackConfig.still_root_first)")  # fmt: skip
    tr.add_argument("--roi-size", type=int, default=224, help="ROI crop side in pixels")
    tr.add_argument("--steps", type=int, default=50, help="Adam steps per frame")
    tr.add_argument("--smooth-iters", type=int, default=30, help="joint smoothing iterations (0: off)")
    tr.add_argument("--max-gaussians", type=int, default=12000, help="Gaussians used for tracking")
    tr.add_argument("--lod-cells", type=float, default=None,
                    help="merge Gaussians per part on voxels of this fraction of an ROI feature cell (faster; default off)")  # fmt: skip
    tr.add_argument("--yaw-seeds", type=int, default=8, help="initialisation yaw seeds")
    tr.add_argument("--init-iters", type=int, default=80, help="initialisation iterations per seed")
    tr.add_argument("--distance", type=float, default=None, help="camera-object distance prior (m)")
    tr.add_argument("--w-feature", type=float, default=1.0, help="feature loss weight")
    tr.add_argument("--w-depth", type=float, default=0.2, help="depth ranking loss weight (0: no depth)")
    tr.add_argument("--w-arap", type=float, default=0.2, help="ARAP loss weight (0: no ARAP)")
    tr.add_argument("--w-touch", type=float, default=0.0, help="as-touching loss weight (sliding contacts allowed)")
    tr.add_argument("--joints", action="store_true",
                    help="joint discovery: a first pass on the contact band, then parts tied at fitted joint points (2× time)")
    tr.add_argument("--no-slides", action="store_true",
                    help="with --joints: no slide hypotheses (a part on a slide candidate is tracked only with its joint point)")
    tr.add_argument("--slides-unheld", action="store_true",
                    help="with --joints and --hands: slide hypotheses also for parts no hand held (default: held parts only)")
    tr.add_argument("--hinge-axes", action="store_true",
                    help="with --joints: each jointed part turns about a fitted hinge axis (no roll about its own length)")
    tr.add_argument("--hinge-refine", type=float, default=None, metavar="DEG",
                    help="with --hinge-axes: turn each hinge axis from its candidate (a principal axis or the table "
                         "normal) toward the first pass's motion by up to DEG degrees")  # fmt: skip
    tr.add_argument("--velocity-hypothesis", type=float, default=None,
                    help="a second start per frame extrapolated with this velocity factor (e.g. 1.0); the lower loss wins (2× time)")
    tr.add_argument("--separable", action=argparse.BooleanOptionalAction, default=None,
                    help="the parts come apart (ARAP α 0.1, no joint discovery) or, with --no-separable, stay "
                         "attached; default: the model's meta['separable'], else attached")  # fmt: skip
    tr.add_argument("--w-rgb", type=float, default=0.05, help="photometric L1 weight")
    tr.add_argument("--w-support", type=float, default=0.0,
                    help="support-plane weight: no part below the table the scan rests on (0: off)")
    tr.add_argument("--seed", type=int, default=0)
    tr.add_argument("--no-video", action="store_true", help="skip the overlay video")
    tr.add_argument("--rerun", action="store_true", help="also write track.rrd")
    tr.add_argument("--overwrite", action="store_true", help="replace an existing trajectory")
    tr.set_defaults(func=cmd_track)

    bd = sub.add_parser("build", help="build an ObjectModel (3DGS + feature field + parts) from a scan capture")
    bd.add_argument("capture", help="capture directory (nerfstudio transforms.json)")
    bd.add_argument("--out", required=True, help="model directory (model.safetensors + model.json)")
    bd.add_argument("--overwrite", action="store_true", help="replace an existing model")
    bd.add_argument("--iterations", type=int, default=None, help="3DGS iterations (default 1000)")
    bd.add_argument("--field-iterations", type=int, default=None, help="feature-field iterations (default 600)")
    bd.add_argument("--max-gaussians", type=int, default=None, help="Gaussian capacity (default 12288)")
    bd.add_argument("--refine-poses", action="store_true", help="optimise per-view camera pose corrections")
    bd.add_argument("--onnx", default=None, help="ViT/DINOv2 ONNX file instead of the embedded EfficientNet")
    bd.add_argument("--pca-dim", type=int, default=64, help="PCA dimension of the features")
    bd.add_argument("--holdout-every", type=int, default=8, help="hold out every k-th view for metrics (0: none)")
    bd.add_argument("--num-parts", type=int, default=None, help="known part count (mask labels above it are errors)")
    bd.add_argument("--scale", type=float, default=1.0, help="automatic grouping scale without part masks")
    bd.add_argument("--crop-box", type=float, nargs=6, default=None, metavar=("X0", "Y0", "Z0", "X1", "Y1", "Z1"),
                    help="world box isolating the object when there are no masks (m)")  # fmt: skip
    bd.add_argument("--no-masks", action="store_true", help="ignore the capture's object masks")
    bd.add_argument("--no-rerun", action="store_true", help="do not write build.rrd")
    bd.add_argument("--seed", type=int, default=0)
    bd.set_defaults(func=cmd_build)

    pl = sub.add_parser("plan", help="plan the YuMi's grasps and joint trajectory for a part trajectory")
    pl.add_argument("model", nargs="?", help="ObjectModel directory (from `rsrd-jax build`)")
    pl.add_argument("traj", nargs="?", help="PartTrajectory directory (from `rsrd-jax track`)")
    pl.add_argument("--object-pose", nargs="+", default=None, metavar="V",
                    help="object pose in the robot base frame: 7 numbers wxyz_xyz, or a studio robot_view/gt.json")  # fmt: skip
    pl.add_argument("--studio-gt", default=None, metavar="DIR",
                    help="use a studio object's ground truth (scan/demo/robot_view) instead of MODEL and TRAJ")  # fmt: skip
    pl.add_argument("--out", required=True, help="output directory (plan.npz + plan.json)")
    pl.add_argument("--scan-surface", default=None, metavar="SCAN",
                    help="plan on the part surfaces this scan's depth maps saw (the model's scan; "
                         "parts.scan_surface_points), not the Gaussian centres")  # fmt: skip
    pl.add_argument("--extent-meshes", action="store_true",
                    help="grasp meshes from the Gaussians' ±1σ extents, not their centres (thin parts)")
    pl.add_argument("--hand-grasps", action="store_true",
                    help="also sample grasps where the tracker anchored each hand on its part (trajectory.json's "
                         "hand_anchors; PlanConfig.hand_grasp_config), tried when no best-scored grasp survives "
                         "(PlanConfig.hand_grasp_tier)")  # fmt: skip
    pl.add_argument("--keyframes", type=int, default=50, help="keyframes of the joint trajectory")
    pl.add_argument("--bimanual", choices=("auto", "yes", "no"), default="auto",
                    help="plan both arms on a ranked (left, right) part pair: yes, no, or auto (when both of the "
                         "demonstrator's hands touch distinct parts, one of which moved; falls back to one arm)")
    pl.add_argument("--parts", type=int, nargs="+", default=None, help="parts to use (default: ranked)")
    pl.add_argument("--max-parts", type=int, default=2, help="ranked parts (pairs) tried")
    pl.add_argument("--hands", choices=("studio", "none"), default="studio",
                    help="rank parts by the studio's hand keypoints (with --studio-gt) or by motion")  # fmt: skip
    pl.add_argument("--chunk", type=int, default=160, help="grasp candidates per vmapped solve")
    pl.add_argument("--max-iterations", type=int, default=50, help="LM iterations per solve")
    pl.add_argument("--approach", type=float, default=0.06, help="pre-grasp offset along the gripper axis (m)")
    pl.add_argument("--approach-steps", type=int, default=6, help="waypoints of the approach segment")
    pl.add_argument("--grasps", type=int, default=64,
                    help="base antipodal grasps per part (x 2 signs x 8 rolls x 3 shifts candidates)")  # fmt: skip
    pl.add_argument("--max-candidates", type=int, default=480, help="seated grasp candidates solved per part and arm")
    pl.add_argument("--pos-tol", type=float, default=0.01, help="TCP position tolerance at every keyframe (m)")
    pl.add_argument("--rot-tol", type=float, default=10.0, help="TCP rotation tolerance (degrees)")
    pl.add_argument("--grasp-pos-tol", type=float, default=0.003,
                    help="TCP position tolerance at the first keyframe, the grasp (m)")
    pl.add_argument("--grasp-rot-tol", type=float, default=5.0,
                    help="TCP rotation tolerance at the first keyframe, the grasp (degrees)")
    pl.add_argument("--grasp-keyframe-weight", type=float, default=3.0,
                    help="weight of the first keyframe's (the grasp's) pose rows relative to the others")
    pl.add_argument("--square-grasps", action="store_true",
                    help="prefer square pinches: contact normals averaged over 8 mm, contacts within --square-cone deg of the "
                         "axis (PlanConfig.with_square_grasps; the spread set keeps RSRD's rule)")  # fmt: skip
    pl.add_argument("--square-cone", type=float, default=15.0, metavar="DEG",
                    help="the friction cone of --square-grasps (degrees; 45 = RSRD's cone with patch normals)")
    pl.add_argument("--no-topdown-grasps", action="store_true",
                    help="no top-down grasps across the parts' footprints (PlanConfig.topdown_grasp_config; on by default, "
                         "tried only when no mesh grasp survives)")  # fmt: skip
    pl.add_argument("--free-parts", type=int, nargs="*", default=None, metavar="K",
                    help="parts no joint holds: square pinches (PlanConfig.free_cone_deg) that need not turn the part "
                         "about the jaw's axis (free_twist_deg); default every part of a trajectory tracked as separable "
                         "(--studio-gt: the object's separable flag); the option with no part turns it off")  # fmt: skip
    pl.add_argument("--hand-tolerance", type=float, default=0.0,
                    help="allowed penetration of the gripper (palm, finger pads) into parts (m; 0 = strict)")  # fmt: skip
    pl.add_argument("--collision-margin", type=float, default=0.0,
                    help="clearance (m) below which a robot-table/part/self distance is a collision (`rsrd-jax demo`: 0.003)")  # fmt: skip
    pl.add_argument("--pad-table-margin", type=float, default=0.001,
                    help="clearance (m) the finger pads keep from the table (fingertip grasps of flat parts)")  # fmt: skip
    pl.add_argument("--approach-clearance", type=_clearance, nargs="+", default=[None, 0.01], metavar="M|open",
                    help="finger openings tried for the approach, widest first: m per finger beyond the grasp's "
                         "half-width, or 'open' (fully open); the widest collision-free one is used")  # fmt: skip
    pl.add_argument("--end-slack", type=float, nargs=2, default=[10.0, 15.0], metavar=("DEG", "MM"),
                    help="when nothing follows the whole demo, end the motion early, every part within DEG / MM of "
                         "its final pose (PlanConfig.end_slack_deg, end_slack_m)")  # fmt: skip
    pl.add_argument("--no-end-slack", action="store_true", help="follow the whole demo or fail")
    pl.add_argument("--short-lever", type=float, default=0.4, metavar="FRACTION",
                    help="grasps on a turning jointed part closer to its turn axis than FRACTION × its farthest point "
                         "rank after the others of their tier (PlanConfig.short_lever_fraction; 0: off)")  # fmt: skip
    pl.add_argument("--root-still", action="store_true",
                    help="plan every part's motion relative to the root held at its first-frame pose, unless a hand "
                         "held the root (PlanConfig.root_still; off: the object-frame track)")  # fmt: skip
    pl.add_argument("--seed", type=int, default=0)
    pl.add_argument("--rerun", action="store_true", help="also write plan.rrd (robot following the plan with the object)")
    pl.add_argument("--overwrite", action="store_true", help="replace an existing plan")
    pl.set_defaults(func=cmd_plan)

    sm = sub.add_parser("simulate", help="execute a RobotPlan in MuJoCo with the studio object; success per stage")
    sm.add_argument("plan", help="RobotPlan directory (plan.npz + plan.json, from `rsrd-jax plan`)")
    sm.add_argument("--studio", required=True, metavar="DIR",
                    help="studio object directory (object.json, robot_view/gt.json, demo/gt/part_poses.npz)")  # fmt: skip
    sm.add_argument("--out", required=True, help="output directory (sim.json, sim.npz, sim.mp4, sim.rrd)")
    sm.add_argument("--video", action="store_true", help="record the robot-view camera into sim.mp4")
    sm.add_argument("--rerun", action="store_true", help="write sim.rrd (robot + object over time)")
    sm.add_argument("--root", choices=("auto", "free", "weld"), default="auto",
                    help="object root resting free on the table, welded to it, or auto (default: free "
                         "when the object rests stably on its own, else welded)")  # fmt: skip
    sm.add_argument("--start", choices=("pregrasp", "home"), default="pregrasp",
                    help="start at the plan's pre-grasp (default) or at home with an unplanned transit")  # fmt: skip
    sm.add_argument("--joint-speed", type=float, default=0.8, help="largest commanded arm joint speed (rad/s)")
    sm.add_argument("--seat-shift", type=float, default=0.01, metavar="M",
                    help="compliant seating: largest shift (m) the arm yields along the jaw axis while the jaw "
                         "closes, kept through the motion (0: a stiff arm, the jaw stalls on the first finger)")
    sm.add_argument("--symmetric-release", action="store_true",
                    help="open both fingers about the TCP on release (default: each finger opens only into free "
                         "space and the arm moves toward the one that opens more)")  # fmt: skip
    sm.add_argument("--quiet", action="store_true", help="no progress bar")
    sm.add_argument("--overwrite", action="store_true", help="replace an existing sim.json")
    sm.set_defaults(func=cmd_simulate)

    bn = sub.add_parser("bench", help="run the benchmark suite (source checkout): args go to benchmarks.run")
    bn.add_argument("args", nargs=argparse.REMAINDER)
    bn.set_defaults(func=cmd_bench)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from ._cache import enable_compilation_cache

    enable_compilation_cache()
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
