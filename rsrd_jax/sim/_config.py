"""Options of the simulated execution (host-side; nothing here is traced)."""

from __future__ import annotations

from typing import Literal

import equinox as eqx


class SuccessConfig(eqx.Module):
    """Thresholds of the per-stage success tests (paper Table 1: Grasp, Exec)."""

    slip_position: float = 0.015
    """Grasp: largest allowed change (m) of the grasped part's origin in the TCP frame between
    the start of the motion and any later step while held."""
    slip_rotation_deg: float = 20.0
    """Grasp: largest allowed change (degrees) of the grasped part's orientation in the TCP frame."""
    pad_gap: float = 0.003
    """Grasp: when the motion starts one pad must press on the intended part and the other be
    within this distance (m) of it (the coupled jaw stalls on the first finger when the part
    cannot shift sideways and the grasp is slightly off-centre)."""
    min_jaw: float = 0.001
    """Grasp: the jaw must stay at least this open (m) on the part; a shut jaw whose fingertips
    press on a surface is not a pinch."""
    final_position: float = 0.015
    """Exec: largest allowed distance (m) between every part's final origin (root frame) and the
    demonstration's final one. Final: after release and retreat, except for a free part
    (separable, e.g. usb_plug's plug), scored where the motion ends, still held (the demonstrator
    still holds it on the video's last frame; released in the air it falls)."""
    final_rotation_deg: float = 15.0
    """Exec: largest allowed angle (degrees) between every part's final orientation (root frame)
    and the demonstration's final one."""
    path_position: float = 0.03
    """Exec ("moved the same way"): largest allowed distance (m) of a moving part from the
    demonstration's pose at the same video frame, over the whole motion."""
    path_rotation_deg: float = 30.0
    """Exec: largest allowed angle (degrees) from the demonstration's pose at the same frame."""
    base_position: float = 0.05
    """Exec: largest allowed displacement (m) of the object's root over the execution (a free root
    may be dragged along; knocking the object away is a failure)."""
    base_rotation_deg: float = 30.0
    """Exec: largest allowed rotation (degrees) of the root (e.g. tipped over)."""
    moving_threshold: float = 0.005
    """A part counts as moved by the demo when its origin moves more than this (m) or it turns
    more than 3° away from its first-frame pose at some frame (root frame)."""


class SimConfig(eqx.Module):
    """Options of :func:`rsrd_jax.sim.simulate_plan`: scene physics, motion timing, recording."""

    root: Literal["auto", "free", "weld"] = "auto"
    """How the object's root part is held: ``"free"`` rests on the table with friction (a free
    joint; it can slide or tip, and the base displacement is reported), ``"weld"`` fixes it to
    the world at the true pose (a simplification the paper's real trials do not have), ``"auto"``
    free when the object rests stably in its scan pose on its own (``stability_time`` with the
    robot away), welded otherwise (e.g. the nerf gun stands on its grip and would topple)."""
    stability_time: float = 0.5
    """``root="auto"``: seconds the free object is simulated alone to test that it rests."""
    stability_tolerance: float = 0.003
    """``root="auto"``: largest displacement (m) of a root geom centre during the test."""
    start: Literal["pregrasp", "home"] = "pregrasp"
    """Where the robot starts: at the plan's pre-grasp (``q_approach[0]``; the transit from home is
    not part of a RobotPlan — RSRD plans it separately with cuRobo's collision-aware motion
    generator), or at ``HOME_Q`` followed by an unplanned joint-space transit (which may hit the
    object, e.g. long objects reach under the home TCPs)."""
    joint_damping: float = 0.05
    """Damping of the object's hinge/slide joints (N·m·s/rad or N·s/m; studio default)."""
    joint_frictionloss: float = 0.01
    """Dry friction of the object's joints (N·m or N; studio default)."""
    object_friction: float = 1.0
    """Sliding friction of the object's geoms (MuJoCo combines pairs by the maximum; the YuMi's
    finger pads have 1.5, the table 1.0)."""
    min_root_mass: float = 0.2
    """With a free root: the root part's density is raised so that it weighs at least this (kg).
    The studio's density (300 kg/m³) makes 10–100 g objects that the friction of their own
    joints drags along the table; real objects (a stapler, a box, a drawer cabinet) are heavier
    or held down. 0 keeps the studio's mass."""
    pad_friction: float | None = None
    """Override of the finger pads' sliding friction (None keeps the MJCF's 1.5; ablations)."""
    object_density: float | None = None
    """Override of the object's density (kg/m³; None keeps the studio's 300)."""
    timestep: float = 0.002
    """Physics step (s)."""
    joint_speed: float = 0.8
    """Largest commanded arm joint speed along every segment (rad/s); the plan's per-frame
    trajectory ``q_video`` is time-scaled so that no joint exceeds it."""
    min_frame_time: float = 1.0 / 30.0
    """Shortest time between two video-frame waypoints (s; the demo's frame period)."""
    settle_time: float = 0.3
    """Time (s) the scene settles at home before moving, and after each gripper command."""
    grip_timeout: float = 1.5
    """Longest time (s) the grippers close before the motion starts anyway."""
    grip_stall_speed: float = 0.002
    """Finger speed (m/s) below which a closing gripper counts as stalled (on the part or empty)."""
    seat_max_shift: float = 0.01
    """Compliant seating: while the jaw closes, each active arm yields along its jaw axis (TCP x)
    to the net force its fingers feel along that axis (an admittance law on what a wrist
    force/torque sensor or the arm's joint-torque estimate measures), so a grasp that is a few mm
    off-centre on a part that cannot shift sideways (a welded root, a hinge) is centred until both
    fingers press. The shift is at most this (m) and is kept, in the TCP frame, through the motion.
    0 disables it (the jaw stalls on the first finger)."""
    seat_speed: float = 0.02
    """Compliant seating: largest yield speed (m/s) along the jaw axis."""
    seat_force: float = 4.0
    """Compliant seating: net jaw-axis force (N) at which the yield speed is ``tanh(1)`` of
    ``seat_speed`` (a closing finger presses with up to the gripper's 20 N)."""
    release_clearance: float = 0.006
    """On release the jaw opens to its width on the part plus this (m), not fully: fully opened
    fingers (50 mm) knock neighbouring parts or tip light objects over."""
    release_step: float = 0.004
    """After the release's settle, while a pad of an active arm is within ``release_gap`` of its
    part, that jaw opens by this much more (m, both fingers together) and settles again
    (``release_settle``), up to fully open: a gripper that keeps opening until its fingers are
    off the part. With one opening of ``release_clearance`` alone, a part that sagged onto the
    lower pad as the jaw opened stayed on it and the retreat dragged it: on the studio toy_drawer
    (tracked plans, session 30) one pad touched the knob after every release and the retreat
    pulled the drawer out by 3–26 mm more. Pads pinned by friction on another surface do not
    open whatever the command (the oracle stapler plan's pads press on the base); the command
    then ends fully open. 0 disables it."""
    release_gap: float = 0.002
    """``release_step``: the distance (m) both pads must keep from the part before the retreat
    (with the pads just off the part, 1 mm, the retreat's servo lag brought one back onto the
    toy_drawer's knob, which it dragged 28 mm)."""
    release_sided: bool = True
    """On release each finger pad opens only into free space: a pad with an object surface on its
    outer side (where it moves as the jaw opens) within its step plus ``release_gap`` moves only
    up to that gap, the other finger opens by what it cannot, and the arm shifts along the jaw
    axis by half the difference (the opening stops when neither can move; when neither has room
    for the first opening, both push by it: a grip that never lets go drags its part away on
    the retreat, as one of the demo-sized stapler's plans did, wedged between the arm and the
    base with its other pad in the arm's slot). A check from the
    fingers' proximity to the object, as pad sensors or the planner's object model would give it.
    False opens both fingers about the TCP (sessions ≤ 42): on tracked robot-trial plans a
    scissors pad in the ring's hole pushed the far wall as the jaw opened (the blade turned
    4–10° more after the motion), and a red_box lower pad between the lid and the box pressed
    the box down and dragged it on the retreat (box tilted 12–80°, lid 18–19° off the demo's
    final angle where the motion ended 6–7° off). Known failure: on a `make demo` stapler plan
    of session 43 the base, lifted by the motion, kept resting on the lower pad with the sided
    release and the retreat dragged it (Exec failed); the symmetric release passed that plan."""
    release_lower: float = 0.012
    """When the release's opening has stopped (the jaw fully open, or no room to open further)
    and a pad still holds its part from its inner side within ``release_gap`` (the part lifted
    by the motion followed the lower pad down as the jaw opened), the arm moves along the jaw
    axis toward that pad's outer side, away from the part, by ``release_step`` and settles
    (``release_settle``), up to this far (m) in all, while the other pad stays ``release_gap``
    plus a step from the part and no object surface lies within that on the pad's outer side
    (a sided release that stopped for lack of room does not lower: on session 47's red_box
    plans that let the lid fall on the pad): the part is set down before the retreat (the
    lowering is part of ``metrics["release"]["shift_mm"]`` and reported alone as
    ``lowered_mm``). Without it, on session 47's tracked toy_drawer plans the cabinet, tilted up
    by the pull, rested on the fully opened lower pad (0.15 mm in) and the retreat dragged the
    drawer to its stop, 20 mm past the demo (Exec failed at all 10 orientations). 0 disables
    it."""
    release_settle: float = 0.1
    """Settle time (s) after each further opening of ``release_step``."""
    retreat_distance: float = 0.08
    """After release, the TCPs back off this far (m) along their approach axis (−gripper z)."""
    disturbance_tolerance: float = 0.01
    """Before the grasp: largest allowed motion (m) of any part point proxy (part origins) caused
    by the transit and approach (otherwise the Grasp stage fails with "object disturbed")."""
    fps: float = 30.0
    """Rate at which states (and video frames) are recorded (Hz of simulated time)."""
    video_size: tuple[int, int] = (320, 240)
    """Width, height of the video frames (pixels)."""
    video_fovy_deg: float = 50.0
    """Vertical field of view of the robot-view camera."""
    success: SuccessConfig = SuccessConfig()
    """Thresholds of the stage tests."""
