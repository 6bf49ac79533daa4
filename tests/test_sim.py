"""Simulated execution: a ground-truth plan succeeds by physics, wrong grasps fail at the Grasp
stage, failed/colliding plans are reported and not executed, bad inputs give clear errors."""

import dataclasses
import json
import shutil
from pathlib import Path

import jax.numpy as jnp
import jaxlie
import mujoco
import numpy as np
import pytest

from rsrd_jax.io import ArtefactError, load_plan, save_plan
from rsrd_jax.robot import HOME_Q, load_yumi, servo_ctrl, tcp_poses
from rsrd_jax.sim import (
    SimConfig,
    SimOutcome,
    build_sim_scene,
    load_sim_object,
    oracle_plan,
    simulate_plan,
    tcp_ik,
    with_init,
)
from rsrd_jax.studio import StudioConfig, get_object, make_object

SMALL = StudioConfig(scan_views=1, demo_frames=12, scan_size=(32, 24), demo_size=(32, 24), robot_size=(32, 24))


@pytest.fixture(scope="module")
def stapler(tmp_path_factory):
    """The studio stapler (arm hinged on a base; the demo folds the arm closed by 0.5 rad)."""
    out = tmp_path_factory.mktemp("sim") / "stapler"
    make_object("stapler", out, SMALL)
    return out


@pytest.fixture(scope="module")
def gt_plan(stapler):
    """Ground-truth plan: the demo's own contact on the arm, followed by per-frame IK with the
    object at its true pose."""
    plan = oracle_plan(load_sim_object(stapler))
    assert plan.success, plan.message
    return plan


@pytest.fixture(scope="module")
def gt_result(stapler, gt_plan):
    return simulate_plan(gt_plan, stapler, progress=False)


def test_ground_truth_plan_succeeds_by_physics(stapler, gt_result):
    r = gt_result
    assert r.success and r.outcome == SimOutcome.success, r.reasons
    assert r.stages == {"init": None, "traj": True, "grasp": True, "exec": True}
    # nothing holds the part but friction: the only equality constraints are the finger couplings
    sc = build_sim_scene(load_sim_object(stapler))
    assert sc.model.neq == 2 and np.all(sc.model.eq_type == mujoco.mjtEq.mjEQ_JOINT)
    assert sc.model.jnt_type[sc.object_joints[0]] == mujoco.mjtJoint.mjJNT_FREE  # root rests freely
    assert r.metrics["root"] == "free" and sc.root == "free"
    # independent reference: the catalogue's scripted hinge angle at the demo's start and end vs
    # MuJoCo's recorded hinge qpos (after the free root's 7 entries)
    keys = get_object("stapler").joint_values
    hinge = r.object_qpos[:, 7]
    assert hinge[0] == pytest.approx(float(keys(0.0)[1][0]), abs=0.02)
    assert hinge[-1] == pytest.approx(float(keys(1.0)[1][0]), abs=np.deg2rad(8))
    # the gripper closed on the 30 mm arm and held it (both pads in contact through the motion)
    g = r.metrics["grasp"]
    assert g["jaw_mm"]["right"] == pytest.approx(30.0, abs=3.0)
    assert g["held_fraction"]["right"] > 0.95
    motion = r.phase == 4
    assert r.pad_contact[motion, 0].all()
    assert r.metrics["base_displacement_mm"] < 10.0  # the base rested on the table
    assert r.metrics["realtime_factor"] > 1.0


def test_welded_root_does_not_move(stapler, gt_plan):
    r = simulate_plan(gt_plan, stapler, SimConfig(root="weld"), progress=False)
    assert r.success, r.reasons
    assert r.metrics["base_displacement_mm"] == 0.0 and r.object_qpos.shape[1] == 1


def test_grasp_into_air_fails_at_grasp_stage(stapler):
    obj = load_sim_object(stapler)
    plan = oracle_plan(obj, grasp_offset=np.array([0.0, 0.0, 0.06]))  # 6 cm above the arm
    assert plan.success
    r = simulate_plan(plan, obj, progress=False)
    assert r.outcome == SimOutcome.grasp and r.stages["grasp"] is False and r.executed
    assert "not touching part 1" in r.reasons["grasp"]
    assert r.metrics["grasp"]["jaw_mm"]["right"] < 1.0  # closed on nothing
    assert r.robot_q[r.phase == 4, 14].max() < 5e-4  # the jaw stayed shut: nothing between the fingers


def test_wrong_part_fails_at_grasp_stage(stapler, gt_plan):
    """Grasp the arm but claim the base: contacts are with the wrong part."""
    plan = dataclasses.replace(gt_plan, part=np.array([0, -1]))
    r = simulate_plan(plan, stapler, progress=False)
    assert r.outcome == SimOutcome.grasp and "not touching part 0" in r.reasons["grasp"]
    # bimanual bookkeeping: the right arm pinches the arm (part 1), the left (at home) holds nothing
    both = dataclasses.replace(gt_plan, active=np.array([True, True]), part=np.array([1, 0]))
    r = simulate_plan(both, stapler, progress=False)
    assert r.outcome == SimOutcome.grasp
    assert "left gripper" in r.reasons["grasp"] and "right gripper" not in r.reasons["grasp"]
    assert r.metrics["grasp"]["pads_touching"] == {"right": [True, True], "left": [False, False]}



def test_off_centre_pinch_on_a_welded_part(stapler, gt_plan):
    """With the root welded the hinged arm cannot shift along the jaw axis, so without compliance
    the coupled jaw stalls on the first finger: 4 mm off-centre leaves a ~2 mm gap at the other
    finger (a pinch, within pad_gap; the soft contacts and hinge absorb the rest), 8 mm leaves
    > 5 mm (no pinch). Compliant seating yields to the fingers' net force and centres the 8 mm
    grasp (both pads press, the shift ≈ the offset), and the part then follows the demo."""
    obj = load_sim_object(stapler)
    from rsrd_jax.sim._scene import _mat

    jaw_axis = _mat(gt_plan.tcp_target[0, 0])[:3, 0]  # right arm's TCP x at the grasp
    stiff = SimConfig(root="weld", seat_max_shift=0.0)
    near = simulate_plan(oracle_plan(obj, grasp_offset=0.004 * jaw_axis), obj, stiff, progress=False)
    assert near.stages["grasp"], near.reasons
    gaps = sorted(near.metrics["grasp"]["pad_gap_mm"]["right"])
    assert gaps[0] <= 0.0 and 0.5 < gaps[1] <= 3.0
    far_plan = oracle_plan(obj, grasp_offset=0.008 * jaw_axis)
    far = simulate_plan(far_plan, obj, stiff, progress=False)
    assert far.stages["grasp"] is False and "mm away" in far.reasons["grasp"]
    assert max(far.metrics["grasp"]["pad_gap_mm"]["right"]) > 5.0
    assert far.metrics["grasp"]["seat_shift_mm"]["right"] == 0.0
    seated = simulate_plan(far_plan, obj, SimConfig(root="weld"), progress=False)
    assert seated.success, seated.reasons
    assert max(seated.metrics["grasp"]["pad_gap_mm"]["right"]) <= 0.0  # both pads press
    # the arm yielded back towards the part by about the offset (sign: against the offset)
    assert -9.0 < seated.metrics["grasp"]["seat_shift_mm"]["right"] < -5.0
    assert seated.metrics["grasp"]["held_fraction"]["right"] > 0.9
    # the idle-jaw bound: seating never moves the TCP beyond seat_max_shift
    capped = simulate_plan(far_plan, obj, SimConfig(root="weld", seat_max_shift=0.002), progress=False)
    assert abs(capped.metrics["grasp"]["seat_shift_mm"]["right"]) <= 2.0 + 1e-6
    assert capped.stages["grasp"] is False


def test_failed_or_colliding_plan_is_reported_not_executed(stapler, gt_plan):
    failed = dataclasses.replace(gt_plan, result="collision", message="every candidate collided")
    r = simulate_plan(failed, stapler, progress=False)
    assert r.outcome == SimOutcome.traj and not r.executed and len(r.time) == 0
    assert "collision" in r.reasons["traj"] and r.stages["grasp"] is None
    colliding = dataclasses.replace(gt_plan, min_distance=np.array([0.01, -0.004, 0.02]))
    r = simulate_plan(colliding, stapler, progress=False)
    assert r.outcome == SimOutcome.traj and not r.executed and "collides" in r.reasons["traj"]


def test_init_stage_combines(gt_result):
    r = with_init(gt_result, False, "translation error 41 mm > 20 mm", translation_mm=41.0)
    assert r.outcome == SimOutcome.init and r.stages["init"] is False and r.metrics["init"]["translation_mm"] == 41.0
    assert with_init(gt_result, True, "ok").success
    from rsrd_jax.sim import stage_summary

    trials = [r, gt_result, with_init(gt_result, True, "ok"), {"stages": {"init": True, "traj": True, "grasp": False}}]
    t = stage_summary(trials)
    assert t["trials"] == 4 and t["init"] == {"ok": 3, "of": 4, "rate": 0.75}
    assert t["traj"]["of"] == 3 and t["grasp"] == {"ok": 2, "of": 3, "rate": 2 / 3}
    assert t["exec"]["of"] == 2 and t["end_to_end"] == {"ok": 2, "of": 4, "rate": 0.5}


def test_bad_inputs_give_clear_errors(stapler, gt_plan, tmp_path):
    with pytest.raises(ArtefactError, match="another object"):
        simulate_plan(dataclasses.replace(gt_plan, part=np.array([3, -1])), stapler, progress=False)
    with pytest.raises(ArtefactError, match="3-part object model"):
        simulate_plan(dataclasses.replace(gt_plan, info=dict(gt_plan.info, num_parts=3)), stapler, progress=False)
    with pytest.raises(ArtefactError, match="another demo"):
        simulate_plan(dataclasses.replace(gt_plan, q_video=gt_plan.q_video[:5]), stapler, progress=False)
    with pytest.raises(ArtefactError, match="not found"):
        simulate_plan(gt_plan, tmp_path / "nowhere", progress=False)
    broken = tmp_path / "broken"
    shutil.copytree(stapler, broken)
    (broken / "robot_view" / "gt.json").unlink()
    with pytest.raises(ArtefactError, match="robot_view/gt.json"):
        load_sim_object(broken)
    meta = json.loads((stapler / "object.json").read_text())
    meta["parts"] = meta["parts"][:1]
    (broken / "robot_view" / "gt.json").write_text((stapler / "robot_view" / "gt.json").read_text())
    (broken / "object.json").write_text(json.dumps(meta))
    with pytest.raises(ArtefactError, match="T_obj_part"):
        load_sim_object(broken)


def test_servo_and_ik_match_the_robot_package(stapler):
    """The scene's vectorised servo law equals rsrd_jax.robot.servo_ctrl, and the MuJoCo IK
    reaches a pose given by the JAX forward kinematics."""
    sc = build_sim_scene(load_sim_object(stapler))
    rng = np.random.default_rng(0)
    robot = load_yumi()
    q = HOME_Q + 0.3 * rng.standard_normal(16) * np.r_[np.ones(14), 0, 0]
    qd = rng.standard_normal(16)
    sc.servo_ctrl(q, qd)
    ref = servo_ctrl(robot, q, qd)  # robot-only model: same actuator order and gains
    np.testing.assert_allclose(sc.data.ctrl[sc.actuators], ref[: len(sc.actuators)], atol=1e-12)
    T = np.asarray(tcp_poses(robot, jnp.asarray(q, jnp.float32)))[0]  # right TCP, wxyz_xyz
    from rsrd_jax.sim._scene import _mat

    qs, e_p, e_r = tcp_ik(sc.model, mujoco.MjData(sc.model), sc.robot_qpos, sc.robot_dof, sc.tcp_sites[0], 0, HOME_Q,
                          _mat(T), iterations=300)  # fmt: skip
    assert e_p < 1e-3 and e_r < 1e-2
    T2 = np.asarray(tcp_poses(robot, jnp.asarray(qs, jnp.float32)))[0]
    assert np.linalg.norm(T2[4:] - T[4:]) < 2e-3


def test_cli_simulate_writes_sim_json(stapler, gt_plan, tmp_path):
    from rsrd_jax.cli import main

    save_plan(gt_plan, tmp_path / "plan")
    assert load_plan(tmp_path / "plan").success
    rc = main(["simulate", str(tmp_path / "plan"), "--studio", str(stapler), "--out", str(tmp_path / "sim"), "--quiet"])
    assert rc == 0
    js = json.loads((tmp_path / "sim" / "sim.json").read_text())
    assert js["outcome"] == "success" and js["stages"]["grasp"] is True and js["format"] == "rsrd_jax.sim/1"
    with np.load(tmp_path / "sim" / "sim.npz") as z:
        assert z["part_poses"].shape[1:] == (2, 7)
    rc = main(["simulate", str(tmp_path / "nope"), "--studio", str(stapler), "--out", str(tmp_path / "sim2")])
    assert rc == 2
    rc = main(["simulate", str(tmp_path / "plan"), "--studio", str(stapler), "--out", str(tmp_path / "sim3"),
               "--seat-shift", "-0.01", "--quiet"])  # fmt: skip
    assert rc == 2 and not (tmp_path / "sim3" / "sim.json").exists()
    rc = main(["simulate", str(tmp_path / "plan"), "--studio", str(stapler), "--out", str(tmp_path / "sim4"),
               "--seat-shift", "0", "--quiet"])  # fmt: skip
    assert rc == 0
    assert json.loads((tmp_path / "sim4" / "sim.json").read_text())["metrics"]["grasp"]["seat_shift_mm"] == {"right": 0.0}
    rc = main(["simulate", str(tmp_path / "plan"), "--studio", str(stapler), "--out", str(tmp_path / "sim5"),
               "--symmetric-release", "--quiet"])  # fmt: skip
    assert rc == 0
    release = json.loads((tmp_path / "sim5" / "sim.json").read_text())["metrics"]["release"]
    assert release["sided_openings"] == {"right": 0} and release["shift_mm"] == {"right": 0.0}



def test_video_and_rerun_outputs(stapler, gt_plan, tmp_path):
    import cv2

    from rsrd_jax.sim import log_sim_rerun, save_sim_result

    cfg = SimConfig(fps=10.0, video_size=(64, 48))
    r = simulate_plan(gt_plan, stapler, cfg, video=True, progress=False)
    assert r.success and r.frames.shape[1:] == (48, 64, 3) and len(r.frames) == len(r.time)
    assert r.frames.std() > 5  # not a blank image
    paths = save_sim_result(r, tmp_path, fps=cfg.fps)
    cap = cv2.VideoCapture(str(paths["mp4"]))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == len(r.frames)
    cap.release()
    rrd = log_sim_rerun(r, stapler, tmp_path / "sim.rrd", cfg)
    assert rrd.stat().st_size > 10_000



def test_friction_holds_the_part_frictionless_pads_slip(tmp_path):
    """The nerf gun's slide is pulled back 4 cm by a pinch on its sides: with the pads' friction
    the part follows the gripper; with (nearly) frictionless pads and part it slips out and the
    Grasp stage fails. The gun stands on its grip in the studio's pose and topples when free, so
    ``root="auto"`` welds it."""
    make_object("nerf_gun", tmp_path / "gun", SMALL)
    obj = load_sim_object(tmp_path / "gun")
    plan = oracle_plan(obj)
    held = simulate_plan(plan, obj, progress=False)
    assert held.metrics["root"] == "weld" and "not a resting pose" in held.metrics["root_note"]
    assert held.success, held.reasons
    assert held.metrics["grasp"]["slip_mm"]["right"] < 3.0
    slide = held.object_qpos[:, 0]
    assert slide[-1] == pytest.approx(float(get_object("nerf_gun").joint_values(1.0)[1][0]), abs=0.01)
    slip = simulate_plan(plan, obj, SimConfig(root="weld", pad_friction=1e-3, object_friction=1e-3), progress=False)
    assert slip.outcome == SimOutcome.grasp and "slipped" in slip.reasons["grasp"]
    assert slip.metrics["grasp"]["slip_mm"]["right"] > 15.0


@pytest.mark.slow
def test_planner_ground_truth_plan_succeeds_in_sim(stapler, tmp_path):
    """The planner's plan from the studio's ground-truth trajectory and true object pose (the
    full search: grasp sampling, LM, collision checks, approach) succeeds in simulation, with the
    demo's strict check (pads touch only the grasped part, 3 mm margin). With pads allowed 10 mm
    into the other parts (``hand_tolerance`` 0.01) the plan still succeeds but pushes the base
    14.8 mm."""
    from rsrd_jax.plan import PlanConfig, plan_robot, studio_plan_inputs

    inp = studio_plan_inputs(stapler)
    cfg = PlanConfig(num_keyframes=8, approach_steps=4, chunk_size=64, max_iterations=40, approach_candidates=4,
                     collision_margin=0.003, parts=(1,))  # fmt: skip
    plan = plan_robot(load_yumi(), inp.part_points, inp.T_obj_part, inp.T_robot_obj, hands=inp.hands, config=cfg)
    assert plan.success, plan.message
    save_plan(plan, tmp_path / "plan")
    r = simulate_plan(load_plan(tmp_path / "plan"), stapler, progress=False)
    assert r.success, r.reasons
    assert r.metrics["base_displacement_mm"] < 10.0


def test_approach_uses_the_plans_finger_opening(stapler, gt_plan, gt_result):
    """The approach is made with the jaw the plan's ``q_approach`` gripper columns ask for (the
    planner opens it to the grasp width + 2 × ``approach_clearance``), read back from MuJoCo's
    finger joints during the approach phase."""
    a = int(np.flatnonzero(gt_plan.active)[0])
    qa = np.array(gt_plan.q_approach, float)
    qa[:, 14 + a] = 0.02
    r = simulate_plan(dataclasses.replace(gt_plan, q_approach=qa), stapler, progress=False)
    fingers = r.robot_q[r.phase == 2, 14 + a]
    assert len(fingers) and np.abs(fingers - 0.02).max() < 1.5e-3
    base = gt_result.robot_q[gt_result.phase == 2, 14 + a]
    expect = min(max(float(gt_plan.q_approach[0, 14 + a]), 0.0), HOME_Q[14 + a])
    assert np.abs(base - expect).max() < 1.5e-3 and abs(expect - 0.02) > 3e-3


def test_release_keeps_opening_while_a_pad_is_on_the_part(tmp_path):
    """Regression (session 30): a tracked toy_drawer plan (robot trials, table yaw -149°; the
    plan is `tests/data/toy_drawer_release_plan`) pinches the knob with the jaw nearly vertical.
    After one opening of ``release_clearance`` the knob still rested on the lower pad and the
    retreat dragged the drawer from 44 to 70 mm (Exec failed, 19.7 mm from the demo's end). With
    the release opening further while a pad is within ``release_gap`` of the part, the retreat
    leaves the drawer where the motion ended (the demo's final pose within tolerance)."""
    studio = tmp_path / "toy_drawer"
    make_object("toy_drawer", studio, StudioConfig(seed=0, demo_size=(32, 24), robot_size=(32, 24),
                                                   parts=("demo", "robot_view")))  # fmt: skip
    plan = load_plan(Path(__file__).parent / "data" / "toy_drawer_release_plan")
    once = simulate_plan(plan, studio, SimConfig(release_step=0.0), progress=False)
    more = simulate_plan(plan, studio, progress=False)
    for r in (once, more):
        assert r.stages["grasp"], r.reasons
    slide = lambda r: r.object_qpos[:, 7]  # noqa: E731  (the drawer's slide after the free root's 7)
    end = lambda r: slide(r)[r.phase == 4][-1]  # noqa: E731
    assert once.stages["exec"] is False and slide(once)[-1] - end(once) > 0.015  # dragged out by the retreat
    assert once.metrics["release"]["further_openings"]["left"] == 0
    assert more.metrics["release"]["further_openings"]["left"] >= 1
    assert more.metrics["release"]["jaw_mm"]["left"] > once.metrics["release"]["jaw_mm"]["left"] + 2.0
    assert abs(slide(more)[-1] - end(more)) < 0.003
    assert more.success, more.reasons


def test_release_sets_down_a_part_resting_on_the_lower_pad(tmp_path):
    """Regression (session 48): a tracked toy_drawer plan of session 47's robot trials (table yaw
    −113.17°; `tests/data/toy_drawer_lower_plan`) pinches the drawer with the jaw nearly
    vertical and pulls the drawer out, tilting the cabinet up. Opened fully, the jaw's lower pad
    still carried the drawer (0.15 mm in) and the retreat dragged the drawer to its 70 mm stop,
    20 mm past the demo (Exec failed). Lowering the arm toward that pad's outer side
    (``release_lower``) sets the cabinet down: both pads end off the part (MuJoCo's pad
    distances) and the retreat leaves the drawer where the motion ended (its slide joint)."""
    studio = tmp_path / "toy_drawer"
    make_object("toy_drawer", studio, StudioConfig(seed=0, demo_size=(32, 24), robot_size=(32, 24),
                                                   robot_object_yaw_deg=-113.17, parts=("demo", "robot_view")))  # fmt: skip
    plan = load_plan(Path(__file__).parent / "data" / "toy_drawer_lower_plan")
    stay = simulate_plan(plan, studio, SimConfig(release_lower=0.0), progress=False)
    low = simulate_plan(plan, studio, progress=False)
    slide = lambda r: r.object_qpos[:, 7]  # noqa: E731  (the drawer's slide after the free root's 7)
    end = lambda r: slide(r)[r.phase == 4][-1]  # noqa: E731
    for r in (stay, low):
        assert r.stages["grasp"], r.reasons
        assert r.metrics["release"]["jaw_mm"]["left"] > 49.0  # opened fully
    assert end(stay) == pytest.approx(end(low), abs=1e-9)  # the same motion; only the release differs
    assert min(stay.metrics["release"]["pad_gap_mm"]["left"]) < 0.0 and stay.metrics["release"]["lowered_mm"]["left"] == 0.0
    assert stay.stages["exec"] is False and slide(stay)[-1] - end(stay) > 0.005  # dragged out by the retreat
    assert 0.0 < low.metrics["release"]["lowered_mm"]["left"] <= 1000 * SimConfig().release_lower
    assert min(low.metrics["release"]["pad_gap_mm"]["left"]) >= 1000 * SimConfig().release_gap
    assert abs(slide(low)[-1] - end(low)) < 0.002
    assert low.success, low.reasons


@pytest.mark.parametrize("name, yaw, part", [("red_box", None, 1), ("scissors", 102.83, 1)])
def test_a_sided_release_leaves_the_object_where_the_motion_ended(tmp_path, name, yaw, part):
    """Regression (session 43): two tracked robot-trial plans (`tests/data/{name}_release_plan`;
    red_box at the default table yaw, scissors at 102.83°) end with a finger pad that has an
    object surface on its outer side: red_box's lower pad lies between the lid it pinched and the
    box, scissors' pad sits in the blade's ring hole next to the far wall. Opening both fingers
    about the TCP pressed that pad into the object: red_box's box was dragged by the retreat
    (tilted > 10°, the lid ended > 15° off the demo's final angle though the motion ended within
    7.5°), the scissors' far wall was pushed (the blade turned > 8° more after the motion). A
    sided release keeps that pad still and opens the other: the object stays where the motion
    left it (MuJoCo's part poses: within 2° of the motion's end, red_box's box turned < 3° since)
    and Exec passes."""
    studio = tmp_path / name
    make_object(name, studio, StudioConfig(seed=0, demo_size=(32, 24), robot_size=(32, 24), robot_object_yaw_deg=yaw,
                                           parts=("demo", "robot_view")))  # fmt: skip
    plan = load_plan(Path(__file__).parent / "data" / f"{name}_release_plan")
    both = simulate_plan(plan, studio, SimConfig(release_sided=False), progress=False)
    sided = simulate_plan(plan, studio, progress=False)
    a = ("right", "left")[int(np.flatnonzero(plan.active)[0])]
    for r in (both, sided):
        assert r.stages["grasp"], r.reasons
    end = lambda r: r.metrics["exec"]["end_of_motion_error_deg"][part]  # noqa: E731
    fin = lambda r: r.metrics["exec"]["final_error_deg"][part]  # noqa: E731
    assert end(both) == pytest.approx(end(sided), abs=1e-6)  # the same motion; only the release differs
    assert both.stages["exec"] is False and fin(both) - end(both) > 8.0, both.metrics["exec"]
    assert both.metrics["release"]["sided_openings"][a] == 0 and both.metrics["release"]["shift_mm"][a] == 0.0
    assert sided.metrics["release"]["sided_openings"][a] >= 1 and abs(sided.metrics["release"]["shift_mm"][a]) >= 2.0
    assert abs(fin(sided) - end(sided)) < 2.0, sided.metrics["exec"]

    def root_turn(r) -> float:  # the root's turn (deg) from the motion's end to the end
        R = [jaxlie.SO3(jnp.asarray(r.part_poses[i, 0, :4])) for i in (np.flatnonzero(r.phase == 4)[-1], -1)]
        return float(np.rad2deg(np.linalg.norm(np.asarray((R[0].inverse() @ R[1]).log()))))

    assert sided.success, sided.reasons
    if name == "red_box":  # the box: dragged by the retreat, or left in place
        assert root_turn(both) > 10.0 and root_turn(sided) < 3.0, (root_turn(both), root_turn(sided))


def test_a_sided_release_still_lets_go_when_neither_pad_has_room(tmp_path):
    """Regression (session 44): a tracked plan of the demo-sized stapler at the default table yaw
    (`tests/data/stapler_release_plan`, planned with a 6 mm pad clearance on the approach, an
    experiment of that session recorded in its config as `approach_pad_margin`, not a planner
    option) ends with one pad between the arm and the base and the
    other in the arm's slot, each with an object surface on its outer side within its opening
    step. The sided release then opened neither finger and retreated with the grip still
    squeezing the arm (the jaw 17.7 mm, narrower than the 18.9 mm it closed to). Now the first
    opening pushes both fingers by ``release_clearance``: the jaw ends wider than it closed to
    (MuJoCo's finger joints; 20.4 mm, the arm and base stop the fingers). The plan still fails
    Exec: the pads stay on the arm and the retreat drags the stapler (77 mm)."""
    studio = tmp_path / "stapler"
    make_object("stapler", studio, StudioConfig(seed=0, demo_frames=30, demo_size=(32, 24), robot_size=(32, 24),
                                                parts=("demo", "robot_view")))  # fmt: skip
    plan = load_plan(Path(__file__).parent / "data" / "stapler_release_plan")
    r = simulate_plan(plan, studio, progress=False)
    assert r.stages["grasp"], r.reasons
    a = ("right", "left")[int(np.flatnonzero(plan.active)[0])]
    assert r.metrics["release"]["jaw_mm"][a] > r.metrics["grasp"]["jaw_mm"][a] + 1.0, r.metrics
    assert r.metrics["release"]["sided_openings"][a] == 0  # both fingers pushed, no shift
    assert r.metrics["release"]["shift_mm"][a] == 0.0


def _planned_from_ground_truth(root, square: bool = False, config=None):
    """The planner's plan from a studio object's ground truth (true part surfaces, trajectory
    and table pose; a separable object's parts free, as the pipeline passes them) with the
    pipeline's 3 mm clearance (and square pinches preferred if asked), or with `config`; asserts
    that it was found."""
    from rsrd_jax.plan import PlanConfig, plan_robot, studio_plan_inputs

    inp = studio_plan_inputs(root)
    cfg = PlanConfig(collision_margin=0.003)
    if config is None:
        config = cfg.with_square_grasps() if square else cfg
    plan = plan_robot(load_yumi(), inp.part_points, inp.T_obj_part, inp.T_robot_obj, hands=inp.hands, config=config,
                      free_parts=inp.free_parts)
    assert plan.success, plan.message
    return plan


@pytest.mark.slow
@pytest.mark.parametrize("name", [
    "red_box", "nerf_gun",
    pytest.param("scissors", marks=pytest.mark.xfail(strict=True, reason="KNOWN FAILURE (issue 8): with a 3 mm margin "
                                                     "no mesh grasp of the blade seats; a top-down one plans (session "
                                                     "41) but the blade turns 19.5 deg in the pinch and ends 18.2 deg "
                                                     "from the demo's final angle")),
    "sunglasses",  # since session 46: the folded temple ends 7 mm behind the frame, where no gripper fits (end slack)
    pytest.param("bear", marks=pytest.mark.xfail(strict=True, reason="KNOWN FAILURE (issue 8): with a 3 mm margin no "
                                                 "approach to the arm clears the torso")),
    "stapler",
    pytest.param("led_light", marks=pytest.mark.xfail(strict=True, reason="KNOWN FAILURE (issue 8, since session 51): "
                                                      "the open-pad check at seating (approach_grasp_pads_margin) backs "
                                                      "the chosen tab pinch off until its open pads clear the panel, "
                                                      "and there its tips end above the tab: no pad touches it; a cap "
                                                      "on that back-off is not done")),
    "wire_cutter",
    "usb_plug",  # passes since session 51 (the open-pad check changed its plan; not analysed): was 19.7 deg off
    "toy_drawer", "frog",
])  # fmt: skip
def test_every_studio_demo_succeeds_in_simulation_from_ground_truth(tmp_path, name):
    """The planner's plan from each studio demo's ground truth (true part trajectory, part
    surfaces and table pose; the pipeline's 3 mm clearance from the object, PlanConfig's default
    grasps: the pipeline's square pinches, see the frog test below) executed in MuJoCo
    passes Traj, Grasp and Exec: what the robot trials ask of the tracked and registered inputs,
    with perfect inputs. Ground truth at 30 demo frames, 4 scan views (only the robot view and the
    demo's poses are used)."""
    root = tmp_path / name
    make_object(name, root, StudioConfig(scan_views=4, scan_size=(64, 48), demo_frames=30, demo_size=(96, 72),
                                         robot_size=(64, 36), robot_object_yaw_deg=0.0))  # fmt: skip
    plan = _planned_from_ground_truth(root)
    save_plan(plan, tmp_path / "plan")
    r = simulate_plan(load_plan(tmp_path / "plan"), root, progress=False)
    assert r.success, r.reasons


@pytest.mark.slow
def test_square_pinches_pull_the_usb_plug_out_upright(tmp_path):
    """usb_plug's ground-truth plan fails Exec by default (the plug turns ~20° as the jaw
    closes on it at a tilt the 45° cone allows, see the xfail above); preferring square pinches
    (patch normals, 15° cone) the pinch keeps it upright and every stage passes."""
    root = tmp_path / "usb_plug"
    make_object("usb_plug", root, StudioConfig(scan_views=4, scan_size=(64, 48), demo_frames=30, demo_size=(96, 72),
                                               robot_size=(64, 36), robot_object_yaw_deg=0.0))  # fmt: skip
    plan = _planned_from_ground_truth(root, square=True)
    r = simulate_plan(plan, root, progress=False)
    assert r.success, r.reasons
    assert r.metrics["grasp"]["slip_deg"][("right", "left")[int(np.flatnonzero(plan.active)[0])]] < 5.0


@pytest.mark.slow
def test_the_pipelines_planner_pulls_the_free_plug_out_square_and_rolled(tmp_path):
    """usb_plug's ground truth with the pipeline's planner settings (square pinches with RSRD's
    45° cone): as a free part (the pipeline passes a separable object's parts) the plug is
    pinched within 15° of its faces and by a grasp that need not turn it about the jaw's axis,
    and every stage passes; planned as if a joint held it, the pinch 24° off its faces rolls and
    yaws it as the jaw closes and it ends over the 15° tolerance."""
    from rsrd_jax.pipeline import PipelineConfig, _plan_config
    from rsrd_jax.plan import plan_robot, studio_plan_inputs

    root = tmp_path / "usb_plug"
    make_object("usb_plug", root, StudioConfig(scan_views=4, scan_size=(64, 48), demo_frames=30, demo_size=(96, 72),
                                               robot_size=(64, 36), robot_object_yaw_deg=0.0))  # fmt: skip
    inp = studio_plan_inputs(root)
    assert inp.free_parts == (0, 1)
    runs = {}
    for free in (inp.free_parts, None):
        plan = plan_robot(load_yumi(), inp.part_points, inp.T_obj_part, inp.T_robot_obj, hands=inp.hands,
                          config=_plan_config(PipelineConfig()), free_parts=free)  # fmt: skip
        assert plan.success, plan.message
        runs[free is None] = (plan, simulate_plan(plan, root, progress=False))
    (plan, r), (_, r_held) = runs[False], runs[True]
    assert plan.info["chosen"]["twisting_grasp"] is False
    assert r.success, r.reasons
    assert r_held.stages["grasp"] and not r_held.stages["exec"]
    assert r_held.metrics["exec"]["final_error_deg"][1] > r.metrics["exec"]["final_error_deg"][1] + 5.0


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="KNOWN FAILURE (issue 8): with the pipeline's square pinches (45° cone) the "
                   "frog's bimanual plan takes a spread grasp on a leg, which turns 22° in the jaw (limit 20°)")
def test_frog_from_ground_truth_with_the_pipelines_planner(tmp_path):
    """The frog's ground-truth plan (30 demo frames) with the pipeline's planner settings
    (`pipeline._plan_config(PipelineConfig())`: 3 mm clearance, square pinches with RSRD's 45°
    cone) passes every stage in simulation. It does not: the tracked frog passes 10/10 with
    them over 10 table orientations, this ground truth fails Grasp (with PlanConfig's default
    grasps it passes, the parametrised test above)."""
    from rsrd_jax.pipeline import PipelineConfig, _plan_config

    root = tmp_path / "frog"
    make_object("frog", root, StudioConfig(scan_views=4, scan_size=(64, 48), demo_frames=30, demo_size=(96, 72),
                                           robot_size=(64, 36), robot_object_yaw_deg=0.0))  # fmt: skip
    plan = _planned_from_ground_truth(root, config=_plan_config(PipelineConfig()))
    r = simulate_plan(plan, root, progress=False)
    assert r.success, r.reasons


def test_a_free_part_is_scored_where_the_motion_ends(tmp_path):
    """usb_plug's plug is in the demonstrator's hand, in the air, on the video's last frame: the
    robot's release drops it, so Exec scores it where the motion ends (still held); the recorded
    last pose, on the table, is far from the demo's."""
    root = tmp_path / "usb_plug"
    make_object("usb_plug", root, dataclasses.replace(SMALL, robot_object_yaw_deg=0.0))
    obj = load_sim_object(root)
    r = simulate_plan(_planned_from_ground_truth(root), obj, progress=False)
    assert r.stages["grasp"], r.reasons
    ex = r.metrics["exec"]
    assert ex["final_error_mm"][1] == ex["end_of_motion_error_mm"][1]
    assert ex["final_error_deg"][1] == ex["end_of_motion_error_deg"][1]
    z_motion_end = r.part_poses[r.phase == 4][-1, 1, 6]
    assert z_motion_end - r.part_poses[-1, 1, 6] > 0.03  # released in the air, it fell
    demo_end = obj.T_obj_part_demo[-1, 1, 4:]
    T_root = r.part_poses[-1, 0]
    last_rel = np.asarray(jaxlie.SE3(jnp.asarray(T_root)).inverse() @ jnp.asarray(r.part_poses[-1, 1, 4:]))
    last_error_mm = 1e3 * np.linalg.norm(last_rel - demo_end)
    assert last_error_mm > ex["final_error_mm"][1] + 30.0  # scoring the last pose would differ


def test_the_progress_bar_survives_a_run_longer_than_its_estimate():
    """A simulation that outlasts its estimated total raises the bar's total instead of crashing
    in tqdm's formatting (which drops a total that `n` passes): four scissors trials crashed so."""
    import io

    from rsrd_jax.sim._execute import advance, sim_progress

    out = io.StringIO()
    bar = sim_progress(1.0, "simulate x", file=out, mininterval=0.0, disable=False)
    for _ in range(30):
        advance(bar, 0.1)  # 3 s against an estimate of 1 s
    bar.refresh()
    assert bar.n == pytest.approx(3.0) and bar.total >= bar.n
    assert "3.0/3.0 sim s" in out.getvalue()
    bar.close()
