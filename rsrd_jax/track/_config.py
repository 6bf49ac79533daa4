"""Tracking configuration. Defaults follow the RSRD paper/code (`shared/notes/reference_rsrd.md`)."""

from __future__ import annotations

import equinox as eqx


class LossWeights(eqx.Module):
    """Weights of the per-frame loss terms (array-like leaves: changing them does not recompile)."""

    feature: float = 1.0
    """Feature (decoded PCA feature) term, RSRD's DINO loss."""
    depth_rank: float = 0.2
    """Mono-depth ranking term on random pixel pairs inside the eroded rendered mask."""
    arap: float = 0.2
    """As-rigid-as-possible term on cross-part boundary pairs (Barron robust loss, mean over pairs).
    RSRD multiplies each pair's loss by a further 0.001 (2e-4 in all); measured on the studio red
    box with this project's feature fields, that weak a term lets the parts drift apart (box 35 mm
    after 40 frames from the true initial pose, with contact pivots), so the default keeps 0.2."""
    touch: float = 0.0
    """As-touching-as-possible term (`touch_loss`): contact Gaussians keep their distance to the
    *nearest* Gaussian of the other part, so sliding joints are not resisted as they are by
    pair-distance ARAP. Same Barron α and scale as ARAP. Off by default: measured with true
    initial pose on 30-frame demos, touch 0.2 instead of ARAP 0.2 gives red_box 3.9/12.8 mm (ARAP:
    3.6/5.9) and does not free nerf_gun's slide (4.9/22.6 mm; ARAP 3.1/21.5)."""
    rgb: float = 0.05
    """Photometric L1 term (RSRD's release uses 0.05; 0 disables it)."""
    support: float = 0.0
    """Support-plane term (`support_loss`, scale `arap_scale`): no Gaussian passes below the table
    the object rests on (`TrackConfig.support_plane`). Not in RSRD; off by default. Measured on the
    studio scissors (90 frames, joint discovery, the robot trials' build): at weight 1 the lowest
    blade centre stays 0.2 mm above the table instead of sinking 6.7 mm below it, but the blades
    still roll about their long axis (up instead of down: 38° instead of 55° at most) and the
    object-frame ADD grows from 4.7 / 7.6 to 5.8 / 8.4 mm."""


    hand: float = 0.01
    """Hand term (`hand_loss`): the point of the part each hand pinches projects onto the midpoint
    of its detected thumb and index tips (needs a `FingertipSource`; not in RSRD, which uses
    hands only to pick the parts to grasp)."""
    hand_depth: float = 0.0
    """Hand depth term (`hand_depth_loss`): each anchored hand's pinched point lies at the depth
    the mono-depth gives the hand (`Observer.hand_depths`): the table around the object has a
    known metric depth along each pixel's ray (the support plane, `TrackConfig.support_plane` or
    the model's, seen from the object's pose), and the hand's depth is where the table's
    mono-depth order against the hand's pinch point flips (only the order of the mono-depth is
    used, as by the ranking term). The 2D hand term leaves the held point free along its
    viewing ray. Needs a fingertip source, a mono-depth source and a support plane; 0 disables
    it. Not in RSRD."""

    motion: float = 0.0
    """Per-frame motion prior: the mean over parts of the squared tangent update away from the
    frame's initial guess (translations in object radii, rotations in radians). Where the data
    say little (a thin part's roll about its own axis, a part under the hand) the part stays
    where the extrapolation put it instead of wandering. Not in RSRD; per-frame solve only (the
    smoothing pass has its own smoothness term)."""


class TrackConfig(eqx.Module):
    """Options of `track_video` (4D-DPM). Every field is documented; the CLI exposes them."""

    weights: LossWeights = LossWeights()
    """Loss weights."""
    roi_size: int = 224
    """Side (pixels) of the square ROI crop the frame is resampled to before feature extraction."""
    roi_margin: float = 0.25
    """ROI = bounding box of the object's projection at the predicted pose, grown by this
    fraction of its extent on each side."""
    steps_per_frame: int = 50
    """Adam steps per frame."""
    lr_start: float = 5e-3
    """Initial learning rate (tangent units: metres and radians)."""
    lr_end: float = 1e-3
    """Final learning rate of the exponential decay (RSRD release: 1e-3; paper: 5e-4)."""
    translation_scale: float | None = None
    """Metres per unit of translation step (learning rates are in radians for rotations); None:
    the object's radius, so steps are relative to the object's size whatever its scale."""
    contact_pivots: bool = True
    """Apply each non-root part's tangent update about the centre of its ARAP contact pairs (the
    hinge region) instead of its centroid, so a hinge rotation is one coordinate of the update.
    Measured on the studio red box (30 frames, lid closing 97° at up to 7°/frame, feature field
    fitted on object crops): object-frame ADD box/lid 3.8/7.8 mm with, 3.0/34.7 mm without (the
    lid falls behind and loses its basin); 2.5/3.9 mm with smoothing and estimated initial pose."""
    joints: bool = False
    """Joint discovery (not for separable objects): a first per-frame pass with ARAP on the parts'
    whole contact band at weight `joint_first_arap` with a saturating loss (α = −2), a fit of each
    part's joint point from that pass's motion (parts that turn by `joint_min_angle_deg` relative
    to their neighbour), then the per-frame pass again with those parts tied only at their joint
    points (and pivoting about them), then smoothing. The first pass takes `joint_first_steps`
    per frame (1.5× the per-frame time in all at the defaults). Measured on 30-frame demos
    (`experiments/results/tracking_table.md`): mean object-frame ADD 8.8 → 7.0 mm over stapler,
    red_box, frog and nerf_gun. See `track._joints`."""
    joint_first_arap: float = 0.005
    """ARAP weight of the first pass (the second uses `weights.arap`)."""
    joint_first_motion: float = 0.0
    """Motion-prior weight of the first pass (the second uses `weights.motion`): the first pass
    must let parts move freely to reveal their joints (with `weights.motion` 0.1 in it too, the
    nerf gun's slide was fitted a hinge point and no slide hypothesis was tried: 3.9 → 19.4 mm)."""
    joint_first_steps: int | None = 25
    """Adam steps per frame of the first pass (None: `steps_per_frame`). Measured on 30-frame
    demos (pipeline-size builds): 25 steps gave stapler 2.6 / 6.0 mm, red_box 2.4 / 10.2 mm,
    50 steps 2.7 / 5.6 and 3.1 / 10.6 mm. (Starting the second pass from the first pass's poses
    with 25 steps instead lost red_box: 12.8 / 18.8 mm.)"""
    joint_min_angle_deg: float = 5.0
    """Smallest rotation relative to the neighbour part for which a joint point is fitted."""
    hinge_axes: bool = False
    """With `joints`: each part with a fitted joint point also gets a hinge axis (`hinge_axis`:
    among its principal axes and the support plane's normal, the one whose turns through the
    joint point best explain the first pass's point motion), and the second pass penalises its
    rotation off that axis relative to its neighbour (the revolute term, `revolute_loss`, at the
    ARAP weight). A ball joint leaves a thin part's roll about its own length to the features,
    which barely see it."""
    hinge_up_tolerance: float = 0.05
    """With `hinge_axes` and a known support plane: its normal is the hinge axis when its residual
    (`hinge_axis`) is within this fraction of the best candidate's. Measured on the studio frog
    (90 frames, the robot trials' build): the front leg's tilted minor principal axis (19° off
    the true vertical hinge) beat the table normal by 8.54 against 8.55 mm, and the tracked leg
    turned 28° of 40° with a 9° roll."""
    hinge_refine_deg: float | None = None
    """With `hinge_axes`: the chosen candidate axis is then turned, by at most this many degrees,
    to the direction whose turns best explain the first pass's point motion (`hinge_axis`'s
    `refine_deg`; `meta["joints"][k]["hinge_refined_deg"]` says by how much). A hinge need not
    lie along a principal axis of the part's Gaussians: the studio led_light's panel (its tab and
    knobs off-centre) has its first axis 5° off the hinge, and the panel, turning about it with
    the root held, overshot to 113.9° at frame 80 (90° true; panel 7.08 mm); refined within 15°
    the axis turned 2.4° (3.7° from the truth) and the panel ends at 100.3°, 3.78 mm (object
    2.18 mm against 3.81). But the first pass's motion is not always nearer the truth than the
    candidate: the stapler's arm axis turned 10.7° (object 0.73 → 2.20 mm; within 5°: 1.29 mm),
    wire_cutter's the full 15° (4.52 → 4.05 mm, still about the wrong axis). Session 50, the
    robot trials' builds, the pipeline's settings otherwise. None (the default): the candidate
    as chosen."""
    hinge_hands: bool = True
    """With `hinge_axes` and a fingertip source: where a hand held a hinged part (or its
    neighbour) in the first pass, the hinge candidates are also scored by how well turns about
    them move the hand's anchor along its 2D pinch track (`hand_hinge_residual`). A first pass
    that falls behind a fast turn under the hand settles on a turn that explains the part's
    points but not the hand's path: the studio bear's waving arm (126° in 30 frames, most of it
    hidden by the hand) was tracked about an axis 78° off its true one; with the pinch track the
    arm's principal axis 12° off it is chosen (robot trials' build, 120 frames: arm ADD 24.3 →
    10.0 mm, object mean 8.6 → 4.5 mm; `slide_hand_ratio` also rules out the arm's slides:
    tracking 1371 → 219 s)."""
    slides: bool = True
    """With `joints`: slide hypotheses. A part that moved relative to its neighbour in the first
    pass by more than `slide_min_m` and either did not turn or got a joint point far from the
    contact (`slide_point_ratio`) is tracked again in the second pass tied to its neighbour by a
    slide joint (the prismatic term, `prismatic_loss`, at the ARAP weight) along each of its
    principal axes and the level direction out of its neighbour (`slide_directions`); the hypothesis (joint point or one of the slides) with the lowest data loss
    summed over the frames wins (by `slide_min_gain`; against `slide_baseline`). Costs one
    second pass per slide direction tried, plus one on the joint point when no slide wins."""
    slide_held_only: bool = True
    """With `slides` and a fingertip source: only parts a hand held in the first pass (its hand
    anchors) are slide candidates (when no hand was anchored, every part stays one). Measured on
    the studio bear (120 frames, the robot trials' build): the first pass left the unmoved left
    arm and right leg 5+ mm off their neighbour, both became candidates and both "won" by < 0.4 %
    of the data loss (static parts tied by slide joints), in 1204 s of extra passes; the waved
    arm, the only one held, was no candidate."""
    slide_point_ratio: float = 0.0
    """A fitted joint point farther than this × the part's radius from the contact makes the
    part a slide candidate; 0 (since session 29): every part with a fitted joint point is one
    (with `slide_held_only`: every held one). The first pass's point is no reliable test: on
    the session-7 builds nerf_gun's slide scored 0.57, hinges 0.02–0.59 against 0.5, and on the
    robot trials' builds nerf_gun's slide (0.5 before session 29: ADD 5.03 / 19.96 mm, with 0:
    4.80 / 3.63) and toy_drawer's drawer fell below 0.5. The price: up to four more second
    passes per held hinged part (red_box +407 s at 120 frames; its hinge kept, every slide
    ≥ 3.9 % worse in data loss)."""
    slide_hand_ratio: float | None = 2.0
    """With `hinge_hands`: a held part's slide direction is not tried when the hand's pinch track
    fits a slide along it (`hand_slide_residual`) worse than this × the chosen hinge (plus
    `SLIDE_HAND_FLOOR_PX`): a hand that turned a part through a wide arc did not slide it. None:
    every direction is tried. Measured on the first passes of the robot trials' builds (pinch
    track RMS, px): bear's waving arm hinge 1.9, slides ≥ 8.3; red_box's lid 3.0 against ≥ 11.5;
    nerf_gun's slide 0.78 along its axis against 0.66 for the fitted hinge, toy_drawer's drawer
    0.40–0.61 against 0.33 (a short pull and a slight turn about a far point trace the same
    path); the frog's two held legs 2.0–12.5 against 2.6 and 6.1. So the bear's and the red box's
    slide passes (4 each) are skipped and every slide of nerf_gun, toy_drawer and the frog is
    still tried. Conversely (since session 48), when the hinge fits the pinch track worse than
    this × the best slide tried (plus the floor), the hinge is ruled out: that part's slide with
    the lowest data loss wins without beating the baseline (`slide_baseline="first"`: the first
    pass, a free part on a weak contact band, does not stand for a hinge). With
    `still_root` the first pass followed toy_drawer's pulled drawer freely (its data loss tied
    with the level slide's, 92.3208 against 92.3203) while the pinch track put the hinge at
    15.8 px and that slide at 1.4 px: the hinge was kept, 23.6 mm. On session 47's default
    tracks no part comes near the rule (hinge against best slide, px: toy_drawer 0.47 / 0.44,
    frog 2.95 / 3.43 and 1.14 / 1.57, nerf_gun 0.66 / 0.78)."""
    slide_max_turn_deg: float | None = 20.0
    """With `slides`: a candidate part that the first pass turned by more than this (degrees,
    relative to its neighbour, in any frame) is hinged and gets no slide hypothesis. None: no
    such test. Measured on the first passes of the robot trials' builds (held parts): the
    slides of nerf_gun 9.7–10.2° and toy_drawer 5.9–6.5°; the hinges of the frog's legs
    40–43° and 26–28° (true 40° and 34°), stapler 26.3°, scissors 17.8°, sunglasses 66.1°,
    bear 82.3°, red_box 91.8°, led_light 95.7°. The frog's 8 slide passes (all losing, by 0.05–0.9 % of
    the data loss) took 623 of its 768 s of tracking. Since session 47 the test applies only to
    parts whose slides no pinch track judges (`slide_hand_ratio` None, or no hand held the part):
    on a later machine the first pass turned toy_drawer's drawer 33.2° (its hinge 22.1 mm), and
    tracked along the level direction it is 3.90 mm (object 13.18 → 3.90 mm)."""
    slide_hand_best: int | None = 2
    """With `slide_hand_ratio`: of the slide directions the hand does not rule out, only this
    many with the lowest pinch-track residual are tried (None: all). On the robot trials' builds
    the hand's best direction is the one whose pass wins: nerf_gun's slide 0.78 px along x against
    1.14 and 1.30 (x won by 0.98 % of the data loss), toy_drawer's drawer 0.40 px along the level
    direction against 0.45–0.61 (won by 1.0 %); the other hypotheses' passes took 178 of
    nerf_gun's 451 s and 287 of toy_drawer's 561 s. 2 since session 47: on session 44's machine
    toy_drawer's winning direction (level, 0.58 px) was the hand's second best (the best, its
    second principal axis at 0.44 px, gained 0.19 % of the data loss, the level one 0.60 %)."""
    slide_min_gain: float = 0.005
    """A slide hypothesis replaces the one chosen so far only when its data loss summed over the
    frames is lower by more than this fraction. Measured (robot trials' builds, every held part
    with a fitted joint a candidate): nerf_gun's true slide won by 0.98 % (ADD 5.03 / 19.96 →
    4.80 / 3.63 mm); toy_drawer's drawer, whose principal axes are its plate's diagonals, got a
    vertical slide by 0.18 % (ADD 4.69 / 23.31 → 10.05 / 24.06 mm)."""
    slide_baseline: str = "first"
    """What the first slide hypothesis must beat (by `slide_min_gain`): "first", the joint
    discovery's first pass (the contact band, `joint_first_steps`, one start), whose data loss is
    already known; "joint" (before session 39), a pass on the joint point with the hypotheses'
    two starts (`slide_velocity`). Either way a later hypothesis must beat the best so far, and
    when no slide wins the joint point is tracked with `velocity_hypothesis`. "first" saves a
    pass with two starts per frame: on nerf_gun and toy_drawer a third of the tracking, the same
    trajectories (robot trials' builds, session 39). The first pass's data loss was as low as the
    joint point's pass or lower (nerf_gun 84.41 against 84.39, toy_drawer 92.79 / 92.83, red_box
    89.32 / 89.43; summed over 90 frames): its weak band lets the parts fit each frame freely,
    so it is the stricter baseline. The true slides beat it by 1.0 % (nerf_gun 83.56,
    toy_drawer 91.89); red_box's lid made a candidate on every direction (`slide_max_turn_deg`
    and `slide_hand_ratio` off) lost by 4.0–5.0 % (92.91–93.76)."""
    slide_velocity: float | None = 1.0
    """`velocity_hypothesis` of every second-pass hypothesis when there are slide candidates (None:
    `velocity_hypothesis`), so that their data losses compare like with like (on toy_drawer the
    joint point tracked with one start scored 96.6 against 92.8–93.5 for every slide with two);
    when the joint point wins, it is tracked once more with `velocity_hypothesis` (since session
    29; before, the hinges of red_box and frog kept this pass: ADD 2.68 → 3.37 and 2.03 → 3.13
    mm). Measured on nerf_gun with the true slide axis: slide ADD 11.9 mm with one start, 3.3 mm
    with 1.0. One start extrapolated with 1.0 alone (half the cost) lost both slides on the
    robot trials' builds (session 33: nerf_gun 4.22 → 15.89 mm, toy_drawer 4.86 → 13.73 mm)."""
    slide_min_m: float = 0.005
    """Smallest displacement relative to the neighbour (first pass) for a slide joint."""
    hand_anchor_cells: float = 1.0
    """Hand term: the radius (feature cells) about a pinch point over which the held part is
    judged (`hand_anchor_by`) and whose Gaussians of that part give the held point
    (`track._hands`)."""
    hand_anchor_by: str = "visible"
    """Hand term: how the held part is chosen. "visible": the part the render shows under the
    pinch point (blend weights at it and around it, `splat.blend_weights`; anchored once the
    render is at least half opaque at one of those points); "opacity" (sessions ≤ 39): the largest
    opacity-weighted share of the Gaussians projecting near it, in front of or behind the
    pinched part alike (a rebuilt usb_plug model gave the plug's hand to the brick behind it)."""
    hand_scale_cells: float = 0.5
    """Barron scale c of the hand term's reprojection distance, feature cells."""
    hand_alpha: float = 0.0
    """Barron α of the hand term (0: Cauchy; a hand that left its part pulls ever less)."""
    velocity_factor: float = 0.2
    """Initial guess of a frame: previous pose composed with this fraction of the last motion."""
    velocity_hypothesis: float | None = None
    """A second start per frame: the previous pose extrapolated with this velocity factor (1.0:
    full constant velocity), solved on the same observations; the lower final loss wins (its
    count is `meta["velocity_hypothesis_frames"]`). None: one start (`velocity_factor`). Costs a
    second solve per frame from the third frame on. Measured with 1.0 (30-frame demos, joint
    discovery, lr 1e-2, the robot trials' builds): led_light's lid 29.7 → 10.9 mm, sunglasses'
    folding arm 59.8 → 45.7 mm, but red_box's lid 5.5 → 10.4 mm and frog's mean 3.8 → 4.2 mm
    (a lower frame loss is not always the truer pose); off by default."""
    rebin_every: int = 1
    """The per-frame solve bins the Gaussians into the rasterizer's tiles on the first of every
    this many Adam steps and renders the steps between on those per-tile lists (`splat.render(
    bins=)`: each Gaussian keeps the tiles it met and its depth rank there); the final render,
    which scores the frame and checks the budgets, is binned afresh. 1: every step binned.
    Binning (depth sort, pair sort, chunk lists) is a fifth of a step on CPU. Measured on
    nerf_gun (a captured frame, 50 steps, the parts moved 4.8 mm): 1 → 412 ms, 5 → 320 ms,
    10 → 309 ms per solve; solved points within 0.06 mm (5) and 0.08 mm (10) of 1's. With 5
    over the 11 robot-trial builds (session 37): 1.51–2.29 frames/s without slide hypotheses
    (1.30–1.96 with 1), nerf_gun 0.83; the object-frame ADD of the 10 others 4.28 mm on average
    (4.30 with 1, each within ±1.1 mm), but toy_drawer's slide, which had won its comparison by
    1.0 % of the data loss, won it by 0.26 % (< `slide_min_gain`), and its drawer was tracked on
    the joint point: 4.86 → 13.87 mm. Off by default until that choice is robust."""
    parallel_starts: bool = True
    """Solve a frame's two starts (`velocity_hypothesis`, `slide_velocity`) at once, one thread
    each; the same results as one after the other. XLA's CPU runtime runs one solve on about
    1.5 of this machine's 2 cores and runs the calls of one thread in order: on nerf_gun (a
    captured frame, 50 steps) 8 solves took 3.3 s one after the other, 2.1–2.3 s from two
    threads."""
    table_pairs: int = 2000
    """Table pixels a hand's depth is read off per frame (`LossWeights.hand_depth`)."""
    hand_depth_calibration: int = 5
    """The hand depth term acts on a hand once its depth read off the table was known on this
    many frames after its anchoring: the median offset between the tracked surface point's depth
    and that reading on them shifts the later readings (the pinch pixel sees the part's surface
    or a finger, not the anchored point, a bias of up to a finger's or the part's thickness;
    without the shift the stapler's held arm went from 1.8 to 3.4 mm and the red box's lid from
    2.0 to 3.4 mm; with it 1.8 and 2.0 mm, and the usb_plug's plug 9.9 mm instead of 11.6)."""
    hand_depth_attached: bool = False
    """Whether the hand depth term (`LossWeights.hand_depth`) also acts on objects whose parts
    are attached (not `separable`). Off: there the joints already tie a held part's depth to the
    rest, and the table reading, biased by the hand's and the part's shapes, pulled held parts
    off (robot-trial builds, pipeline tracking, weight 0.2: nerf_gun 4.22 -> 10.84 mm, frog 2.03
    -> 4.59, toy_drawer 4.86 -> 13.60); on the separable
    usb_plug it is what follows the lifted plug (21.4 -> 8.8 mm)."""
    hand_depth_scale: float = 0.01
    """Cauchy scale of the hand depth term, metres (studio usb_plug before the calibration, ARAP
    weight 0: plug 10.3 mm at 0.01, 10.6 mm at 0.005)."""
    rank_pairs: int = 4096
    """Random pixel pairs of the depth ranking loss per step."""
    alpha_mask: float = 0.8
    """Rendered alpha above which a pixel counts as object (ranking mask, per-part residuals)."""
    arap_alpha: float | None = None
    """Barron α of the ARAP loss; None: 1.0 for attached parts, 0.1 for separable objects."""
    separable_arap: float | None = 2e-4
    """ARAP weight for separable objects (None: `weights.arap`): RSRD's effective weight (0.2 ×
    its 0.001 per pair). At `weights.arap` (0.2) the pairs between the studio usb_plug's plug and
    its socket held the plug in place while the hand pulled it out (Barron α 0.1 barely
    saturates: 41 against the hand term's 0.3 in gradient per metre, 20 mm out); with 2e-4 the
    hand pulls it out (34.6 mm: along the wrong viewing depth), and with the hand depth term too
    the plug is tracked at 9.9 mm instead of 38.6 mm (robot trials' build)."""
    separable_motion: float | None = None
    """Motion-prior weight for separable objects (None: `weights.motion`). Nothing but the
    motion prior holds a separable object's parts where the data say little (their ARAP is
    RSRD's 2e-4, `separable_arap`): on the studio usb_plug (the robot trials' build, 90 frames)
    with the pipeline's 0.1 the brick, held still by one hand, turned 34° and moved 22–36 mm
    while the other hand pulled the plug out (object-frame ADD brick / plug 10.6 / 12.1 mm); with
    1.0 it turned at most 9° (3.3 / 8.3 mm), with 3.0 2.4 / 6.5 mm, with 10 the plug lagged
    the pull (1.7 / 20.0 mm); `PipelineConfig.track_motion_separable` (3.0)."""
    arap_scale: float = 0.001
    """Barron scale c of the ARAP loss, metres."""
    support_plane: tuple[float, float, float, float] | None = None
    """(n, d) of the support term, object frame (n·x = d, n up); None: the model's
    `meta["support_plane"]` (the build fits it to the scan's table, `parts.support_plane`, when
    the scan has depth and masks), else no plane (the term is off)."""
    smooth_iters: int = 30
    """Joint temporal smoothing iterations after the per-frame pass (0 disables smoothing)."""
    smooth_batch: int = 8
    """Frames rendered per smoothing iteration (a random minibatch; smoothness uses all frames)."""
    smooth_weight: float = 0.2
    """Weight of the first-difference pose smoothness term (RSRD: 0.2)."""
    smooth_lr: float = 2e-3
    """Adam learning rate of the smoothing pass."""
    lod_cells: float | None = None
    """Level of detail: merge each part's Gaussians on a voxel grid of this fraction of an ROI
    feature cell (at the object's size: ROI side ≈ object diameter × (1 + 2·margin)); the render
    then costs a fraction of the scan-resolution model's (0.5: 3.6× fewer Gaussians, 3× faster per
    step on the red box). Off by default: merging changes the decoded features of the nonlinear
    field decoder by ~50 % of their norm (the colour/alpha by ~2 %). None: no merge."""
    max_gaussians: int = 12000
    """Gaussians used for tracking (a fixed random subset if the model has more after merging)."""
    render_headroom: float = 1.25
    """Margin (≥ 1) of the rasterizer's chunk budget (`splat.choose_config`) over what the first
    frame's ROI render needs; its list capacity and pair budget, which cost little, get twice
    this margin. A frame whose final render is not exact under the budgets (a truncated tile,
    dropped pairs) widens them at its solved pose and is solved again (one more compilation;
    listed in `meta["render_budget_growths"]`), so a small margin costs no accuracy. The
    per-step cost follows the chunk budget, not the real counts: on nerf_gun (robot trials'
    build, frame 40) a 50-step solve took 0.57 s with 2.0 for every budget (the margin before
    session 36), 0.34 s with 1.25."""
    still_root: bool = False
    """Hold the root (part 0) at the pose frame 0's solve gives it for the rest of the video
    (its updates are zero from frame 1 on, in the per-frame passes and the smoothing; with
    `joints` from the second pass on, see `still_root_first`): the camera is still and the
    object rests where it stands, so only the other parts move (the studio's demos; RSRD's
    object on a table). Off: every part, the root too, is tracked in the object frame, and a
    root the tracker pulls along with a moved part drifts (the studio roots' first passes moved
    them 3–18 mm; toy_drawer's cabinet 12.4 mm along its pulled drawer). With `joints` it needs
    `slide_baseline="joint"` (the free first pass is no baseline for hypotheses that hold the
    root; refused otherwise). The pipeline's default (`PipelineConfig.track_still_root`). On the
    robot trials' 11 builds (session 49, `experiments/results/tracking_pipeline_s49.md`) mean
    object-frame ADD 3.94 → 2.17 mm, every root 0.05–0.85 mm, toy_drawer 3.90 → 1.03, nerf_gun
    4.78 → 1.24, sunglasses 6.07 → 2.66, bear 5.64 → 2.30; led_light 2.13 → 3.81: its panel's
    joint point lies 1.5 mm off the hinge line (session 50; session 49 misreported 15 mm), but the
    held root stays where frame 0's solve put it, 14.4 mm too far from the camera and 1.9° off,
    and the panel, tied to it, turns to 113.9° at frame 80 (90° true; with the root free it drifted
    4.3 mm and the panel turned 91.8° relative to it)."""
    still_root_first: bool = False
    """With `still_root` and `joints`: the joint discovery's first pass holds the root too. Off:
    the first pass tracks the root freely, so that a drift common to every part is not read as a
    joint's motion; the root is held from the second pass on. On (session 48's `still_root`):
    led_light's first pass turned the panel 65.5° of 90° and its joint point came out 17.3 mm off
    the hinge line (1.5 mm with the root free; session 50, where session 49 had misreported 28
    and 15 mm), ADD 5.09 mm (3.81 free)."""
    seed: int = 0
    """PRNG seed (pair sampling, Gaussian subset)."""


class InitConfig(eqx.Module):
    """Object pose initialisation on the first frame (also used for robot-view registration)."""

    yaw_seeds: int = 8
    """Distinct yaw seeds, evenly spaced over 360° (not endpoint-inclusive)."""
    altitudes_deg: tuple[float, ...] = (30.0, 55.0)
    """Camera elevation hypotheses (degrees above the object's horizontal plane); each yaw seed is
    tried at each altitude."""
    distance_m: float | None = None
    """Camera-to-object distance prior; None: per seed, from the located region's image area and
    the seed view's silhouette (or from metric depth when given)."""
    iters: int = 80
    """Adam iterations of a seed that is optimised to the end (seeds in parallel under vmap)."""
    screen_iters: int = 30
    """Successive halving: every seed gets this many iterations, then only the `keep_seeds` with
    the lowest loss continue to `iters` (0 or ≥ `iters`: every seed runs `iters`). Measured on
    four studio demos (16 seeds, 80 iterations): the seed that ends best was first or second
    after 30 iterations in all four, and the seed stage costs 680 instead of 1280 seed-steps."""
    keep_seeds: int = 4
    """Seeds that continue after the screening iterations."""
    parallel: bool = True
    """Run the seed batches after the first (`keep_seeds` seeds each, vmapped) two at a time on
    two threads (`rsrd_jax._threads`); the same results as one after the other."""
    refine_iters: int = 60
    """Iterations refining the best seeds on an ROI crop around the best: the `keep_seeds` lowest
    (one batch of the single compiled seed optimiser), each from its own pose; the lowest refined
    loss wins."""
    lr_start: float = 1e-2
    """Initial learning rate."""
    lr_end: float = 4e-3
    """Final learning rate."""
    match_gaussians: int = 3000
    """Gaussians whose decoded features locate the object on the frame (`locate_object`)."""
    locate_fraction: float = 0.5
    """The object's region on the first frame: connected cells whose contrast score exceeds this
    fraction of the smoothed peak (`locate_object`). Its centre gives the ray, its area each
    seed's distance (where the model's silhouette seen from that seed covers it)."""
    occluded_weight: float = 0.5
    """Factor on the contrast score of occluded (hand) cells when locating the object: a hand
    can cover all of a small object on the first frame (studio usb_plug)."""
    locate_support: bool = True
    """Use the relative depth (when a mono-depth source is given) to find the table plane and
    damp the contrast score of cells on it (`locate_object`, `support_height`): without it the
    near table at the bottom of the studio toy_drawer's and usb_plug's first frames won the
    contrast or joined the object's region (`experiments/results/init_table.md`)."""
    depth_weight: float = 1.0
    """Weight of the metric depth term when metric depth is given (registration)."""
