"""Candidate search: ranked parts (pairs) × arm assignments × all grasps, solved in vmapped batches
on the banded LM, filtered by tracking error, joint limits and collisions along the whole
trajectory, then an approach motion (pre-grasp → grasp) that must be collision-free too.

Host-side orchestration (numpy, shapes decided here); every solve is one jitted, vmapped call
over a fixed-size chunk of candidates (padded), so each chunk size compiles once.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Sequence
from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Float

from ..grasp import (GraspConfig, MeshConfig, PartGrasps, TopDownConfig, build_part_mesh, merge_grasps,
                     sample_antipodal_grasps, sample_topdown_grasps)
from ..hands import PartRanking, RankConfig, rank_parts
from ..robot import HOME_Q, ObjectGeometry, YumiModel, collision_distances, object_boxes_from_points, tcp_poses
from ._costs import (
    CostParams,
    CostWeights,
    PoseData,
    problem_data,
    strip_robot,
    tcp_errors,
    trajectory_problem,
)
from ._lm import LMResult, SolverConfig, TerminationConfig, TrustRegionConfig, solve_lm
from ._proxy import (
    PartSDF,
    RobotProxy,
    hand_clearance,
    hand_geometry,
    hand_part_mask,
    part_sdf,
    proxy_distances,
    robot_proxy,
)

ARM_NAMES = ("right", "left")
"""Arm index 0 = right (joints 0..6, gripper 14), 1 = left (7..13, 15)."""

STAGES = ("grasp_invalid", "grasp_collision", "unsolved", "solver", "pose_error", "joint_limits", "collision",
          "approach")
"""Rejection stages, in the order they are applied (``grasp_collision``: the free-floating
gripper at the grasp poses along the trajectory, or at the first one with the fingers at the
approach's narrowest opening, hits the table or a part at every seating depth;
``unsolved``: seated grasps beyond ``PlanConfig.max_candidates``, lowest scores)."""


class PlanResult(eqx.Enumeration):
    """Outcome of :func:`plan_robot`."""

    success = "a feasible plan was found"
    no_grasp = "no antipodal grasp was found on the requested parts"
    unreachable = "no grasp candidate tracked the part trajectory within the pose tolerance"
    joint_limits = "every candidate that tracked the trajectory violated joint limits"
    collision = "every remaining candidate collided (self, table or object) along the trajectory"
    approach = "no remaining candidate had a collision-free approach motion"


class PlanConfig(eqx.Module):
    """Options of :func:`plan_robot`."""

    num_keyframes: int = 50
    """Keyframes of the joint trajectory (fewer if the video is shorter; RSRD ≤ 50)."""
    bimanual: bool | Literal["auto"] = "auto"
    """Plan both arms (a ranked (left part, right part) pair) in one 16-DoF solve. ``"auto"``
    decides from the demonstrator's hands (ranked parts, ``hands`` given): bimanual when each hand
    touches a part (its smallest contact distance, :class:`rsrd_jax.hands.PartRanking`, within
    ``bimanual_contact``), the two parts differ and one of them moved; single-arm otherwise
    (one hand, no hands, or ``parts`` given). The decision is in ``info["bimanual"]``. On the
    studio demos a touching hand is 7.4–8.6 mm from its part (the fingertip radius), every
    other part ≥ 15.8 mm; frog (two legs) and usb_plug (hold the socket, pull the plug) are
    bimanual. ``plan_robot(hand_parts=...)`` gives the hands' parts directly (the pipeline passes
    the tracker's 2D hand anchors). A failed bimanual search falls back to one arm."""
    bimanual_contact: float = 0.012
    """``bimanual="auto"``: largest contact distance (m) at which a hand counts as touching a part."""
    parts: tuple[int, ...] | None = None
    """Parts to use (single: tried in this order; bimanual: (left-hand part, right-hand part));
    None = from the hand/motion ranking."""
    max_parts: int = 2
    """Ranked parts (or pairs) tried before giving up."""
    min_motion_fraction: float = 0.2
    """With ranked parts (``parts`` None): a part whose motion relative to its parent part
    (``rank_parts``' ``relative_motion``, time-averaged RMS) is below this fraction of the
    largest part's is not planned for, and a bimanual pair only if its other part moved: a plan
    that holds a part that did not move reproduces nothing of the demo, whatever the hand
    ranking says. On the studio's ground-truth demos the moved parts' motion is 6.8–54.5 mm and
    every other part's is 0; the fingertips of usb_plug's demo rank the still socket first, and
    toy_drawer's planner fell back to its cabinet. 0 keeps every part."""
    arms: tuple[int, ...] = (0, 1)
    """Arm assignments tried (0 right, 1 left); bimanual tries both assignments of a pair."""
    weights: CostWeights = CostWeights()
    """Cost weights. Smoothness weights are per keyframe step at ``smoothness_reference``
    keyframes and rescaled to the actual count (see there)."""
    smoothness_reference: int = 50
    """Keyframe count at which the smoothness weights apply as given (RSRD: 50 keyframes, velocity
    weight 1). With K keyframes the velocity weight is scaled by sqrt((K-1)/(ref-1)) and the
    acceleration weight by ((K-1)/(ref-1))^1.5, so the smoothness cost of a given motion does not
    depend on K (fewer keyframes would otherwise stiffen the trajectory and spoil tracking)."""
    max_iterations: int = 50
    """LM iterations per solve."""
    lambda_initial: float = 0.1
    """Initial LM damping (RSRD 0.1)."""
    chunk_size: int = 160
    """Candidates per vmapped solve (chunks are padded to this size, so each size compiles once;
    grasps rejected before solving are left out, so smaller chunks waste less padding)."""
    position_tolerance: float = 0.01
    """Maximum TCP position error at every keyframe (m)."""
    rotation_tolerance_deg: float = 10.0
    """Maximum TCP rotation error at every keyframe (degrees)."""
    grasp_position_tolerance: float = 0.003
    """Maximum TCP position error at the first keyframe (m): the grasp itself, where the approach
    ends and the fingers close. Tighter than ``position_tolerance``: a grasp 9 mm off along the jaw
    misses a 4 mm scissor blade altogether."""
    grasp_rotation_tolerance_deg: float = 5.0
    """Maximum TCP rotation error at the first keyframe (degrees)."""
    grasp_keyframe_weight: float = 3.0
    """Weight of the first keyframe's pose rows relative to the others (the grasp, held to the
    tighter ``grasp_*_tolerance``). With 1 the solver spreads a trajectory's misfit evenly over the
    keyframes, the grasp included: on tracked scissors (session 23) the 4 best seated grasps missed
    the 3 mm grasp tolerance by 0.3–0.5 mm while staying within 5.4 mm elsewhere, and on the
    studio bear's ground truth (an arm waved 2.2 rad in a quarter of the demo, which the smoothness
    terms cannot follow exactly) all 138 seated grasps tracked within 6–7 mm but missed it by
    2–3 mm; with 3 both meet it (bear: 0.8–1.3 mm) and the bear plans."""
    limit_tolerance: float = 1e-3
    """Allowed joint-limit violation (rad or m)."""
    collision_margin: float = 0.0
    """A distance below this (m) is a collision (self, table, object)."""
    pad_table_margin: float | None = 0.001
    """Clearance (m) the finger pads must keep from the table; None = ``collision_margin``. Below
    the margin so that a fingertip grasp reaches a flat part lying on the table: the pads end
    20 mm past the TCP, so with a 3 mm margin no grasp centre lower than about 4 mm can be
    seated (scissors are 7 mm thick). Reported table distances include the pads' allowance."""
    hand_tolerance: float = 0.0
    """Penetration (m) allowed between the gripper (palm + finger pads) and the parts it must not
    touch (0 = strict). The reported object distance includes this allowance."""
    check_palm_on_grasped_part: bool = True
    """Also check the palm (gripper base) against the grasped part itself (the finger pads may
    touch it); off = the whole gripper may touch its part, as RSRD's filter."""
    sdf_spacing: float = 0.004
    """Node spacing of the parts' signed-distance grids (m), see :func:`part_sdf`."""
    object_radius: float | None = None
    """Ball radius around each part point in the object proxy (m); None = from the point spacing."""
    sample_spacing: float = 0.01
    """Largest spacing of the samples along each robot capsule's axis in the object check (m)."""
    grasp_depths: tuple[float, ...] = (0.0, 0.004, 0.008, 0.012, 0.016, 0.019)
    """Seating: each grasp is backed off along its approach axis by the smallest of these depths
    (m) at which the free-floating gripper clears the table and the parts at every keyframe. The
    pads reach 20 mm past the TCP, so the contact line stays on the pad; deep back-offs are
    fingertip grasps (flat parts on the table, parts next to other parts)."""
    seat_approach_opening: bool = True
    """Seating also requires the gripper to clear the table and the other parts at the first
    keyframe with the fingers at the approach's narrowest opening (``approach_clearance``),
    where the approach ends and the jaw is about to close: a grasp whose open pads hit something
    there is never approachable, and without the check such grasps could fill the
    ``approach_candidates`` that get an approach."""
    max_candidates: int = 480
    """Grasp candidates solved per part and arm: the seated ones (see ``grasp_depths``), best
    grasp score first (RSRD solves 480), the top-down set after all others."""
    approach_distance: float = 0.06
    """Pre-grasp offset along −approach (gripper z) from the first grasp pose (m)."""
    approach_clearance: float | tuple[float | None, ...] | None = (None, 0.01)
    """Finger openings tried for the approach, in this order (list them widest first): each is
    the opening beyond the grasp's half-width (m per finger, capped at fully open; None = fully
    open). Each candidate takes the first opening whose approach is collision-free; a candidate
    earlier in the order wins over a wider opening. Stored in ``RobotPlan.q_approach[:, 14:16]``. A fully open jaw
    (50 mm) around a 4 mm scissors ring puts the open pads onto the neighbouring part, so it
    falls back to 10 mm; with only 10 mm the stapler's tracked-and-registered arm (2–5 mm off,
    sagging on its hinge) met a pad during the demo's approach (16.5 mm disturbance, Grasp
    failed), fully open it does not."""
    approach_pads_clear_part: bool = True
    """The open finger pads must clear the grasped part too (by ``collision_margin``) along the
    approach, at every waypoint but its last (the grasp pose, where they surround the part and
    the proxies' few-millimetre conservatism would reject good grasps: led_light's and red_box's
    ground-truth plans). Off, the pads may brush their part on the way in (before session 28):
    on the demo's stapler a tilted approach slid a pad along the arm's edge (−0.5 to −1 mm on the
    proxies from 12 mm out) and knocked it 10.5 mm in simulation (Grasp failed)."""
    approach_grasp_pads_margin: float | None = -0.001
    """Where the approach ends (the grasp pose, the jaw still open as it arrives) the open finger
    pads must keep at least this distance (m; negative: a penetration allowed) from the grasped
    part's proxy; checked when grasps are seated (with ``seat_approach_opening``: a grasp is backed
    off until it holds, else never seats) and again on each solved approach's last waypoint
    (``pads_in_part_at_grasp``); None: unchecked (sessions before 51). The pads surround the pinched
    part there, so ``approach_pads_clear_part`` and the seating leave them out; this weaker test
    still sees a pad that ends inside the part beside the pinch. −1 mm because the proxies are
    conservative by up to a few millimetres (a 4 cm cube sampled every 8 mm reads 0.1 mm where
    MuJoCo has 5 mm). Studio led_light (session 50's robot trials, tracked and registered): the four
    pinches of the panel's 6 mm tab that closed on nothing ended their approaches with a pad
    3.0–3.7 mm into the panel on the proxies (0.9–1.7 mm into its true box in MuJoCo): closing, the
    pad pushed the panel and the tab slipped out; with this default three of the four pass (6/10
    over the 10 orientations), but the seating may back a grasp off until its open pads clear the
    part, and the fourth, seated 19 mm back, closes above the tab (as led_light's ground-truth plan
    now does; no cap on that back-off yet). The other approaches of those trials (led_light,
    stapler, sunglasses, wire_cutter) ended 0.3–22 mm clear. On the last waypoint the check runs
    the approach's compiled A-waypoint evaluation with every waypoint set to the last."""
    approach_steps: int = 6
    """Waypoints of the approach segment, pre-grasp to grasp inclusive."""
    approach_candidates: int = 32
    """Best trajectory candidates (by cost) whose approach is solved, per tier (best-scored grasps,
    then spread ones). Their approaches are solved in one ``chunk_size`` batch (padded to it), so
    up to half of it costs no more than one; the first candidate in cost order whose approach
    passes wins, so more candidates only add fallbacks."""
    top_k_per_arm: int = 12
    """Bimanual: best single-arm candidates per arm combined (k × k bimanual solves; 144 fill one
    ``chunk_size`` batch, which is padded to 160 anyway), see ``bimanual_per_base``. The best few
    by cost are often rolls of one grasp: on the studio frog all 16 pairs of the best 4 collided
    (arm against arm or part)."""
    bimanual_per_base: int = 1
    """Bimanual: at most this many of an arm's ``top_k_per_arm`` candidates come from one base grasp
    (its rolls and shifts), the rest from the next base grasps in cost order (and only then more
    of the same ones). The cheapest candidates are mostly rolls of one or two grasps, so pairs of
    them differ little: on a tracked frog (session 30, table yaw -5°) all 144 pairs of the best
    12 per arm put the grippers into each other (median -11 mm), with one candidate per base
    grasp 102 of 144 were collision-free."""
    grasp_config: GraspConfig = GraspConfig(num_grasps=64)
    """Antipodal grasp sampling when grasps are not given. More base grasps than RSRD's 10: most
    are removed by seating (e.g. grasps in the middle of a plate put the palm into it; on the
    studio scissors only grasps on the rings' outer ends seat, and 32 base grasps had none), and
    ``max_candidates`` caps what is solved."""
    spread_grasp_config: GraspConfig | None = GraspConfig(num_grasps=64, min_separation=0.012)
    """A second sampling of the same part with a wide non-maximum suppression, merged into the
    candidates (:func:`rsrd_jax.grasp.merge_grasps`); None = off. The best-scored grasps cluster
    around the part's centre (the score rewards centredness), while a lid, a panel lying on its
    stand or an arm next to a torso can only be held at its rim or tip: on the studio's red_box
    and led_light (ground-truth motion) no grasp of the 64 best seated, and 20–24 of the spread
    set do. A spread grasp comes after every surviving best-scored one (in the approach order and
    between arm assignments; ``info["chosen"]["spread_grasp"]``): a rim grasp holds a part far
    from its centre, where tracking errors move it most (the stapler's arm was pushed 43 mm by
    the approach when a spread grasp won on cost)."""
    hand_grasp_config: GraspConfig | None = GraspConfig(num_grasps=32)
    """A third sampling of a part the demonstrator held (``plan_robot(hand_points=...)``): first
    contacts only within ``hand_grasp_radius`` of where the hand held it, best nearest it
    (:func:`rsrd_jax.grasp.sample_antipodal_grasps` with ``near``). Merged after the best-scored
    grasps, before the spread set, in a tier of their own (``hand_grasp_tier``). The centre-scored grasps of a part
    reach only where its surface is large: on the tracked toy_drawer (session 30) the drawer's
    centroid lies on its front panel, its best grasps 36 mm (mean) from the knob the hand
    pulled, and 20 of 4464 valid grasps seated; None = off."""
    topdown_grasp_config: TopDownConfig | None = TopDownConfig()
    """A fourth sampling of each part: level pinches across its footprint seen from above,
    approached from above (:func:`rsrd_jax.grasp.sample_topdown_grasps`, the table's normal taken
    in the part's frame at the first keyframe), merged after the spread set and used only when no
    grasp of the first three sets survives (tier 3). The mesh sampler's grasps on a part lying
    flat pinch across its thickness with a side approach through the table: on the tracked
    studio scissors none seats at any depth; with these all 10 table orientations of the robot
    trials plan and 6 succeed in simulation, led_light 9 and 3
    (``experiments/results/robot_trials_s41.md``); None = off."""
    hand_grasp_radius: float = 0.02
    """Radius (m) around each hand's point within which ``hand_grasp_config`` samples."""
    hand_grasp_tier: bool = True
    """The grasps near the hands (``hand_grasp_config``) are used only when no best-scored grasp
    survives (a tier between those and the spread set; ``info["chosen"]["hand_grasp"]``). False
    (sessions ≤ 45): ranked with the best-scored ones by cost. Measured on session 46's machine
    (its robot-trial builds): on led_light no best-scored grasp of the panel seats and the top-down
    pinches of its tab (tier 3) slip or shut beside it (0/10 end to end); pinches near the
    demonstrator's hand on the tab pass at 5 of the 10 table orientations. Ranked with the
    best-scored ones, they won on cost in 2 of the stapler's first 4 trials, pinching the arm's
    end, which slipped 24–26° (limit 20°)."""
    free_cone_deg: float | None = 15.0
    """The antipodal samplings of a free part (``plan_robot(free_parts=)``) accept only contacts
    whose normals lie within this angle of the grasp axis (``GraspConfig.friction_angle_deg``,
    the smaller of the two): the closing jaw turns a free part until its faces lie flat on the
    pads, which moves the whole part, not only within the pinch. Studio usb_plug on ground truth:
    a pinch 24° off the plug's faces (45° cone) rolled and yawed the plug by 18° and 17° as it
    closed (it ended 25° off the demo); with 15° the plug turned by 6–8° and the trial succeeded.
    None = the sets' own cones."""
    free_twist_deg: float | None = 10.0
    """A grasp on a free part (``plan_robot(free_parts=)``: no joint holds it, so the grip alone
    turns it) whose trajectory turns the part by more than this about the grasp's closing axis
    ranks after the other grasps of its tier: the pads' friction alone must carry that turn
    (torsion), and two small contact patches let the part pivot between them. A hinged part's
    turn is carried by the hinge and the pinch point's path along the arc, so the rule does not
    apply to it. Studio usb_plug (the plug leaves the brick with a 23° roll about its width): the
    best-cost ground-truth grasp pinched across that width, the plug did not roll in simulation
    and ended 20.7° off the demo; with this rule alone the next grasp, across the thickness but 24°
    off the faces, turned the plug as it closed (25.3° off); with ``free_cone_deg`` too the pinch
    across the thickness carried the roll and every stage passed. None = off."""
    short_lever_fraction: float | None = 0.4
    """A grasp on a jointed part (not in ``free_parts``) that turns by at least ``short_lever_turn_deg`` whose distance from the
    part's turn axis is under this fraction of the part's farthest point's ranks after the
    other grasps of its tier (with the twisting ones): the hinge, not the plan, sets where a
    hinged part goes, and the pinch point follows the tracked arc, whose centre is off by the
    track's error; near the axis a few millimetres of path error are a wide turn of the part in
    the jaw. The axis: the screw axis of the part's motion (object frame) from the first keyframe
    to the one where it turned most (object frame: the root is taken to stay put). Measured on
    the studio scissors (session 47, the machine of sessions 44–47, its robot-trial build and
    track, 10 table orientations): the top-down pinches chosen by cost
    held the blade's neck 29 mm from the pivot (0.35 of the blade's 84 mm) and let the blade turn
    20.3–23.7° in the jaw (limit 20°) at 4 of 6 orientations, at 39–44 mm (0.46–0.52) it turned
    7.4–8.3°; with this rule 8 of 10 trials pass every stage (5 before). None = off."""
    short_lever_turn_deg: float = 10.0
    """See ``short_lever_fraction``."""
    root_still: bool = False
    """Plan every part's motion relative to the object's root (part 0), the root held at its
    first-frame pose (:func:`root_still_trajectory`), as the simulator scores the parts, unless
    the root is to be held (a demonstrator's hand held it, ``hand_parts``, or ``parts`` names it:
    usb_plug's socket is held while the plug is pulled, and the arm holding it follows its
    motion). The drift removed is in ``info["root_still"]`` (None when not applied: off, a held
    root, or a one-part object, whose only part is what moves). The studio roots never move;
    their tracks moved 3–12 mm. Off by default: which is nearer the truth depends on the track.
    Measured on session 47's robot-trial tracks (motion of each moved part from the first frame
    against the ground truth's, mean over the part's points at the last frame, object frame →
    relative to the root): toy_drawer's drawer 14.3 → 2.3 mm (its cabinet's track moved 12.4 mm
    along the pull, and plans following the object frame pulled the drawer 11–15 mm past the
    demo's 50 mm), red_box's lid 6.0 → 2.3, a frog leg 4.7 → 2.8, but stapler's arm 2.3 → 3.0,
    led_light's panel 5.4 → 6.7, scissors' blade 9.4 → 10.4, a sunglasses arm 7.0 → 14.3. Robot
    trials re-planned on those tracks and registrations: toy_drawer 0 → 10/10, scissors 8 → 4/10
    (grasps slip or miss as the blade's path turns about the root's drift)."""
    end_slack_deg: float | None = 10.0
    """When no plan follows the whole demo, the motion may end early: the parts are held at an
    earlier frame from which every part stays within ``end_slack_deg`` and ``end_slack_m`` of its
    final pose (object frame, at its rest centroid), and the search runs again on that trajectory
    (the latest such frames first, at ``end_slack_fractions`` of the slack). A demo may end with a
    part where no gripper fits: tracked studio sunglasses fold an arm to 7 mm behind the frame,
    and every grasp on the arm meets the frame over the last 12 of 50 keyframes, 8° before the
    end (the robot trials score the final pose within 15 mm / 15°). The plan's ``info["end_slack"]``
    records the frame and the slack used. None = off (the whole demo or no plan)."""
    end_slack_m: float = 0.015
    """See ``end_slack_deg`` (m)."""
    end_slack_fractions: tuple[float, ...] = (0.5, 1.0)
    """See ``end_slack_deg``: one attempt per fraction of the slack, in this order."""
    mesh_config: MeshConfig = MeshConfig()
    """Part meshing when grasps are not given."""
    rank_config: RankConfig = RankConfig()
    """Part ranking."""
    seed: int = 0
    """Seed for grasp sampling."""

    def with_square_grasps(self, normal_radius: float = 0.008, cone_deg: float = 15.0) -> "PlanConfig":
        """This config with square pinches preferred: its best-scored and near-hand grasp
        samplings take contact normals averaged over ``normal_radius`` (m, ``GraspConfig.
        normal_radius``) and accept only contacts within ``cone_deg`` of the axis, so that a pinch
        does not turn a round or tilted part as the jaw closes; the spread set (tier 2, used only
        when none of those survives) keeps RSRD's rule (single-face normals, 45°) for parts held
        at a rim (a lid's lip, a panel's edge)."""
        if not 0.0 < cone_deg < 90.0:  # also refuses NaN
            raise ValueError(f"cone_deg: expected degrees in (0, 90), got {cone_deg}")
        sq = lambda g: None if g is None else dataclasses.replace(  # noqa: E731
            g, normal_radius=float(normal_radius), friction_angle_deg=float(cone_deg))
        return dataclasses.replace(self, grasp_config=sq(self.grasp_config), hand_grasp_config=sq(self.hand_grasp_config))


class RobotPlan(eqx.Module):
    """A plan (host numpy arrays). Arm index 0 = right, 1 = left; unused arms have part -1."""

    result: PlanResult
    """Why the search stopped; arrays are empty/NaN unless ``success``."""
    message: str = eqx.field(static=True)
    """Human-readable reason."""
    keyframe_indices: np.ndarray
    """(K,) video frame index of each keyframe."""
    q_keyframes: np.ndarray
    """(K, 16) joints at keyframes (rad, gripper m)."""
    q_video: np.ndarray
    """(T, 16) joints linearly resampled to every video frame."""
    q_approach: np.ndarray
    """(A, 16) approach segment, pre-grasp to grasp (its last row is ``q_keyframes[0]`` in the arm joints); its
    gripper columns are the finger opening of the approach (``PlanConfig.approach_clearance``),
    which the simulator uses."""
    tcp_target: np.ndarray
    """(K, 2, 7) TCP targets at keyframes (robot frame, wxyz_xyz; home TCP for idle arms)."""
    tcp_approach_target: np.ndarray
    """(A, 2, 7) TCP targets of the approach segment."""
    active: np.ndarray
    """(2,) bool, arm in use."""
    part: np.ndarray
    """(2,) int, grasped part per arm (-1 none)."""
    grasp_index: np.ndarray
    """(2,) int, index of the chosen grasp among the part's candidates (-1 none)."""
    T_part_grasp: np.ndarray
    """(2, 7) chosen grasp in its part frame (rest-centroid frame)."""
    grasp_width: np.ndarray
    """(2,) contact separation of the chosen grasp (m)."""
    T_robot_obj: np.ndarray
    """(7,) object pose in the robot base frame."""
    position_error: np.ndarray
    """(2,) max TCP position error over keyframes (m)."""
    rotation_error: np.ndarray
    """(2,) max TCP rotation error over keyframes (rad)."""
    min_distance: np.ndarray
    """(3,) smallest self, table, object distance along trajectory and approach (m)."""
    info: dict = eqx.field(static=True)
    """JSON-able: solver results, rejection counts per stage and attempt, timings."""

    @property
    def success(self) -> bool:
        """True when a feasible plan was found."""
        return bool(self.result == PlanResult.success)

    @property
    def result_name(self) -> str:
        """Name of ``result`` (e.g. ``"success"``, ``"unreachable"``)."""
        for name, item in PlanResult._name_to_item.items():
            if bool(item == self.result):
                return name
        raise ValueError(f"unknown PlanResult {self.result!r}")


def keyframe_indices(num_frames: int, num_keyframes: int) -> np.ndarray:
    """Evenly spaced frame indices including the first and last frame; at least 2 keyframes
    (a one-frame video repeats its frame), at most ``num_frames`` distinct ones."""
    if num_frames < 1:
        raise ValueError(f"num_frames must be ≥ 1, got {num_frames}")
    if num_keyframes < 2:
        raise ValueError(f"num_keyframes must be ≥ 2, got {num_keyframes}")
    if num_frames == 1:
        return np.zeros(2, np.int64)
    k = min(num_keyframes, num_frames)
    return np.unique(np.round(np.linspace(0, num_frames - 1, k)).astype(np.int64))


def resample_keyframes(q_key: np.ndarray, idx: np.ndarray, num_frames: int) -> np.ndarray:
    """Linear interpolation of keyframe joints (K, 16) at every frame 0..num_frames-1."""
    t = np.arange(num_frames)
    return np.stack([np.interp(t, idx, q_key[:, j]) for j in range(q_key.shape[1])], axis=1)


def _se3(x) -> jaxlie.SE3:
    return jaxlie.SE3(jnp.asarray(x, jnp.float32))


# ----------------------------------------------------------------------------------------------
# Batched solve + evaluation
# ----------------------------------------------------------------------------------------------


@eqx.filter_jit
def _solve_batch(params: CostParams, x0, pose: PoseData, config: SolverConfig):
    K = x0.shape[1]
    prob = trajectory_problem(False, False)

    def one(x, d):
        return solve_lm(prob, x, problem_data(d, K), params, config)

    return jax.vmap(one)(x0, pose)


@eqx.filter_jit
def _solve_batch_acc(params: CostParams, x0, pose: PoseData, config: SolverConfig):
    K = x0.shape[1]
    prob = trajectory_problem(True, False)
    return jax.vmap(lambda x, d: solve_lm(prob, x, problem_data(d, K, True), params, config))(x0, pose)


def _solve(params: CostParams, x0, pose: PoseData, config: SolverConfig, acceleration: bool):
    fn = _solve_batch_acc if acceleration else _solve_batch
    return fn(params, x0, pose, config)


class _Collide(eqx.Module):
    """What the candidate check collides with: the robot proxy and the parts' distance grids."""

    proxy: RobotProxy
    sdf: PartSDF


@eqx.filter_jit
def _evaluate(robot, coll: _Collide, q, target, active, T_world_part, mask, hand_tolerance, grip, pad_table):
    """Per candidate: max pos/rot error of active arms, max limit violation, min distances
    (self, table, object) with the grippers at ``grip`` (n, 2) opening per finger (m); the pads'
    table distances are increased by ``pad_table`` (m)."""
    pos, rot = tcp_errors(robot, q, target)  # (n, K, 2)
    pos, rot = jnp.where(active > 0, pos, 0.0), jnp.where(active > 0, rot, 0.0)
    pos0, rot0 = jnp.max(pos[:, 0], axis=-1), jnp.max(rot[:, 0], axis=-1)  # at the first keyframe
    pos, rot = jnp.max(pos, axis=1), jnp.max(rot, axis=1)
    viol = jnp.max(jnp.maximum(q - robot.upper, robot.lower - q), axis=(1, 2))
    qe = q.at[..., 14].set(grip[:, None, 0]).at[..., 15].set(grip[:, None, 1])
    res = collision_distances(robot, qe, None, None, margin=0.0, check_finite=False)
    d_table, d_obj = jax.vmap(jax.vmap(lambda x, T: proxy_distances(robot, coll.proxy, coll.sdf, x, T),
                                       in_axes=(0, 0)), in_axes=(0, None))(qe, T_world_part)  # (n,K,caps[,P])
    d_table = d_table + jnp.where(coll.proxy.kind == 2, pad_table, 0.0)
    # the gripper (palm + pads) gets ``hand_tolerance`` (m) of allowed penetration into parts
    hand = (coll.proxy.kind >= 1)[:, None]
    d_obj = jnp.where(mask, d_obj + jnp.where(hand, hand_tolerance, 0.0), jnp.inf)
    min_obj = jnp.min(d_obj, axis=(-2, -1))
    mins = jnp.stack([jnp.min(res.min_self, axis=1), jnp.min(d_table, axis=(1, 2)), jnp.min(min_obj, axis=1)], -1)
    return pos, rot, viol, mins, pos0, rot0


class _Batch(eqx.Module):
    q: np.ndarray  # (n, K, 16)
    cost: np.ndarray
    lm_result: np.ndarray  # LMResult index
    iterations: np.ndarray
    pos: np.ndarray  # (n, 2)
    rot: np.ndarray
    viol: np.ndarray
    mins: np.ndarray  # (n, 3)
    pos0: np.ndarray  # (n,) over the active arms, at the first keyframe
    rot0: np.ndarray


def _run_candidates(
    params: CostParams, robot_eval, coll: _Collide, x0: np.ndarray, target: np.ndarray, active: np.ndarray,
    T_world_part: np.ndarray, mask: np.ndarray, cfg: PlanConfig, acceleration: bool, grip: np.ndarray,
    q_ref: np.ndarray | None = None, ref_weight: np.ndarray | None = None, q_last: np.ndarray | None = None,
    first_weight: float = 1.0,
) -> _Batch | list[_Batch]:
    """Solve and evaluate n candidates in chunks of ``cfg.chunk_size`` (padded); ``grip`` (n, 2)
    is the finger opening (m) used in the collision check; ``q_last`` (n, 16), if given, replaces
    each solution's last keyframe (before it is evaluated and returned); ``first_weight`` scales the
    first keyframe's pose rows (the grasp of a trajectory). With ``grip`` (n, G, 2)
    each solution is evaluated at every opening (solved once) and G batches are returned."""
    n = x0.shape[0]
    chunk = max(1, cfg.chunk_size)  # always padded: one compilation per (chunk, keyframes)
    solver = SolverConfig(
        trust_region=TrustRegionConfig(lambda_initial=cfg.lambda_initial),
        termination=TerminationConfig(max_iterations=cfg.max_iterations),
    )
    grips = grip if grip.ndim == 3 else grip[:, None]
    outs: list[list] = [[] for _ in range(grips.shape[1])]
    for s in range(0, n, chunk):
        sl = slice(s, min(s + chunk, n))
        m = sl.stop - sl.start
        pad = lambda a: np.concatenate([a[sl], np.repeat(a[sl][-1:], chunk - m, 0)]) if m < chunk else a[sl]  # noqa: E731
        xs, ts, acts = pad(x0), pad(target), pad(active)
        K = xs.shape[1]
        acts_k = np.repeat(np.asarray(acts, np.float32)[:, None], K, 1)  # (chunk, K, 2)
        acts_k[:, 0] *= first_weight
        if q_ref is None:
            pose = PoseData(jnp.asarray(ts, jnp.float32), jnp.asarray(acts_k))
        else:
            pose = PoseData(jnp.asarray(ts, jnp.float32), jnp.asarray(acts_k), jnp.asarray(pad(q_ref), jnp.float32),
                            jnp.asarray(pad(ref_weight), jnp.float32))
        sol = _solve(params, jnp.asarray(xs, jnp.float32), pose, solver, acceleration)
        if q_last is not None:
            sol = eqx.tree_at(lambda r: r.x, sol, sol.x.at[:, -1].set(jnp.asarray(pad(q_last), jnp.float32)))
        for j, out in enumerate(outs):
            ev = _evaluate(robot_eval, coll, sol.x, pose.target, pose.active, jnp.asarray(T_world_part, jnp.float32),
                           jnp.asarray(mask), jnp.asarray(cfg.hand_tolerance, jnp.float32),
                           jnp.asarray(pad(grips[:, j]), jnp.float32), jnp.asarray(_pad_table_allowance(cfg), jnp.float32))
            out.append([np.asarray(a)[:m] for a in (sol.x, sol.cost, sol.result._value, sol.iterations, *ev)])
    batches = [_Batch(*[np.concatenate(x) for x in zip(*out)]) for out in outs]
    return batches if grip.ndim == 3 else batches[0]


def _pad_table_allowance(cfg: PlanConfig) -> float:
    """Allowance (m) added to the pads' table distances so that ``collision_margin`` applies."""
    return 0.0 if cfg.pad_table_margin is None else cfg.collision_margin - cfg.pad_table_margin


def _reject(b: _Batch, valid: np.ndarray, cfg: PlanConfig, collision: bool = True,
            seated: np.ndarray | None = None, solved: np.ndarray | None = None,
            grasp: bool = True) -> tuple[np.ndarray, dict]:
    """Apply the stages in order; returns the surviving mask and counts rejected per stage
    (collisions only when ``collision``; ``seated`` = the free gripper clears everything; the
    grasp tolerances at the first keyframe only when ``grasp``, i.e. for trajectories, not for
    approach segments)."""
    counts = {}
    alive = valid.copy()
    counts["grasp_invalid"] = int((~valid).sum())
    seated = np.ones_like(alive) if seated is None else seated
    counts["grasp_collision"] = int((alive & ~seated).sum())
    alive &= seated
    solved = np.ones_like(alive) if solved is None else solved
    counts["unsolved"] = int((alive & ~solved).sum())
    alive &= solved
    ok = np.isfinite(b.cost) & np.all(np.isfinite(b.q), axis=(1, 2))
    counts["solver"] = int((alive & ~ok).sum())
    alive &= ok
    ok = (np.max(b.pos, 1) <= cfg.position_tolerance) & (np.max(b.rot, 1) <= np.deg2rad(cfg.rotation_tolerance_deg))
    if grasp:
        ok &= (b.pos0 <= cfg.grasp_position_tolerance) & (b.rot0 <= np.deg2rad(cfg.grasp_rotation_tolerance_deg))
    counts["pose_error"] = int((alive & ~ok).sum())
    alive &= ok
    ok = b.viol <= cfg.limit_tolerance
    counts["joint_limits"] = int((alive & ~ok).sum())
    alive &= ok
    ok = np.all(b.mins >= cfg.collision_margin, axis=1) if collision else np.ones_like(alive)
    counts["collision"] = int((alive & ~ok).sum())
    alive &= ok
    return alive, counts


# ----------------------------------------------------------------------------------------------
# Main entry
# ----------------------------------------------------------------------------------------------


def plan_config_from_dict(d: dict) -> PlanConfig:
    """The :class:`PlanConfig` a plan was planned with, from its ``info["config"]`` (``plan.json``):
    nested configs rebuilt, JSON lists back to tuples. Raises ValueError on an unknown field."""
    return _config_from_dict(PlanConfig(), d, "config")


def _config_from_dict(default, d: dict, where: str):
    if not isinstance(d, dict):
        raise ValueError(f"{where}: expected an object of {type(default).__name__} fields, got {type(d).__name__}")
    names = {f.name for f in dataclasses.fields(default)}
    unknown = sorted(set(d) - names)
    if unknown:
        raise ValueError(f"{where}: unknown {type(default).__name__} field(s) {unknown}")
    kw = {}
    for k, v in d.items():
        cur = getattr(default, k)
        if dataclasses.is_dataclass(cur) and isinstance(v, dict):
            v = _config_from_dict(cur, v, f"{where}.{k}")
        elif isinstance(v, list):
            v = tuple(v)
        kw[k] = v
    return dataclasses.replace(default, **kw)


def grasp_targets(
    T_robot_obj: Float[np.ndarray, "7"], T_obj_part: Float[np.ndarray, "k 7"], T_part_grasp: Float[np.ndarray, "n 7"]
) -> np.ndarray:
    """TCP targets ``T_robot_obj · T_obj_part(t) · T_part_grasp`` for n grasps at k keyframes:
    (n, k, 7) wxyz_xyz."""
    T_robot_part = _se3(T_robot_obj) @ _se3(T_obj_part)  # (k,)
    out = jaxlie.SE3(T_robot_part.wxyz_xyz[None]) @ jaxlie.SE3(_se3(T_part_grasp).wxyz_xyz[:, None])
    return np.asarray(out.wxyz_xyz)


def object_geometry(part_points: Sequence[np.ndarray], boxes_per_part: int = 8, pad: float = 0.0,
                    seed: int = 0) -> ObjectGeometry:
    """Box proxy of an articulated object (for the optional collision *cost*; the candidate checks
    of :func:`plan_robot` use the tighter :func:`part_sdf` grids): each part's points split by
    k-means into up to ``boxes_per_part`` clusters, one oriented bounding box per cluster
    (``box_part`` = the part). Several boxes follow non-convex parts far more tightly than one
    (a single box of an L-shaped body swallows the neighbouring part)."""
    from sklearn.cluster import KMeans

    pts, ids, owner = [], [], []
    for k, p in enumerate(part_points):
        p = np.asarray(p, float)
        if len(p) == 0:
            raise ValueError(f"part_points[{k}] is empty")
        m = int(max(1, min(boxes_per_part, len(p) // 8)))
        lab = np.zeros(len(p), int) if m == 1 else KMeans(m, n_init=1, random_state=seed).fit_predict(p)
        _, lab = np.unique(lab, return_inverse=True)
        pts.append(p)
        ids.append(lab + len(owner))
        owner += [k] * (int(lab.max()) + 1)
    geom = object_boxes_from_points(np.concatenate(pts), np.concatenate(ids), len(owner), pad=pad)
    return dataclasses.replace(geom, box_part=jnp.asarray(owner, jnp.int32), num_parts=len(part_points))


def _failure(result: PlanResult, message: str, T_robot_obj, idx, info) -> RobotPlan:
    nan = lambda *s: np.full(s, np.nan)  # noqa: E731
    return RobotPlan(
        result=result, message=message, keyframe_indices=np.zeros(0, np.int64), q_keyframes=nan(0, 16), q_video=nan(0, 16),
        q_approach=nan(0, 16), tcp_target=nan(0, 2, 7), tcp_approach_target=nan(0, 2, 7),
        active=np.zeros(2, bool), part=np.full(2, -1), grasp_index=np.full(2, -1), T_part_grasp=nan(2, 7),
        grasp_width=nan(2), T_robot_obj=np.asarray(T_robot_obj, float), position_error=nan(2),
        rotation_error=nan(2), min_distance=nan(3), info=info,
    )


SEAT_BLOCK = 512
"""Grasps per seating call (padded): one compilation per keyframe count."""


def _clearance_blocks(robot, hand, sdf, T_tcp: np.ndarray, opening: np.ndarray, T_parts: np.ndarray, part: int,
                      cfg: PlanConfig, own_pad_offset: float = np.inf) -> np.ndarray:
    """:func:`hand_clearance` (+ ``hand_tolerance``) of n gripper trajectories (n, k, 7) in padded
    blocks of ``SEAT_BLOCK``."""
    n = T_tcp.shape[0]
    out = np.zeros(n, np.float32)
    for s in range(0, n, SEAT_BLOCK):
        m = min(SEAT_BLOCK, n - s)
        sl = np.minimum(np.arange(s, s + SEAT_BLOCK), n - 1)  # pad with the last row
        c = hand_clearance(robot, hand, sdf, jnp.asarray(T_tcp[sl], jnp.float32), jnp.asarray(opening[sl]),
                           jnp.asarray(T_parts, jnp.float32), jnp.asarray(part), cfg.check_palm_on_grasped_part,
                           _pad_table_allowance(cfg), jnp.asarray(own_pad_offset, jnp.float32))  # fmt: skip
        out[s : s + m] = np.asarray(c)[:m]
    return out + cfg.hand_tolerance


def _seat_grasps(robot, hand, sdf, Tg: np.ndarray, opening: np.ndarray, valid: np.ndarray, T_robot_obj: np.ndarray,
                 T_obj_part_k: np.ndarray, T_robot_part: np.ndarray, part: int, cfg: PlanConfig,
                 coarse: int = 4, opening_approach: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Seating of part ``part``'s grasps ``Tg`` (n, 7): per grasp the smallest depth of
    ``cfg.grasp_depths`` at which the free gripper clears the table and the parts at every
    keyframe (``ok``), else the depth of its largest clearance; returns (ok (n,), depth (n,)).
    With ``opening_approach`` (n,) the gripper must also clear them at the first keyframe with
    the fingers at that opening: where the approach ends, before the jaw closes; there its pads
    must not end inside the grasped part either (``cfg.approach_grasp_pads_margin``).

    Only valid grasps are checked, and only at depths shallower than the one they already seat
    at. Each depth is checked coarse to fine: first at ``coarse`` keyframes spread over the
    trajectory, then at every keyframe for the grasps that cleared those (a grasp that hits
    something at one keyframe fails anyway), which gives the same result as checking every
    keyframe of every grasp (most grasps never seat: on the stapler 4748 of 4992)."""
    n, K = Tg.shape[0], T_robot_part.shape[0]
    depths = np.asarray(cfg.grasp_depths, float)
    sub = np.unique(np.round(np.linspace(0, K - 1, min(coarse, K))).astype(int))
    first = np.zeros_like(sub)  # the first keyframe, repeated to the coarse pass's shape (no new compile)
    seat = np.full(n, -1)
    best = np.full(n, -np.inf)
    best_j = np.zeros(n, int)
    for j, d in enumerate(depths):
        todo = np.flatnonzero(valid & (seat < 0))
        if len(todo) == 0:
            break
        Td = np.asarray((_se3(Tg[todo]) @ jaxlie.SE3.from_translation(jnp.asarray([0.0, 0.0, -d]))).wxyz_xyz)
        T_tcp = grasp_targets(T_robot_obj, T_obj_part_k, Td)  # (m, K, 7)
        c = _clearance_blocks(robot, hand, sdf, T_tcp[:, sub], opening[todo], T_robot_part[sub], part, cfg)
        if opening_approach is not None:
            own = np.inf if cfg.approach_grasp_pads_margin is None else cfg.collision_margin - cfg.approach_grasp_pads_margin
            c = np.minimum(c, _clearance_blocks(robot, hand, sdf, T_tcp[:, first], opening_approach[todo],
                                                T_robot_part[first], part, cfg, own))  # fmt: skip
        fine = np.flatnonzero(c >= cfg.collision_margin)
        if len(fine) and len(sub) < K:
            c[fine] = _clearance_blocks(robot, hand, sdf, T_tcp[fine], opening[todo[fine]], T_robot_part, part, cfg)
        seat[todo[c >= cfg.collision_margin]] = j
        better = c > best[todo]
        best[todo[better]], best_j[todo[better]] = c[better], j
    ok = seat >= 0
    return ok, depths[np.where(ok, seat, best_j)]


def _two_hands(rk: PartRanking, moved: np.ndarray, contact: float) -> tuple[bool, str]:
    """``bimanual="auto"``: do both hands touch distinct parts, one of which moved?"""
    cd = np.asarray(rk.contact_distance, np.float64)
    if rk.method != "hands" or cd.shape[0] < 2:
        return False, f"{'one hand' if rk.method == 'hands' else 'no hands'}: single-arm"
    best = np.argmin(cd, axis=1)  # (left, right)
    dist = cd[np.arange(2), best]
    mm = ", ".join(f"{h} hand {1000 * d:.1f} mm from part {k}" for h, d, k in zip(("left", "right"), dist, best))
    if not np.all(dist <= contact):
        return False, f"{mm}: not both within {1000 * contact:.0f} mm, single-arm"
    if best[0] == best[1]:
        return False, f"{mm}: both hands on one part, single-arm"
    if not moved[best].any():
        return False, f"{mm}: neither part moved, single-arm"
    return True, f"{mm}: bimanual"


def plan_robot(
    robot: YumiModel,
    part_points: Sequence[Float[np.ndarray, "_n 3"]],
    T_obj_part: Float[np.ndarray, "t p 7"],
    T_robot_obj: Float[np.ndarray, "7"],
    hands: Float[np.ndarray, "t h 2 3"] | None = None,
    grasps: dict[int, PartGrasps] | None = None,
    config: PlanConfig = PlanConfig(),
    mesh_points: Sequence[Float[np.ndarray, "_m 3"]] | None = None,
    hand_parts: tuple[int, int] | None = None,
    hand_points: Sequence[tuple[int, Float[np.ndarray, "3"]]] | None = None,
    free_parts: Sequence[int] | None = None,
) -> RobotPlan:
    """Plan a YuMi joint trajectory that makes grasped parts follow a part trajectory.

    Frames: part k's frame is its rest-centroid frame (object-frame axes, origin at the rest
    centroid): ``part_points[k]`` are its points there and ``T_obj_part[t, k]`` maps it into the
    object frame. The TCP target of grasp g on part k is
    ``T_robot_obj · T_obj_part(t) · T_part_grasp[g]``.

    Collision proxies: the parts are signed-distance grids built from their points
    (:func:`part_sdf`), moved by the trajectory; the robot is its MJCF capsules with each finger
    replaced by capsules over its contact pad (:func:`robot_proxy`); the finger pads may touch the
    grasped part, the palm may not (``check_palm_on_grasped_part``).

    Search: for each ranked part (or (left, right) pair) and arm assignment, every grasp is first
    *seated*: backed off along its approach axis by the smallest of ``grasp_depths`` at which the
    free-floating gripper (palm + pads, fingers closed to the grasp width) clears the table and
    the parts at every keyframe; grasps that never clear are rejected (``grasp_collision``) without
    solving. Up to ``max_candidates`` seated grasps (best score first) are solved (single-arm
    problems, the other arm held near home) in vmapped chunks and rejected in order by tracking
    error (``position_tolerance``/``rotation_tolerance_deg`` at every keyframe, the tighter
    ``grasp_position_tolerance``/``grasp_rotation_tolerance_deg`` at the first), joint limits and
    collisions of the whole robot along the trajectory (self, table, parts). Bimanual: the best ``top_k_per_arm``
    survivors of each arm are combined into 16-DoF solves initialised from them and checked again
    (including arm-arm collisions). The best survivors by cost then get an approach segment
    (pre-grasp ``approach_distance`` behind the first grasp pose along the gripper z axis, to the
    grasp) that must track and be collision-free, the open pads clear of the grasped part too
    until the grasp pose (``approach_pads_clear_part``) and not inside it there
    (``approach_grasp_pads_margin``). The first part (pair) with a feasible plan wins;
    within it, the lowest cost.
    When nothing follows the whole demo, the search runs again with the motion ending early,
    within ``end_slack_deg`` / ``end_slack_m`` of every part's final pose (``info["end_slack"]``).

    Args:
        robot: from :func:`rsrd_jax.robot.load_yumi`.
        part_points: P point sets in their part frames (m).
        T_obj_part: (T, P, 7) part poses in the object frame per video frame.
        T_robot_obj: (7,) object pose in the robot base frame (wxyz_xyz).
        hands: optional (T, H, 2, 3) fingertip keypoints in the object frame for part ranking.
        grasps: optional precomputed grasps per part index (else sampled on the part points).
        config: options.
        mesh_points: optional P point sets (part frames) the grasp meshes are built from instead
            of ``part_points`` (e.g. ``ObjectModel.part_extent_points``: a thin part's Gaussian
            centres lie on its mid-surface); collisions are still checked on ``part_points``.
        hand_parts: with ``config.bimanual="auto"`` and ``config.parts`` None: the (left hand,
            right hand) parts the demonstrator held, decided elsewhere (the tracker's 2D hand
            anchors, which a depth error of the tracked object does not move, unlike the 3D
            fingertips in the object frame). Distinct parts, one of which moved, are planned
            bimanually (that pair only); otherwise, or if that fails, single-arm.
        hand_points: optional (part, point) pairs: where the demonstrator's hands held which
            part (part frame, m; e.g. the tracker's hand anchors). Grasps are also sampled near
            them (``config.hand_grasp_config``) when grasps are not given.
        free_parts: optional parts that no joint holds (the parts of a separable object):
            their pinches must close square on their faces (``config.free_cone_deg``), and a
            grasp that must turn such a part about its own closing axis ranks late
            (``config.free_twist_deg``).

    Returns:
        :class:`RobotPlan`; infeasible requests return a plan whose ``result`` says why. Its
        ``info["config"]`` is ``config`` as a dict (saved in ``plan.json``).

    Raises:
        ValueError: on inconsistent input shapes or a bad part index.
    """
    if config.bimanual not in (True, False, "auto"):
        raise ValueError(f"config.bimanual must be True, False or 'auto', got {config.bimanual!r}")
    slack = (config.end_slack_deg if config.end_slack_deg is not None else 0.0, config.end_slack_m)
    if not all(np.isfinite(slack)) or min(slack) < 0 or not all(0 < s <= 1 for s in config.end_slack_fractions):
        raise ValueError(f"config.end_slack_deg / end_slack_m: expected ≥ 0 (got {config.end_slack_deg}, "
                         f"{config.end_slack_m}); end_slack_fractions in (0, 1] (got {config.end_slack_fractions})")
    lever = config.short_lever_fraction
    if lever is not None and not (0.0 < lever < 1.0 and 0.0 <= config.short_lever_turn_deg < 180.0):
        raise ValueError(f"config.short_lever_fraction: expected None or a fraction in (0, 1), got {lever} "
                         f"(short_lever_turn_deg {config.short_lever_turn_deg}: expected 0–180)")
    if hand_points is not None:
        hand_points = [(int(k), np.asarray(x, np.float64).reshape(-1)) for k, x in hand_points]
        bad = [(k, x) for k, x in hand_points if not 0 <= k < len(part_points) or x.shape != (3,) or not np.all(np.isfinite(x))]
        if bad:
            raise ValueError(f"hand_points: expected (part in 0..{len(part_points) - 1}, finite point (3,)) pairs, got {bad}")
    if free_parts is not None:
        free_parts = tuple(int(k) for k in free_parts)
        if any(not 0 <= k < len(part_points) for k in free_parts):
            raise ValueError(f"free_parts {free_parts} out of range for {len(part_points)} parts")
    T_obj_part = np.asarray(T_obj_part, np.float64)
    still = None
    held_root = 0 in tuple(hand_parts or ()) + tuple(config.parts or ())
    if (config.root_still and len(part_points) >= 2 and not held_root and T_obj_part.ndim == 3
            and T_obj_part.shape[1:] == (len(part_points), 7)):  # fmt: skip
        T_obj_part, still = root_still_trajectory(T_obj_part)
    plan = _plan_demo(robot, part_points, T_obj_part, T_robot_obj, hands, grasps, config, mesh_points, hand_parts,
                      hand_points, free_parts)  # fmt: skip
    plan.info["root_still"] = still
    if plan.success or config.end_slack_deg is None:
        return plan
    rot, pos = end_deviation(T_obj_part)
    tried: list[dict] = []
    for s in config.end_slack_fractions:
        f = end_frame(rot, pos, s * np.deg2rad(config.end_slack_deg), s * config.end_slack_m)
        if f >= len(T_obj_part) - 1 or any(t["frame"] == f for t in tried):
            continue
        held = T_obj_part.copy()
        held[f + 1 :] = held[f]
        short = _plan_demo(robot, part_points, held, T_robot_obj, hands, grasps, config, mesh_points, hand_parts,
                           hand_points, free_parts)  # fmt: skip
        tried.append({"frame": f, "rotation_deg": round(float(np.rad2deg(rot[f])), 2),
                      "position_mm": round(float(1000 * pos[f]), 2), "result": short.result_name, "message": short.message})  # fmt: skip
        if short.success:
            short.info["root_still"] = still
            short.info["end_slack"] = {"frame": f, "num_frames": len(T_obj_part), "whole_demo": plan.result_name,
                                       "whole_demo_message": plan.message, "attempts": tried}  # fmt: skip
            t = tried[-1]
            msg = (f"{short.message}; the motion ends at frame {f} of {len(T_obj_part) - 1}, parts within "
                   f"{t['rotation_deg']:.1f}° / {t['position_mm']:.1f} mm of the demo's end (the whole demo: {plan.result_name})")
            with warnings.catch_warnings():  # info["config"] holds the config's float32 weights (static, by design)
                warnings.filterwarnings("ignore", "A JAX array is being set as static")
                return dataclasses.replace(short, message=msg)
    plan.info["end_slack"] = {"frame": None, "num_frames": len(T_obj_part), "attempts": tried}
    return plan


def root_still_trajectory(T_obj_part: Float[np.ndarray, "t p 7"]) -> tuple[np.ndarray, dict]:
    """Part poses (T, P, 7, wxyz_xyz, object frame) with the root (part 0) held at its first-frame
    pose and every part keeping its pose relative to the root:
    ``T'[t, k] = T[0, 0] · T[t, 0]⁻¹ · T[t, k]``. Returns them (float64) and the root motion
    removed: its largest translation (mm) and rotation (°) from the first frame."""
    T = np.asarray(T_obj_part, np.float64)
    root0 = _se3(np.broadcast_to(T[:1, 0], T[:, 0].shape))
    fix = root0 @ _se3(T[:, 0]).inverse()  # (T,)
    out = np.asarray((jaxlie.SE3(fix.wxyz_xyz[:, None]) @ _se3(T)).wxyz_xyz, np.float64)
    out[:, 0] = T[0, 0]
    moved = np.linalg.norm(T[:, 0, 4:] - T[:1, 0, 4:], axis=-1)
    turned = np.linalg.norm(np.asarray((root0.inverse() @ _se3(T[:, 0])).rotation().log(), np.float64), axis=-1)
    return out, {"max_root_motion_mm": round(float(1000 * moved.max()), 2),
                 "max_root_turn_deg": round(float(np.rad2deg(turned.max())), 2)}


def end_deviation(T_obj_part: Float[np.ndarray, "t p 7"]) -> tuple[np.ndarray, np.ndarray]:
    """Per frame the largest rotation (rad) and translation (m) of any part from its pose on the
    last frame (object frame; part frames at the rest centroids): (T,), (T,)."""
    R = jaxlie.SO3(jnp.asarray(T_obj_part[..., :4], jnp.float32))
    turn = jaxlie.SO3(jnp.broadcast_to(R.wxyz[-1:], R.wxyz.shape)).inverse() @ R
    rot = np.linalg.norm(np.asarray(turn.log(), np.float64), axis=-1)
    pos = np.linalg.norm(np.asarray(T_obj_part[..., 4:], np.float64) - np.asarray(T_obj_part[-1:, :, 4:], np.float64), axis=-1)
    return rot.max(axis=1), pos.max(axis=1)


def end_frame(rot: np.ndarray, pos: np.ndarray, max_rot: float, max_pos: float) -> int:
    """The earliest frame from which every later frame's deviation (:func:`end_deviation`) stays
    within ``max_rot`` (rad) and ``max_pos`` (m)."""
    out = (rot > max_rot) | (pos > max_pos)
    return int(np.flatnonzero(out)[-1] + 1) if out.any() else 0


def _plan_demo(robot, part_points, T_obj_part, T_robot_obj, hands, grasps, config: PlanConfig, mesh_points, hand_parts,
               hand_points, free_parts) -> RobotPlan:
    """:func:`plan_robot` on the whole given trajectory: the ``bimanual="auto"`` decision and
    its single-arm fallback."""
    args = (robot, part_points, T_obj_part, T_robot_obj, hands, grasps)
    if config.bimanual != "auto":
        plan = _plan_robot(*args, config, mesh_points, hand_points, free_parts)
        plan.info["config"] = dataclasses.asdict(config)
        return plan
    why = "parts given" if config.parts is not None else "no hands" if hands is None else "one part"
    decided, why = False, f"{why}: single-arm"
    pair_config = config
    if config.parts is None and hand_parts is not None and len(part_points) >= 2:
        l, r = (int(v) for v in hand_parts)
        if not (0 <= l < len(part_points) and 0 <= r < len(part_points)):
            raise ValueError(f"hand_parts {hand_parts} out of range for {len(part_points)} parts")
        rk = rank_parts(list(part_points), np.asarray(T_obj_part, float), None, config=config.rank_config)
        motion = np.asarray(rk.relative_motion, np.float64)
        moved = motion >= config.min_motion_fraction * motion.max()
        decided = l != r and bool(moved[[l, r]].any())
        why = (f"hands hold parts {l} (left) and {r} (right): "
               + ("bimanual" if decided else "one part, single-arm" if l == r else "neither moved, single-arm"))
        pair_config = dataclasses.replace(config, parts=(l, r))
    elif config.parts is None and hands is not None and len(part_points) >= 2:
        rk = rank_parts(list(part_points), np.asarray(T_obj_part, float), hands, config=config.rank_config)
        motion = np.asarray(rk.relative_motion, np.float64)
        decided, why = _two_hands(rk, motion >= config.min_motion_fraction * motion.max(), config.bimanual_contact)
    plan = _plan_robot(*args, dataclasses.replace(pair_config if decided else config, bimanual=decided), mesh_points,
                       hand_points, free_parts)
    decision = {"mode": "auto", "bimanual": decided, "reason": why}
    if decided and not plan.success:  # a single arm may still reproduce part of the demo
        # the largest part of it: the moved parts in the order of their motion relative to their
        # parents. Both hands touched a part, so the hand ranking no longer tells them apart, and
        # it may put first a part a hand only held still (usb_plug's brick, which the tracked
        # demo moves a little, ranked before its pulled-out plug)
        order = [int(k) for k in np.argsort(-motion, kind="stable") if motion[k] >= config.min_motion_fraction * motion.max()]
        single_cfg = dataclasses.replace(config, bimanual=False, parts=tuple(order))
        single = _plan_robot(*args, single_cfg, mesh_points, hand_points, free_parts)
        decision.update(fallback="single-arm", fallback_parts=list(single_cfg.parts), bimanual_result=plan.result_name,
                        bimanual_message=plan.message, bimanual_attempts=plan.info.get("attempts"))  # fmt: skip
        plan = single
    plan.info["bimanual"] = decision
    plan.info["config"] = dataclasses.asdict(config)  # as given (the decision above may override bimanual/parts)
    return plan


def _plan_robot(
    robot: YumiModel,
    part_points: Sequence[Float[np.ndarray, "_n 3"]],
    T_obj_part: Float[np.ndarray, "t p 7"],
    T_robot_obj: Float[np.ndarray, "7"],
    hands: Float[np.ndarray, "t h 2 3"] | None = None,
    grasps: dict[int, PartGrasps] | None = None,
    config: PlanConfig = PlanConfig(),
    mesh_points: Sequence[Float[np.ndarray, "_m 3"]] | None = None,
    hand_points: Sequence[tuple[int, np.ndarray]] | None = None,
    free_parts: Sequence[int] | None = None,
) -> RobotPlan:
    """The body of :func:`plan_robot` (``config.bimanual`` True or False)."""
    import time

    t_start = time.perf_counter()
    P = len(part_points)
    T_obj_part = np.asarray(T_obj_part, float)
    T_robot_obj = np.asarray(T_robot_obj, float).reshape(-1)
    if T_obj_part.ndim != 3 or T_obj_part.shape[1:] != (P, 7):
        raise ValueError(f"T_obj_part: expected shape (T, {P}, 7), got {T_obj_part.shape}")
    if T_robot_obj.shape != (7,) or not np.all(np.isfinite(T_robot_obj)):
        raise ValueError(f"T_robot_obj: expected 7 finite numbers (wxyz_xyz), got {T_robot_obj}")
    if mesh_points is not None and len(mesh_points) != P:
        raise ValueError(f"mesh_points: expected {P} point sets (one per part), got {len(mesh_points)}")
    if config.parts is not None and any(not 0 <= k < P for k in config.parts):
        raise ValueError(f"config.parts {config.parts} out of range for {P} parts")
    if config.bimanual and P < 2 and config.parts is None:
        raise ValueError("bimanual planning needs at least 2 parts")
    clear = config.approach_clearance if isinstance(config.approach_clearance, tuple) else (config.approach_clearance,)
    if not clear or any(c is not None and not 0.0 <= c < np.inf for c in clear):
        raise ValueError(f"config.approach_clearance: expected openings ≥ 0 m or None (fully open), got {config.approach_clearance}")
    nT = T_obj_part.shape[0]
    idx = keyframe_indices(nT, config.num_keyframes)
    K = len(idx)
    T_robot_part = np.asarray((_se3(T_robot_obj) @ _se3(T_obj_part[idx])).wxyz_xyz)  # (K, P, 7)
    coll = _Collide(robot_proxy(robot, config.sample_spacing),
                    part_sdf(list(part_points), config.sdf_spacing, radius=config.object_radius))
    robot_lite = strip_robot(robot)
    r = (K - 1) / max(config.smoothness_reference - 1, 1)
    weights = eqx.tree_at(lambda w: (w.velocity, w.acceleration), config.weights,
                          (config.weights.velocity * np.sqrt(r), config.weights.acceleration * r**1.5))
    params = CostParams(robot_lite, weights, None)
    acceleration = float(config.weights.acceleration) > 0
    home = np.asarray(HOME_Q, np.float32)
    home_tcp = np.asarray(tcp_poses(robot_lite, jnp.asarray(home)))  # (2, 7)
    open_grip = float(robot.upper[14])
    info: dict = {"num_frames": nT, "num_parts": len(part_points), "keyframes": K, "attempts": [], "rejections": {s: 0 for s in STAGES},
                  "free_parts": [int(k) for k in (free_parts or ())]}  # fmt: skip

    # Ranking
    if config.parts is not None:
        if config.bimanual:
            if len(config.parts) != 2 or config.parts[0] == config.parts[1]:
                raise ValueError(f"bimanual config.parts must be two distinct parts, got {config.parts}")
            order = [tuple(config.parts)]
        else:
            order = [(k,) for k in config.parts]
        info["ranking"] = "given"
    else:
        rk = rank_parts(list(part_points), T_obj_part, hands, config=config.rank_config)
        info["ranking"] = rk.method
        motion = np.asarray(rk.relative_motion, np.float64)
        moved = motion >= config.min_motion_fraction * motion.max()
        if config.bimanual:
            order = [tuple(int(v) for v in p) for p in np.asarray(rk.pair_order)]
        else:
            order = [(int(k),) for k in np.asarray(rk.part_order)]
        info["relative_motion_mm"] = [round(float(m) * 1e3, 2) for m in motion]
        info["still_parts"] = [int(k) for k in np.flatnonzero(~moved)]
        order = [p for p in order if moved[list(p)].any()]
    order = order[: config.max_parts]

    # Grasps (lazily per part)
    grasp_cache: dict[int, PartGrasps] = dict(grasps or {})
    spread_row: dict[int, int] = {}  # part -> first row of its spread grasps (after the best-scored ones)
    hand_row: dict[int, int] = {}  # part -> first row of its grasps near the hands (between the two)
    topdown_row: dict[int, int] = {}  # part -> first row of its top-down grasps (after the spread set)
    table_down = -np.asarray(jaxlie.SE3(jnp.asarray(robot.geom.table_wxyz_xyz)).rotation().as_matrix(), np.float64)[:, 2]
    key = jax.random.PRNGKey(config.seed)

    def get_grasps(k: int) -> PartGrasps:
        if k not in grasp_cache:
            mesh = build_part_mesh(np.asarray((part_points if mesh_points is None else mesh_points)[k]), config.mesh_config)
            kk = jax.random.fold_in(key, k)
            cone = config.free_cone_deg if k in (free_parts or ()) else None
            gc = lambda c: c if c is None or cone is None else dataclasses.replace(  # noqa: E731
                c, friction_angle_deg=min(float(c.friction_angle_deg), float(cone)))
            g = sample_antipodal_grasps(mesh, kk, gc(config.grasp_config))
            hand_row[k] = int(g.T_part_grasp.shape[0])
            if config.hand_grasp_config is not None:
                for j, (kh, x) in enumerate(hand_points or []):
                    if kh == k:
                        near = sample_antipodal_grasps(mesh, jax.random.fold_in(kk, 1000 + j), gc(config.hand_grasp_config),
                                                       near=(x, config.hand_grasp_radius))  # fmt: skip
                        g = merge_grasps(g, near)
            spread_row[k] = int(g.T_part_grasp.shape[0])
            if config.spread_grasp_config is not None:
                g = merge_grasps(g, sample_antipodal_grasps(mesh, kk, gc(config.spread_grasp_config)))
            topdown_row[k] = int(g.T_part_grasp.shape[0])
            if config.topdown_grasp_config is not None:
                R0 = np.asarray(_se3(T_robot_part[0, k]).rotation().as_matrix(), np.float64)
                down = R0.T @ table_down
                pk = np.asarray((part_points if mesh_points is None else mesh_points)[k])
                g = merge_grasps(g, sample_topdown_grasps(pk, down, config.seed * 1009 + k, config.topdown_grasp_config))
            grasp_cache[k] = g
        return grasp_cache[k]

    # how far each free part turns from the first keyframe, in its own frame (K, 3 rotation vectors)
    turns = {k: _part_turns(T_obj_part[idx, k]) for k in (free_parts or ())} if config.free_twist_deg is not None else {}

    late_rows: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # part -> (twisting, short lever) per grasp row
    # (seating moves grasps along their approach only: the rows keep their flags)

    def late_flags(k: int) -> tuple[np.ndarray, np.ndarray]:
        """Part k's grasps that must turn it about their closing axis (a free part,
        ``free_twist_deg``) and those near its turn axis (a jointed part, ``short_lever_fraction``)."""
        if k not in late_rows:
            Tg = np.asarray(get_grasps(k).T_part_grasp)
            twist, short = np.zeros(Tg.shape[0], bool), np.zeros(Tg.shape[0], bool)
            if k in turns:
                twist = _grasp_twist(turns[k], Tg) > np.deg2rad(config.free_twist_deg)
            if config.short_lever_fraction is not None and k not in (free_parts or ()):
                short = _short_lever(T_obj_part[idx, k], Tg, np.asarray(part_points[k]), config.short_lever_fraction,
                                     np.deg2rad(config.short_lever_turn_deg))  # fmt: skip
            late_rows[k] = (twist, short)
        return late_rows[k]

    def twisting(k: int, i) -> np.ndarray:
        """Whether grasps ``i`` of part k rank after the others of their tier (:func:`late_flags`)."""
        twist, short = late_flags(k)
        return (twist | short)[np.asarray(i)]

    def tier_starts(k: int) -> tuple[int, ...]:
        """First rows of part k's tiers 1–3 (:func:`_tier`): near the hands, spread, top-down."""
        return (hand_row[k] if config.hand_grasp_tier else spread_row[k], spread_row[k], topdown_row[k])

    hand = hand_geometry(robot_lite, coll.proxy)
    seat_cache: dict[int, tuple[PartGrasps, np.ndarray, np.ndarray]] = {}

    def get_seated(k: int) -> tuple[PartGrasps, np.ndarray, np.ndarray]:
        """Grasps of part k backed off to their seating depth, the 'clears' mask, the depths."""
        if k not in seat_cache:
            g = get_grasps(k)
            Tg = np.asarray(g.T_part_grasp, float)
            opening = np.clip(np.asarray(g.width) / 2, 0.0, open_grip).astype(np.float32)
            # the approach ends at the grasp with the fingers at its narrowest opening
            narrow = min((c for c in clear if c is not None), default=None)
            opening_app = (np.full_like(opening, open_grip) if narrow is None
                           else np.clip(opening + narrow, 0.0, open_grip).astype(np.float32))  # fmt: skip
            ok, depth = _seat_grasps(robot_lite, hand, coll.sdf, Tg, opening, np.asarray(g.valid, bool), T_robot_obj,
                                     T_obj_part[idx, k], T_robot_part, k, config,
                                     opening_approach=opening_app if config.seat_approach_opening else None)  # fmt: skip
            offs = jnp.stack([jnp.zeros(len(depth)), jnp.zeros(len(depth)), -jnp.asarray(depth)], -1)
            Tg_s = (_se3(Tg) @ jaxlie.SE3.from_translation(offs)).wxyz_xyz
            seat_cache[k] = (eqx.tree_at(lambda x: x.T_part_grasp, g, jnp.asarray(Tg_s, g.T_part_grasp.dtype)), ok, depth)
        return seat_cache[k]

    def single_arm(k: int, arm: int) -> tuple[_Batch, np.ndarray, dict, np.ndarray]:
        g, seated, _ = get_seated(k)
        Tg = np.asarray(g.T_part_grasp, float)
        n = Tg.shape[0]
        target = np.repeat(np.repeat(home_tcp[None, None], n, 0), K, 1)  # (n, K, 2, 7)
        target[:, :, arm] = grasp_targets(T_robot_obj, T_obj_part[idx, k], Tg)
        active = np.zeros((n, 2), np.float32)
        active[:, arm] = 1
        x0 = np.repeat(np.repeat(home[None, None], n, 0), K, 1)
        mask = hand_part_mask(coll.proxy, P, [(arm, k)], pads_only=config.check_palm_on_grasped_part)
        grip = np.full((n, 2), open_grip, np.float32)
        grip[:, arm] = np.clip(np.asarray(g.width, np.float32) / 2, 0.0, open_grip)
        valid = np.asarray(g.valid, bool)
        # only grasps that are valid and seat without collision are solved (the rest keep NaN
        # joints / infinite errors and are counted at their own stage)
        sel = np.nonzero(valid & seated)[0]
        # best score first, the top-down set after every mesh grasp (so it never displaces one)
        late = (sel >= topdown_row.get(k, np.iinfo(np.int64).max)).astype(int) * 2
        if config.hand_grasp_tier:  # under the cap too, the grasps near the hands after the others
            late += (sel >= hand_row.get(k, np.iinfo(np.int64).max)) & (sel < spread_row.get(k, 0))
        sel = np.sort(sel[np.lexsort((-np.asarray(g.score)[sel], twisting(k, sel), late))][: config.max_candidates])
        b = _Batch(q=np.full((n, K, 16), np.nan, np.float32), cost=np.full(n, np.inf, np.float32),
                   lm_result=np.zeros(n, np.int32), iterations=np.zeros(n, np.int32),
                   pos=np.full((n, 2), np.inf, np.float32), rot=np.full((n, 2), np.inf, np.float32),
                   viol=np.full(n, np.inf, np.float32), mins=np.full((n, 3), -np.inf, np.float32),
                   pos0=np.full(n, np.inf, np.float32), rot0=np.full(n, np.inf, np.float32))
        if len(sel):
            bs = _run_candidates(params, robot_lite, coll, x0[sel], target[sel], active[sel], T_robot_part, mask,
                                 config, acceleration, grip[sel], first_weight=config.grasp_keyframe_weight)
            b = _Batch(*[np.asarray(full).astype(np.asarray(part).dtype) for full, part in
                         zip(jax.tree.leaves(b), jax.tree.leaves(bs))])
            for full, part in zip(jax.tree.leaves(b), jax.tree.leaves(bs)):
                full[sel] = part
        # Bimanual: the other arm is still at home here, so collisions are checked after the
        # joint 16-DoF solve only.
        solved = np.zeros(n, bool)
        solved[sel] = True
        alive, counts = _reject(b, valid, config, collision=not config.bimanual, seated=seated, solved=solved)
        return b, alive, counts, target

    best = None
    last_stage = None  # the furthest stage any attempt reached (its failure is the one reported)
    any_grasp = False
    for parts in order:
        assignments = []
        if config.bimanual:
            left, right = parts
            assignments = [((0, right), (1, left)), ((0, left), (1, right))]
        else:
            assignments = [((arm, parts[0]),) for arm in config.arms]
        for assign in assignments:
            att = {"parts": {ARM_NAMES[a]: int(k) for a, k in assign}, "rejections": {}}
            info["attempts"].append(att)
            per_arm = []
            for a, k in assign:
                g = get_grasps(k)
                if not bool(np.any(np.asarray(g.valid))):
                    per_arm = None
                    att["rejections"][ARM_NAMES[a]] = {"grasp_invalid": int(np.asarray(g.valid).size)}
                    info["rejections"]["grasp_invalid"] += int(np.asarray(g.valid).size)
                    break
                any_grasp = True
                b, alive, counts, target = single_arm(k, a)
                g = get_seated(k)[0]
                att["rejections"][ARM_NAMES[a]] = counts
                for s, c in counts.items():
                    info["rejections"][s] += c
                per_arm.append((a, k, b, alive, target, g))
            if per_arm is None:
                continue
            stage = _first_empty_stage(per_arm, att)
            if stage is not None:
                last_stage = _furthest(last_stage, stage)
                continue
            cand = _combine(per_arm, params, robot_lite, coll, T_robot_part, config, acceleration, open_grip, att, info,
                            {k: tier_starts(k) for k in spread_row}, twisting)
            if cand is None:
                last_stage = _furthest(last_stage, att.get("failed_stage", "collision"))
                continue
            # approach
            plan = _approach(cand, params, robot_lite, coll, T_robot_part, config, acceleration, open_grip, att, info)
            if plan is None:
                last_stage = _furthest(last_stage, "approach")
                continue
            if best is None or (plan["tier"], plan["twist"], plan["cost"]) < (best["tier"], best["twist"], best["cost"]):
                best = plan
        if best is not None:
            break

    info["time_s"] = round(time.perf_counter() - t_start, 3)
    if best is None:
        info["failed_stage"] = last_stage
        if not any_grasp:
            return _failure(PlanResult.no_grasp, "no antipodal grasp on the requested parts", T_robot_obj, idx, info)
        res, msg = {
            "joint_limits": (PlanResult.joint_limits, "all tracking candidates violate joint limits"),
            "collision": (PlanResult.collision, "all remaining candidates collide along the trajectory"),
            "grasp_collision": (PlanResult.collision, ("at every grasp the gripper itself hits the table or the "
                                                       "object along the trajectory (at every seating depth)")),
            "approach": (PlanResult.approach, "no remaining candidate has a collision-free approach"),
        }.get(last_stage, (PlanResult.unreachable,
                           "no grasp candidate tracked the trajectory within tolerance (unreachable)"))
        return _failure(res, msg, T_robot_obj, idx, info)
    info["chosen"] = {k: v for k, v in best.items() if k in ("parts", "grasp_index", "cost", "lm_result", "iterations")}
    rows = [(int(k), int(i)) for k, i in zip(best["part"], best["grasp_index_arr"]) if k >= 0]
    big = np.iinfo(np.int64).max  # (grasps given: no later sets)
    info["chosen"]["spread_grasp"] = any(spread_row.get(k, big) <= i < topdown_row.get(k, big) for k, i in rows)
    info["chosen"]["hand_grasp"] = [bool(k >= 0 and hand_row.get(int(k), np.inf) <= i < spread_row.get(int(k), -1))
                                    for k, i in zip(best["part"], best["grasp_index_arr"])]  # fmt: skip
    info["chosen"]["topdown_grasp"] = any(i >= topdown_row.get(k, big) for k, i in rows)
    info["chosen"]["twisting_grasp"] = any(bool(late_flags(k)[0][i]) for k, i in rows)
    info["chosen"]["short_lever_grasp"] = any(bool(late_flags(k)[1][i]) for k, i in rows)
    info["chosen"]["tier"] = int(best["tier"])  # 0 best-scored, 1 near the hands, 2 spread, 3 top-down
    info["hand_points_mm"] = [[int(k), [round(1e3 * float(v), 2) for v in x]] for k, x in (hand_points or [])]
    info["chosen"]["grasp_depth"] = [float(seat_cache[int(k)][2][int(i)]) if k >= 0 else None
                                     for k, i in zip(best["part"], best["grasp_index_arr"])]
    q_key = best["q"]
    return RobotPlan(
        result=PlanResult.success, message="feasible plan found", keyframe_indices=idx, q_keyframes=q_key,
        q_video=resample_keyframes(q_key, idx, nT), q_approach=best["q_approach"], tcp_target=best["target"],
        tcp_approach_target=best["approach_target"], active=best["active"], part=best["part"],
        grasp_index=best["grasp_index_arr"], T_part_grasp=best["T_part_grasp"], grasp_width=best["width"],
        T_robot_obj=T_robot_obj, position_error=best["pos"], rotation_error=best["rot"],
        min_distance=best["mins"], info=info,
    )


def _furthest(a: str | None, b: str) -> str:
    """The later of two rejection stages (``STAGES`` order): the attempt that got furthest names
    the failure (an attempt on another part or arm whose grasps never seat says less about why
    the request failed than one whose seated grasps all missed the pose tolerance)."""
    return b if a is None or STAGES.index(b) > STAGES.index(a) else a


def _exhausting_stage(counts: dict) -> str:
    """The stage that removed the last candidates (counts from :func:`_reject`)."""
    last = "pose_error"
    for s in STAGES[1:]:
        if counts.get(s, 0) > 0:
            last = s
    return last


def _first_empty_stage(per_arm, att) -> str | None:
    for a, k, b, alive, target, g in per_arm:
        if not alive.any():
            return _exhausting_stage(att["rejections"][ARM_NAMES[a]])
    return None


def _top_per_base(ids: np.ndarray, base_index: np.ndarray, k: int, per_base: int) -> np.ndarray:
    """The first ``k`` of the candidate rows ``ids`` (in their order) taking at most ``per_base``
    rows of one base grasp (``base_index[row]``) before any further row of it (those follow, in
    order, when fewer base grasps survived)."""
    seen: dict[int, int] = {}
    first, rest = [], []
    for i in ids:
        b = int(base_index[i])
        seen[b] = seen.get(b, 0) + 1
        (first if seen[b] <= per_base else rest).append(int(i))
    return np.asarray((first + rest)[:k], int)


def _part_turns(T_obj_part_k: np.ndarray) -> np.ndarray:
    """(K, 3) rotation vectors of a part's turn from its first pose to each pose of ``(K, 7)``
    poses, in the part's own frame (``log(R_0ᵀ R_t)``)."""
    R = jaxlie.SE3(jnp.asarray(T_obj_part_k, jnp.float32)).rotation()
    return np.asarray((jaxlie.SO3(jnp.broadcast_to(R.wxyz[0], R.wxyz.shape)).inverse() @ R).log(), np.float64)


def _grasp_twist(turns: np.ndarray, T_part_grasp: np.ndarray) -> np.ndarray:
    """(n,) largest turn (rad) about each grasp's closing axis (its x axis, part frame) over the
    turns ``(K, 3)`` of :func:`_part_turns`."""
    axes = np.asarray(jaxlie.SO3(jnp.asarray(np.asarray(T_part_grasp)[..., :4], jnp.float32)).as_matrix(), np.float64)[..., :, 0]
    return np.abs(axes.reshape(-1, 3) @ turns.T).max(axis=1, initial=0.0)


def _short_lever(T_obj_part_k: np.ndarray, T_part_grasp: np.ndarray, points: np.ndarray, fraction: float,
                 min_turn: float) -> np.ndarray:
    """(n,) whether each grasp (part frame) lies within ``fraction`` × the farthest of the part's
    ``points`` (its rest-centroid frame, as the grasps') from the part's turn axis: the screw
    axis of its motion (object frame) from its first pose in ``(K, 7)`` to the one it turned
    most from. All False when it never turns by ``min_turn`` (rad)."""
    T = jaxlie.SE3(jnp.asarray(T_obj_part_k, jnp.float32))
    rel = T @ jaxlie.SE3(T.wxyz_xyz[0]).inverse()  # motion from the first pose, object frame
    rv = np.asarray(rel.rotation().log(), np.float64)
    th = np.linalg.norm(rv, axis=-1)
    n = np.asarray(T_part_grasp).reshape(-1, 7).shape[0]
    j = int(np.argmax(th))
    if th[j] < min_turn:
        return np.zeros(n, bool)
    w = rv[j] / th[j]
    R = np.asarray(rel.rotation().as_matrix(), np.float64)[j]
    t = np.asarray(rel.translation(), np.float64)[j]
    c = np.linalg.lstsq(np.eye(3) - R, t - (w @ t) * w, rcond=None)[0]  # a point on the axis
    R0, t0 = np.asarray(T.rotation().as_matrix(), np.float64)[0], np.asarray(T.translation(), np.float64)[0]
    dist = lambda x: np.linalg.norm(np.cross(x @ R0.T + t0 - c, w), axis=-1)  # noqa: E731  (part frame -> object frame at rest)
    return dist(np.asarray(T_part_grasp).reshape(-1, 7)[:, 4:]) < fraction * dist(np.asarray(points)).max()


def _tier(tier_rows: dict[int, tuple[int, ...]], k: int, i):
    """Tier of row(s) ``i`` of part ``k``'s grasps: how many of its tier start rows they reach."""
    i = np.asarray(i)
    return sum(((i >= r).astype(int) for r in tier_rows.get(k, ())), np.zeros(i.shape, int))


def _combine(per_arm, params, robot_lite, coll, T_robot_part, cfg: PlanConfig, acceleration, open_grip, att, info,
             tier_rows: dict[int, tuple[int, ...]], twisting=None):
    """Single arm: survivors ordered by (tier, twist, cost). Bimanual: top-k × top-k joint solves.
    Tier t = the number of ``tier_rows[k]`` (first rows of the grasps near the hands, of the spread
    set, of the top-down set) at or before the grasp's row: a grasp near a hand (tier 1) is used
    only after every best-scored grasp (tier 0), a spread one (2) after both, a top-down one (3)
    after all. ``twisting(k, rows)``: grasps that must turn a
    free part about their closing axis, ranked after the others of their tier."""
    tier = lambda k, i: _tier(tier_rows, k, i)  # noqa: E731
    twist = twisting or (lambda k, i: np.zeros(np.shape(i), bool))

    def order(k, b, alive):
        ids = np.nonzero(alive)[0]
        return ids[np.lexsort((b.cost[ids], twist(k, ids), tier(k, ids)))]

    if len(per_arm) == 1:
        a, k, b, alive, target, g = per_arm[0]
        ids = order(k, b, alive)
        active = np.zeros(2, bool)
        active[a] = True
        tw = twist(k, ids)
        return [dict(q=b.q[i], cost=float(b.cost[i]), lm_result=int(b.lm_result[i]), iterations=int(b.iterations[i]),
                     target=target[i], active=active, arms=[(a, k, i, g)], pos=b.pos[i], rot=b.rot[i], mins=b.mins[i],
                     tier=int(tier(k, i)), twist=bool(w)) for i, w in zip(ids, tw)]
    (a0, k0, b0, al0, t0, g0), (a1, k1, b1, al1, t1, g1) = per_arm
    i0 = _top_per_base(order(k0, b0, al0), np.asarray(g0.base_index), cfg.top_k_per_arm, cfg.bimanual_per_base)
    i1 = _top_per_base(order(k1, b1, al1), np.asarray(g1.base_index), cfg.top_k_per_arm, cfg.bimanual_per_base)
    pairs = [(i, j) for i in i0 for j in i1]
    n = len(pairs)
    K = b0.q.shape[1]
    x0 = np.zeros((n, K, 16), np.float32)
    target = np.zeros((n, K, 2, 7), np.float32)
    arm_sl = {0: slice(0, 7), 1: slice(7, 14)}
    for m, (i, j) in enumerate(pairs):
        x0[m] = b0.q[i]
        x0[m][:, arm_sl[a1]] = b1.q[j][:, arm_sl[a1]]
        target[m][:, a0] = t0[i][:, a0]
        target[m][:, a1] = t1[j][:, a1]
    active = np.ones((n, 2), np.float32)
    grip = np.zeros((n, 2), np.float32)
    for m, (i, j) in enumerate(pairs):
        grip[m, a0] = min(float(g0.width[i]) / 2, open_grip)
        grip[m, a1] = min(float(g1.width[j]) / 2, open_grip)
    mask = hand_part_mask(coll.proxy, T_robot_part.shape[1], [(a0, k0), (a1, k1)],
                          pads_only=cfg.check_palm_on_grasped_part)
    b = _run_candidates(params, robot_lite, coll, x0, target, active, T_robot_part, mask, cfg, acceleration, grip,
                        first_weight=cfg.grasp_keyframe_weight)
    alive, counts = _reject(b, np.ones(n, bool), cfg)
    att["rejections"]["bimanual"] = counts
    for s, c in counts.items():
        if s != "grasp_invalid":
            info["rejections"][s] += c
    if not alive.any():
        att["failed_stage"] = _exhausting_stage(counts)
        return None
    ids = np.nonzero(alive)[0]
    p0, p1 = (np.array([pairs[m][j] for m in ids], int) for j in (0, 1))
    pair_tier = np.maximum(tier(k0, p0), tier(k1, p1))
    pair_twist = twist(k0, p0) | twist(k1, p1)
    o = np.lexsort((b.cost[ids], pair_twist, pair_tier))
    return [dict(q=b.q[m], cost=float(b.cost[m]), lm_result=int(b.lm_result[m]), iterations=int(b.iterations[m]),
                 target=target[m], active=np.ones(2, bool),
                 arms=[(a0, k0, pairs[m][0], g0), (a1, k1, pairs[m][1], g1)], pos=b.pos[m], rot=b.rot[m],
                 mins=b.mins[m], tier=int(t), twist=bool(w)) for m, t, w in zip(ids[o], pair_tier[o], pair_twist[o])]


def _pads_to_grasped(robot_lite, coll, Qs: list, T_parts: np.ndarray, grasped: set, grip: np.ndarray,
                     cfg: PlanConfig, last: bool = False) -> np.ndarray:
    """(n, G) smallest distance (m) of each arm's finger pads to the parts it grasps in any
    candidate, along each solved approach ``Qs[j]`` (n, A, 16) without its last waypoint (with
    ``last``: at the last waypoint only), with the fingers at opening ``grip[:, j]``; evaluated in
    the solver's padded chunks (no new compile)."""
    own = ~hand_part_mask(coll.proxy, T_parts.shape[1], sorted(grasped), pads_only=True)  # exactly those pad rows
    n, A = Qs[0].shape[:2]
    chunk = max(1, cfg.chunk_size)
    out = np.full((n, len(Qs)), np.inf)
    zeros_t, zeros_a = jnp.zeros((chunk, A, 2, 7), jnp.float32), jnp.zeros((chunk, A, 2), jnp.float32)
    for j, Q in enumerate(Qs):
        Q = np.asarray(Q, np.float32).copy()
        if last:
            Q[:] = Q[:, -1:]
        else:
            Q[:, -1] = Q[:, -2]  # the last waypoint is left out
        for s in range(0, n, chunk):
            sl = np.minimum(np.arange(s, s + chunk), n - 1)
            m = min(chunk, n - s)
            ev = _evaluate(robot_lite, coll, jnp.asarray(Q[sl]), zeros_t, zeros_a, jnp.asarray(T_parts, jnp.float32),
                           jnp.asarray(own), jnp.asarray(0.0, jnp.float32), jnp.asarray(grip[sl, j], jnp.float32),
                           jnp.asarray(_pad_table_allowance(cfg), jnp.float32))  # fmt: skip
            out[s : s + m, j] = np.asarray(ev[3])[:m, 2]
    return out


def _approach(cands, params, robot_lite, coll, T_robot_part, cfg: PlanConfig, acceleration, open_grip, att, info):
    """Approach segments for the best candidates (batched; ``approach_candidates`` per tier, so a
    spread grasp still gets its approach when every best-scored one fails); the first that passes
    wins."""
    cands = [c for t in range(4) for c in [c for c in cands if c["tier"] == t][: cfg.approach_candidates]]
    A = max(2, cfg.approach_steps)
    n = len(cands)
    s = np.linspace(0.0, 1.0, A)
    target = np.zeros((n, A, 2, 7), np.float32)
    x0 = np.zeros((n, A, 16), np.float32)
    active = np.zeros((n, 2), np.float32)
    grasped = set()
    for m, c in enumerate(cands):
        for a, k, i, g in c["arms"]:
            grasped.add((a, k))
        x0[m] = c["q"][0][None]
        target[m] = c["target"][0][None]
        for a, k, i, g in c["arms"]:
            active[m, a] = 1
            T0 = _se3(c["target"][0, a])
            offs = jnp.stack([jnp.zeros(A), jnp.zeros(A), -cfg.approach_distance * (1.0 - jnp.asarray(s))], -1)
            path = jaxlie.SE3(T0.wxyz_xyz[None]) @ jaxlie.SE3.from_translation(offs)
            target[m, :, a] = np.asarray(path.wxyz_xyz)
    T_part0 = np.repeat(T_robot_part[:1], A, 0)
    mask = hand_part_mask(coll.proxy, T_robot_part.shape[1], sorted(grasped), pads_only=cfg.check_palm_on_grasped_part)
    # No rest pull here; instead a joint reference to the trajectory's first keyframe (weak along
    # the segment, strong at its end) keeps the segment in that keyframe's null-space branch.
    params_a = eqx.tree_at(lambda p: p.weights.rest, params, jnp.zeros_like(params.weights.rest))
    q_ref = x0.copy()
    ref_w = np.full((n, A), 0.1, np.float32)
    ref_w[:, -1] = 10.0  # end at the trajectory's first keyframe
    # The last waypoint reaches the same TCP pose as the trajectory's first keyframe, possibly
    # elsewhere in the arm's null space; it is replaced by that keyframe (last step recorded) before the
    # segment is checked, so the check sees the configuration the robot will take (with open
    # fingers here).
    q_first = np.stack([np.asarray(c["q"][0], np.float32) for c in cands])
    # the approach is made with the fingers opened beyond the grasp width: each solved approach is
    # checked at every opening of ``approach_clearance`` and takes the first that passes
    clear = cfg.approach_clearance if isinstance(cfg.approach_clearance, tuple) else (cfg.approach_clearance,)
    G = len(clear)
    grip = np.full((n, G, 2), open_grip, np.float32)
    for m, c in enumerate(cands):
        for a, k, i, g in c["arms"]:
            for j, cl in enumerate(clear):
                grip[m, j, a] = open_grip if cl is None else min(float(g.width[i]) / 2 + cl, open_grip)
    bs = _run_candidates(params_a, robot_lite, coll, x0, target, active, T_part0, mask, cfg, acceleration, grip,
                         q_ref, ref_w, q_last=q_first)  # fmt: skip
    alive_all = np.stack([_reject(bj, np.ones(n, bool), cfg, grasp=False)[0] for bj in bs], 1)  # (n, G)
    own = None
    if cfg.approach_pads_clear_part:
        # the open pads keep the margin from the grasped part on the way in (every waypoint but the
        # last, where they surround it and the proxies' few-mm conservatism decides nothing)
        own = _pads_to_grasped(robot_lite, coll, [bj.q for bj in bs], T_part0, grasped, grip, cfg)  # (n, G)
        alive_all &= own >= cfg.collision_margin
    at_grasp = None
    if cfg.approach_grasp_pads_margin is not None:
        # where the approach ends the open pads surround the part; none may end inside it
        at_grasp = _pads_to_grasped(robot_lite, coll, [bj.q for bj in bs], T_part0, grasped, grip, cfg, last=True)
        alive_all &= at_grasp >= cfg.approach_grasp_pads_margin
    # per candidate: its first passing opening (or, if none passes, the last, for the counts)
    pick = np.where(alive_all.any(1), np.argmax(alive_all, 1), G - 1)
    b = jax.tree.map(lambda *fs: np.stack(fs, 1)[np.arange(n), pick], *bs)
    grip = grip[np.arange(n), pick]
    alive, counts = _reject(b, np.ones(n, bool), cfg, grasp=False)
    if own is not None:
        own_m = own[np.arange(n), pick]
        counts["pads_on_part"] = int(np.sum(alive & (own_m < cfg.collision_margin)))
        alive &= own_m >= cfg.collision_margin
        att["approach_pads_to_part_best"] = round(float(own_m.max()), 4) if n else None
    if at_grasp is not None:
        at_m = at_grasp[np.arange(n), pick]
        counts["pads_in_part_at_grasp"] = int(np.sum(alive & (at_m < cfg.approach_grasp_pads_margin)))
        alive &= at_m >= cfg.approach_grasp_pads_margin
        att["approach_pads_at_grasp_best"] = round(float(at_m.max()), 4) if n else None
    # largest joint step into the trajectory's first keyframe (large if the segment ended in another
    # null-space branch)
    end_gap = np.max(np.abs(b.q[:, -1, :14] - b.q[:, -2, :14]), axis=1)
    att["rejections"]["approach_checked"] = n
    att["rejections"]["approach"] = int(n - alive.sum())
    att["approach_rejections"] = {k: v for k, v in counts.items() if v}
    best_m = int(np.argmax(np.min(b.mins, 1)))
    att["approach_best_min_distance"] = np.round(b.mins[best_m], 4).tolist()  # (self, table, object)
    info["rejections"]["approach"] += int(n - alive.sum())
    if not alive.any():
        return None
    m = int(np.nonzero(alive)[0][0])
    c = cands[m]
    part = np.full(2, -1)
    gidx = np.full(2, -1)
    Tpg = np.full((2, 7), np.nan)
    width = np.full(2, np.nan)
    for a, k, i, g in c["arms"]:
        part[a], gidx[a] = k, i
        Tpg[a] = np.asarray(g.T_part_grasp[i])
        width[a] = float(g.width[i])
    mins = np.minimum(c["mins"], b.mins[m])
    q_app = np.asarray(b.q[m], float)
    q_app[:, 14:16] = grip[m]  # the finger opening of the approach (the simulator uses it)
    att["approach_last_step_rad"] = float(end_gap[m])
    att["approach_clearance"] = clear[pick[m]]
    return dict(
        q=np.asarray(c["q"], float), cost=c["cost"], lm_result=LMResult._index_to_message[c["lm_result"]],
        iterations=c["iterations"],
        target=np.asarray(c["target"], float), active=c["active"], part=part, grasp_index_arr=gidx,
        grasp_index=[int(v) for v in gidx], parts=[int(v) for v in part], T_part_grasp=Tpg, width=width,
        pos=np.asarray(c["pos"], float), rot=np.asarray(c["rot"], float), mins=np.asarray(mins, float),
        q_approach=q_app, approach_target=np.asarray(target[m], float), tier=c["tier"], twist=c["twist"],
    )
