"""The whole pipeline (scan → model → track → register → plan → simulate) on a tiny studio object.

Slow (every stage runs, compiles included); the per-stage tests live beside each stage. This test
checks the stages connect through their on-disk artefacts and that the summary reports each
stage honestly against the studio's ground truth.
"""

import dataclasses
import json

import numpy as np
import pytest

from rsrd_jax.io import load_plan, load_trajectory
from rsrd_jax.pipeline import (PipelineConfig, plan_on_meshes, run_pipeline, studio_hands_in_object_frame,
                               studio_separable)  # fmt: skip
from rsrd_jax.studio import StudioConfig, make_object


@pytest.mark.slow
def test_pipeline_end_to_end_writes_every_artefact(tmp_path):
    cfg = PipelineConfig(scan_views=12, scan_size=(128, 96), demo_frames=12, demo_size=(192, 144), fit_iterations=250,
                         field_iterations=150, max_gaussians=4000, track_steps=20, track_roi=160, init_iters=40,
                         register_seeds=8, rerun=False, sim_video=False, plan_grasp_keyframe_weight=2.0)  # fmt: skip
    rep = run_pipeline("red_box", tmp_path / "run", cfg, log=lambda m: None)
    out = tmp_path / "run"
    for f in ("studio/object.json", "model/model.json", "track/trajectory.npz", "register/registration.json",
              "plan/plan.json", "sim/sim.json", "summary.json"):  # fmt: skip
        assert (out / f).is_file(), f
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["stages"]) == {"init", "traj", "grasp", "exec"}
    assert summary["end_to_end"] == all(summary["stages"].values())
    # the registration is scored against the studio's true pose, and is good enough to grasp with
    assert rep["register"]["error"]["translation_mm"] < 20.0 and rep["register"]["error"]["rotation_deg"] < 10.0
    assert rep["stages"]["init"] is True
    reg = json.loads((out / "register" / "registration.json").read_text())
    seeds = reg["seed_errors"]  # each seed's optimised pose scored against the truth
    assert len(seeds) == 8 and seeds[reg["info"]["best_seed"]]["rotation_deg"] < 15.0, seeds
    traj = load_trajectory(out / "track")
    assert traj.num_frames == 12 and np.all(np.isfinite(traj.T_obj_part))
    plan = load_plan(out / "plan")
    assert plan.result == rep["plan"]["result"] and plan.info["num_parts"] == 2
    # the stages ran with the pipeline's options (recorded in the artefacts)
    assert plan.info["config"]["grasp_keyframe_weight"] == 2.0
    assert plan.info["config"]["collision_margin"] == pytest.approx(cfg.plan_collision_margin)
    assert traj.meta["config"]["hinge_axes"] is True and traj.meta["config"]["joints"] is True
    for k in ("studio", "build", "track", "register", "plan", "simulate"):
        assert rep[k]["time_s"] > 0


def test_pipeline_track_config_carries_the_pipeline_options():
    on, off = PipelineConfig().track_config(), PipelineConfig(track_hinge_axes=False, track_joints=False).track_config()
    assert on.hinge_axes and on.joints and not off.hinge_axes and not off.joints
    # the registration's seeds (the pipeline and experiments.registration_seeds share them)
    assert PipelineConfig(register_seeds=12).register_config().yaw_seeds == 12
    assert on.weights.motion == PipelineConfig().track_motion and on.lr_start == PipelineConfig().track_lr_start
    assert on.separable_motion == PipelineConfig().track_motion_separable
    assert PipelineConfig(track_motion_separable=0.5).track_config().separable_motion == 0.5


def test_hand_keypoints_follow_the_tracked_object_frame(tmp_path):
    """Studio fingertips (demo camera frame) moved by the object pose land on the contact part in the
    object frame: with the *true* object pose they coincide with the studio's object-frame points."""
    root = tmp_path / "red_box"
    make_object("red_box", root, StudioConfig(scan_views=4, scan_size=(64, 48), demo_frames=5, demo_size=(96, 72), parts=("scan", "demo")))
    import jax.numpy as jnp
    import jaxlie

    with np.load(root / "demo/gt/part_poses.npz") as z:
        T_cw = jaxlie.SE3(jnp.asarray(z["T_cam_world"], jnp.float32))
        T_ds = jaxlie.SE3(jnp.asarray(z["T_demo_scan"], jnp.float32))
    # the model's object frame is the scan world: T_cam_obj = T_cam_world · T_demo_scan
    T_cam_obj = np.tile(np.asarray((T_cw @ T_ds).wxyz_xyz), (5, 1))
    kp = studio_hands_in_object_frame(root, T_cam_obj)
    with np.load(root / "demo/gt/hand_keypoints.npz") as z:
        kw = z["keypoints_world"]
    M = np.asarray(T_ds.inverse().as_matrix(), np.float64)
    expect = kw @ M[:3, :3].T + M[:3, 3]
    np.testing.assert_allclose(kp, expect, atol=1e-5)


def test_the_pipeline_plans_on_the_gaussian_extents_only_when_the_centres_give_no_plan():
    """`plan_on_meshes`: a plan found on the centres' meshes is kept and the extents are never
    computed; a failed one is followed by a plan on the extents (reported as a fallback, with the
    failed plan); the fallback can be turned off, and `plan_extent_meshes` plans on the extents
    at once."""
    from types import SimpleNamespace

    calls = []

    def planner(found_on):
        def run(mesh):
            calls.append("centres" if mesh is None else "extents")
            return SimpleNamespace(success=calls[-1] in found_on, result_name="collision", message="m")
        return run

    def extents():
        calls.append("extent points")
        return ["points"]

    cfg = PipelineConfig()
    assert cfg.plan_extent_fallback and not cfg.plan_extent_meshes
    plan, meshes, first = plan_on_meshes(planner({"centres", "extents"}), extents, cfg, log=lambda m: None)
    assert plan.success and meshes == "centres" and first is None and calls == ["centres"]
    calls.clear()
    plan, meshes, first = plan_on_meshes(planner({"extents"}), extents, cfg, log=lambda m: None)
    assert plan.success and meshes == "extents (fallback)" and not first.success
    assert calls == ["centres", "extent points", "extents"]
    calls.clear()
    plan, meshes, first = plan_on_meshes(planner({"extents"}), extents, dataclasses.replace(cfg, plan_extent_fallback=False))
    assert not plan.success and meshes == "centres" and first is None and calls == ["centres"]
    calls.clear()
    plan, meshes, first = plan_on_meshes(planner({"extents"}), extents, dataclasses.replace(cfg, plan_extent_meshes=True))
    assert plan.success and meshes == "extents" and first is None and calls == ["extent points", "extents"]


def test_robot_trial_rates_are_cumulative():
    """A trial counts at a stage only if it passed that stage and every one before it (the
    simulator scores Exec even after a Grasp failure); markdown and totals agree."""
    from experiments.robot_trials import markdown, stage_rates, summarise

    ok = {"init": True, "traj": True, "grasp": True, "exec": True}
    slip = {"init": True, "traj": True, "grasp": False, "exec": True}  # turned in the jaw, ended right
    noplan = {"init": True, "traj": False, "grasp": None, "exec": None}
    trials = [dict(stages=s, end_to_end=all(bool(v) for v in s.values()), failure=f, reason="")
              for s, f in ((ok, None), (slip, "grasp"), (noplan, "traj"))]
    r = stage_rates(trials)
    assert r == pytest.approx({"init": 1.0, "traj": 2 / 3, "grasp": 1 / 3, "exec": 1 / 3, "end_to_end": 1 / 3})
    res = summarise({"objects": {"a": {"trials": trials[:2], "tracking_add_obj_mm": 1.0},
                                 "b": {"trials": trials[2:], "tracking_add_obj_mm": 2.0}}})
    assert res["objects"]["a"]["rates"]["exec"] == 0.5 and res["total"]["exec"] == pytest.approx(1 / 3)
    assert res["failure_causes"] == {"grasp": 1, "traj": 1}
    assert "| a | 2/2 | 2/2 | 1/2 | 1/2 | 1/2 |" in markdown(res)


def test_robot_trials_table_yaws_cover_the_circle_from_the_studio_yaw():
    """The trials' orientations (shared with experiments.registration_seeds): trial 0 at the
    studio's yaw, then evenly over 360°, wrapped into [-180, 180)."""
    from experiments.robot_trials import table_yaws

    y = np.asarray(table_yaws(-149.17, 10))
    assert y[0] == pytest.approx(-149.17) and np.all((y >= -180.0) & (y < 180.0))
    steps = np.diff(np.unwrap(np.deg2rad(y)))
    np.testing.assert_allclose(np.rad2deg(steps), 36.0, atol=1e-9)
    assert table_yaws(179.0, 2) == pytest.approx([179.0, -1.0])


def test_robot_trials_merge_takes_each_object_from_the_last_run_that_has_it(tmp_path):
    """`--merge`: one table over several runs' JSONs; an object in two files comes from the later
    one; totals are recomputed over the merged trials; the sources are listed."""
    import json

    from experiments.robot_trials import main

    ok = {"init": True, "traj": True, "grasp": True, "exec": True}
    bad = {"init": True, "traj": False, "grasp": False, "exec": False}
    t = lambda s, f: dict(stages=s, end_to_end=f is None, failure=f, reason="")  # noqa: E731
    runs = {"r1": {"a": [t(ok, None), t(bad, "traj")], "b": [t(bad, "traj")]},
            "r2": {"b": [t(ok, None), t(ok, None)]}}  # fmt: skip
    for k, objs in runs.items():
        (tmp_path / f"{k}.json").write_text(json.dumps(
            {"config": {"commit": k}, "objects": {n: {"trials": tr, "tracking_add_obj_mm": 1.0} for n, tr in objs.items()}}))
    assert main(["--merge", str(tmp_path / "r1.json"), str(tmp_path / "r2.json"), "--out", str(tmp_path / "m")]) == 0
    res = json.loads((tmp_path / "m.json").read_text())
    assert res["objects"]["b"]["source"].endswith("r2.json") and len(res["objects"]["b"]["trials"]) == 2
    assert res["total"]["trials"] == 4 and res["total"]["end_to_end"] == pytest.approx(3 / 4)
    assert [m["commit"] for m in res["config"]["merged"]] == ["r1", "r2"]
    md = (tmp_path / "m.md").read_text()
    assert "| a | 2/2 | 1/2 | 1/2 | 1/2 | 1/2 |" in md and "| b | 2/2 | 2/2 | 2/2 | 2/2 | 2/2 |" in md and "r2.json" in md
    with pytest.raises(SystemExit, match="no such file"):
        main(["--merge", str(tmp_path / "nope.json"), "--out", str(tmp_path / "x")])


def test_robot_trials_resume_reuses_only_complete_artefacts_tracked_with_this_config(tmp_path):
    """`--resume` reuses trial 0's studio and model when they are complete, and its track only if
    its stored TrackConfig is the pipeline's: a track made with another motion-prior weight is
    tracked again."""
    from experiments.robot_trials import reusable
    from rsrd_jax.track._track import _config_dict

    cfg = PipelineConfig()
    y0 = tmp_path / "yaw0"
    assert reusable(y0, cfg) == {}
    (y0 / "studio" / "robot_view").mkdir(parents=True)
    (y0 / "studio" / "object.json").write_text("{}")
    assert reusable(y0, cfg) == {"studio_dir": y0 / "studio"}
    (y0 / "model").mkdir()
    (y0 / "model" / "model.json").write_text("{}")
    (y0 / "track").mkdir()
    other = dataclasses.replace(cfg, track_motion=cfg.track_motion + 1.0)
    (y0 / "track" / "trajectory.json").write_text(json.dumps({"config": _config_dict(other.track_config())}))
    assert set(reusable(y0, cfg)) == {"studio_dir", "model_dir"}
    (y0 / "track" / "trajectory.json").write_text(json.dumps({"config": _config_dict(cfg.track_config())}))
    assert reusable(y0, cfg)["track_dir"] == y0 / "track"
    assert cfg.track_config().weights.motion == cfg.track_motion and cfg.track_config().joints == cfg.track_joints


def test_robot_trials_record_a_dirty_commit_only_for_changed_code(tmp_path):
    """The recorded commit is the checkout's HEAD, with ``-dirty`` when a tracked file of the
    package or the script differs (the pathspecs are the repository's, not the script folder's:
    before session 41 a run with edited ``rsrd_jax/`` files recorded a clean commit)."""
    import subprocess

    from experiments.robot_trials import _commit

    git = lambda *a: subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", *a], cwd=tmp_path,  # noqa: E731
                                    check=True, capture_output=True, text=True).stdout.strip()  # fmt: skip
    assert _commit(tmp_path) is None  # not a checkout
    git("init", "-q")
    for f in ("rsrd_jax/a.py", "experiments/robot_trials.py", "README.md"):
        (tmp_path / f).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / f).write_text("x = 1\n")
    git("add", "-A")
    git("commit", "-qm", "c")
    head = git("rev-parse", "HEAD")
    assert _commit(tmp_path) == head
    (tmp_path / "README.md").write_text("changed\n")  # not code
    (tmp_path / "rsrd_jax" / "new.py").write_text("")  # untracked
    assert _commit(tmp_path) == head
    for f in ("rsrd_jax/a.py", "experiments/robot_trials.py"):
        (tmp_path / f).write_text("x = 2\n")
        assert _commit(tmp_path) == head + "-dirty"
        git("checkout", "--", f)
    assert _commit(tmp_path) == head


def test_tracking_table_pipeline_rows_are_the_pipelines_tracking():
    """The table's "pipeline" row tracks as `rsrd-jax demo` does (`PipelineConfig.track_config()`,
    with the studio fingertips), its ablations drop the hand term or the motion prior, and the
    RSRD rows keep the library defaults."""
    from experiments.tracking_table import row_config
    from rsrd_jax.track import LossWeights, TrackConfig

    pipe = PipelineConfig()
    assert row_config("pipeline") == (pipe.track_config(), pipe.track_hands)
    cfg, hands = row_config("pipeline − both")
    assert not hands and cfg.weights == LossWeights() and cfg.joints == pipe.track_joints and cfg.lr_start == pipe.track_lr_start
    assert row_config("pipeline − hands") == (pipe.track_config(), False)
    assert row_config("RSRD (ours)") == (TrackConfig(), False)
    assert row_config("no ARAP", quick=True)[0].smooth_iters == 10 and row_config("no ARAP")[0].weights.arap == 0.0
    # `--track-set`: fields set on top of the row's
    over = row_config("pipeline", overrides={"seed": 1, "slide_max_turn_deg": None})
    assert over == (dataclasses.replace(pipe.track_config(), seed=1, slide_max_turn_deg=None), pipe.track_hands)
    # a loss weight on top of the row's weights (the pipeline's motion prior and hand depth kept)
    cfg, _ = row_config("pipeline", overrides={"weights.support": 1.0})
    assert cfg.weights == dataclasses.replace(pipe.track_config().weights, support=1.0)
    assert row_config("no ARAP", overrides={"weights.support": 1.0})[0].weights == LossWeights(arap=0.0, support=1.0)


def test_tracking_table_reports_the_initialisations_compile_time_where_recorded():
    """The table's per-part rows give each run's init time with the part JAX spent compiling in
    brackets, and a dash for results recorded before init was timed; the method row's mean is
    over the objects."""
    from experiments.tracking_table import table

    def res(add, timings):
        return {"pipeline": {"add_obj_mm": add, "add_cam_mm": 2 * add, "per_part_add_obj_mm": [add - 1, add + 1],
                             "frames_per_second": 1.234, "timings_s": timings}}  # fmt: skip

    md = table({"red_box": res(2.0, {"init_s": 13.34, "init_compile_s": 5.01}), "frog": res(4.0, {"init_s": 9.0}), "stapler": res(6.0, {})},
               ["pipeline"])  # fmt: skip
    assert "| pipeline | 2.00 (4.0) | 4.00 (8.0) | 6.00 (12.0) | 4.00 |" in md
    assert "| red_box | pipeline | 1.0 / 3.0 | 1.23 | 13.3 (5.0) |" in md
    assert "| frog | pipeline | 3.0 / 5.0 | 1.23 | 9.0 |" in md and "| stapler | pipeline | 5.0 / 7.0 | 1.23 | — |" in md


def test_the_studio_separable_flag_reaches_tracking(tmp_path):
    """A scan does not say whether the parts come apart: the pipeline takes it from the studio's
    object.json (usb_plug: separable; red_box: attached), and `rsrd-jax track` from --separable /
    --no-separable or, by default, the model's metadata."""
    from rsrd_jax.cli import build_parser

    for name, expect in (("usb_plug", True), ("red_box", False)):
        root = tmp_path / name
        make_object(name, root, StudioConfig(scan_views=2, scan_size=(32, 24), parts=("scan",)))
        assert studio_separable(root) is expect
    bad = tmp_path / "bad"
    bad.mkdir()
    with pytest.raises(FileNotFoundError, match="object.json"):
        studio_separable(bad)
    (bad / "object.json").write_text(json.dumps({"separable": "yes"}))
    with pytest.raises(ValueError, match="separable"):
        studio_separable(bad)
    p = build_parser()
    base = ["track", "m", "v", "--out", "o"]
    assert p.parse_args(base).separable is None
    assert p.parse_args(base + ["--separable"]).separable is True
    assert p.parse_args(base + ["--no-separable"]).separable is False


def test_track_cli_hand_options_match_the_library():
    """`rsrd-jax track`'s hand and motion-prior options: off unless asked for (no fingertip source), the weight's
    default is the library's, and bad values are argparse errors."""
    from rsrd_jax.cli import build_parser
    from rsrd_jax.track import LossWeights

    p = build_parser()
    base = ["track", "m", "v", "--out", "o"]
    a = p.parse_args(base)
    assert a.hands == "none" and a.w_hand == LossWeights().hand and a.hand_noise == 0.0
    assert a.w_motion == LossWeights().motion
    a = p.parse_args(base + ["--hands", "studio", "--hand-noise", "2.5", "--w-hand", "0.03", "--w-motion", "0.1"])
    assert (a.hands, a.hand_noise, a.w_hand, a.w_motion) == ("studio", 2.5, 0.03, 0.1)
    with pytest.raises(SystemExit):
        p.parse_args(base + ["--hands", "mediapipe"])
    assert PipelineConfig().track_hands is True


@pytest.mark.parametrize("w", ["-1", "nan", "inf"])
def test_cli_track_refuses_a_negative_or_nan_separable_motion_weight(tmp_path, capsys, w):
    from rsrd_jax.cli import main

    rc = main(["track", str(tmp_path / "no_model"), str(tmp_path / "no_video.mp4"), "--out", str(tmp_path / "t"),
               "--w-motion-separable", w])  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 2 and "--w-motion-separable" in err, err
    assert not (tmp_path / "t").exists()


@pytest.mark.parametrize("still", [False, True])
def test_cli_track_takes_a_separable_motion_weight(tmp_path, monkeypatch, still):
    """`--w-motion-separable` reaches `TrackConfig.separable_motion`, `--hinge-refine`
    `TrackConfig.hinge_refine_deg` (and `PipelineConfig.track_hinge_refine_deg` the pipeline's), and `--still-root`
    `TrackConfig.still_root` (off without it; checked where `track_video` is called; the model
    loader is stubbed to stop there) with `slide_baseline="joint"`; `PipelineConfig.track_still_root`
    reaches the pipeline's `TrackConfig`, whose slide baseline is "joint"."""
    from rsrd_jax.pipeline import PipelineConfig

    import rsrd_jax.track as T
    from rsrd_jax import cli

    seen = {}

    class Stop(Exception):
        pass

    def fake_track(model, demo, cfg, *args, **kw):
        seen["cfg"] = cfg
        raise Stop

    monkeypatch.setattr(T, "track_video", fake_track)
    monkeypatch.setattr("rsrd_jax.parts.load_object_model", lambda p: object())
    monkeypatch.setattr("rsrd_jax.io.read_demo", lambda v, c=None: object())
    with pytest.raises(Stop):
        cli.main(["track", str(tmp_path / "m"), str(tmp_path / "v.mp4"), "--out", str(tmp_path / "t"), "--occluder", "none",
                  "--mono-depth", "none", "--hands", "none", "--w-motion-separable", "2.5", *(["--still-root"] if still else []),
                  *(["--hinge-refine", "12.5"] if still else [])])  # fmt: skip
    assert seen["cfg"].separable_motion == 2.5 and seen["cfg"].still_root is still
    assert seen["cfg"].hinge_refine_deg == (12.5 if still else None)
    assert PipelineConfig(track_hinge_refine_deg=7.0).track_config().hinge_refine_deg == 7.0
    # a held root compares the slide hypotheses with a pass that holds it too
    assert seen["cfg"].slide_baseline == ("joint" if still else "first") and seen["cfg"].still_root_first is False
    assert PipelineConfig(track_still_root=still).track_config().still_root is still
    assert PipelineConfig().track_config().slide_baseline == "joint"
