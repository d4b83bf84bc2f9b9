"""Kinematic probes: does a motion do what its sentence asked? Measured on joint positions alone.

A text-to-motion model can score well on distribution metrics (FID, R-precision) and still ignore a word like
"backwards" or "left". These probes check single, physically obvious consequences of a sentence on the SMPL-22
joints [T, 22, 3] (metres, Y up, 20 fps), each against a fixed threshold, so that a model card can say "turns left
when asked in 9 of 10 tries". They are written for the ~3 s motions the probe runner asks for
(t2m/quality/probes.py) and are checked on real motion capture in tests/test_probes.py: each passes on a real clip of
its action and fails on a clearly different one.

| probe | measured quantity | passes when |
| --- | --- | --- |
| walk_forward | pelvis displacement along the initial facing (m) | > 0.5 m |
| walk_backward | the same | < -0.3 m |
| run_vs_walk | horizontal pelvis path of a run / of a walk with the same seed | > 1.25 |
| turn_left / turn_right | heading change, start to end (degrees; + = left) | > +45 / < -45 |
| raise_right / _left / _both | fraction of frames a wrist is above its shoulder | asked >= 0.2, other <= 0.1 |
| bow | forward trunk lean (pelvis -> neck from vertical), most minus first frames (deg) | > 20 degrees |
| kick | height of a foot's lowest point above the other foot's, while in front of the pelvis (m) | > 0.4 m |

"Initial facing" and "heading" come from the hip and shoulder lines (motion.features.forward_directions, lightly
smoothed) averaged over the first `START_FRAMES` frames: a generated motion starts wherever the model puts it, so
the probes never assume it starts facing +Z. The heading convention is motion.transforms.facing_angle's: positive
is counter-clockwise seen from above, i.e. turning to the person's left.

Calibration on motion capture (`t2m eval probes --real-clips DATASET_DIR`: the first 3 s of 15-30
random Bandai-Namco clips per label): each probe passes on 73-100% of the clips of its own action (turns: 73-77%,
as some clips turn after their third second; raised/waved hands: 80-93%, as some styles keep the hand at face
height) and on 0-7% of the others, except where the other motion really does it too (runs move forward, a `bye`
raises the right hand, the one spinning kick clip turns left and lifts its left hand). Two walks differ in speed
by over 1.25x in 20% of random pairs; a run beats a walk by that margin in 100%. The probes come in opposite
pairs (forward/backward, left/right), so a model that ignores the text cannot pass both of a pair.

`join_smoothness` measures a multi-sentence stream's seams: the pelvis velocity change across each join against the
typical frame-to-frame change inside the segments.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from t2m.motion.constants import FPS
from t2m.motion.features import forward_directions, validate_joints
from t2m.motion.skeleton import SMPL22

__all__ = [
    "PROBES",
    "STREAM",
    "JoinSmoothness",
    "ProbeResult",
    "ProbeSpec",
    "forward_displacement",
    "front_foot_lift",
    "heading_change",
    "initial_facing",
    "join_smoothness",
    "path_length",
    "probe_bow",
    "probe_by_name",
    "probe_kick",
    "probe_raise_hand",
    "probe_run_vs_walk",
    "probe_turn",
    "probe_walk_backward",
    "probe_walk_forward",
    "trunk_lean",
    "wrist_above_shoulder_fraction",
]

Side = Literal["left", "right"]
Hands = Literal["left", "right", "both"]

# ------------------------------------------------------------------ thresholds (documented in the module docstring)
START_FRAMES = 5                 # frames averaged for "the start" (0.25 s at 20 fps)
FACING_SMOOTH_SIGMA = 2.0        # frames; the raw hip/shoulder facing jitters a few degrees frame to frame
WALK_FORWARD_MIN_M = 0.5
WALK_BACKWARD_MAX_M = -0.3
RUN_OVER_WALK_MIN_RATIO = 1.25
TURN_MIN_DEG = 45.0
HAND_UP_MIN_FRACTION = 0.2
HAND_DOWN_MAX_FRACTION = 0.1
BOW_MIN_LEAN_DEG = 20.0
KICK_MIN_LIFT_M = 0.4
FRONT_MIN_M = 0.1             # "in front of the body": ankle this far ahead of the pelvis

_J = {name: index for index, name in enumerate(SMPL22.joint_names)}
PELVIS, NECK, HEAD = _J["pelvis"], _J["neck"], _J["head"]
_WRIST = {"left": _J["left_wrist"], "right": _J["right_wrist"]}
_SHOULDER = {"left": _J["left_shoulder"], "right": _J["right_shoulder"]}
_FOOT = {"left": (_J["left_ankle"], _J["left_foot"]), "right": (_J["right_ankle"], _J["right_foot"])}


@dataclass(frozen=True)
class ProbeResult:
    """One probe on one motion: the measured quantity, its unit, the rule it was held to, and the verdict."""

    probe: str
    value: float
    unit: str
    rule: str                 # e.g. "> 0.5 m"
    passed: bool
    details: dict[str, float] = field(default_factory=dict)


def _joints(joints: np.ndarray, min_frames: int = 2) -> np.ndarray:
    return validate_joints(joints, SMPL22, min_frames=min_frames)


# ------------------------------------------------------------------ measures

def _headings(joints: np.ndarray) -> np.ndarray:
    """Unwrapped heading per frame in radians (facing_angle's convention), from the smoothed facing."""
    forward = forward_directions(joints, SMPL22, smooth_sigma=FACING_SMOOTH_SIGMA)
    return np.unwrap(np.arctan2(forward[:, 0], forward[:, 2]))


def initial_facing(joints: np.ndarray) -> np.ndarray:
    """Unit horizontal direction [3] the body faces over its first START_FRAMES frames."""
    forward = forward_directions(_joints(joints, 1), SMPL22, smooth_sigma=FACING_SMOOTH_SIGMA)
    mean = forward[:START_FRAMES].mean(axis=0)
    return mean / np.linalg.norm(mean)


def forward_displacement(joints: np.ndarray) -> float:
    """Metres the pelvis ends up ahead (+) or behind (-) of where it started, along the initial facing."""
    array = _joints(joints)
    start = array[:START_FRAMES, PELVIS].mean(axis=0)
    end = array[-START_FRAMES:, PELVIS].mean(axis=0)
    return float((end - start) @ initial_facing(array))


def path_length(joints: np.ndarray) -> float:
    """Metres the pelvis travels on the floor (sum of horizontal frame-to-frame steps)."""
    pelvis = _joints(joints)[:, PELVIS][:, [0, 2]]
    return float(np.linalg.norm(np.diff(pelvis, axis=0), axis=1).sum())


def heading_change(joints: np.ndarray) -> float:
    """Degrees the body turned from its first to its last START_FRAMES frames; positive = to its left."""
    headings = _headings(_joints(joints))
    return float(np.degrees(headings[-START_FRAMES:].mean() - headings[:START_FRAMES].mean()))


def wrist_above_shoulder_fraction(joints: np.ndarray, side: Side) -> float:
    """Fraction of frames in which the `side` wrist is higher than the same side's shoulder."""
    array = _joints(joints, 1)
    return float(np.mean(array[:, _WRIST[side], 1] > array[:, _SHOULDER[side], 1]))


def trunk_lean(joints: np.ndarray) -> np.ndarray:
    """Forward lean of the trunk per frame, degrees: the pelvis -> neck line's angle from vertical, + = forward.

    Forward is the body's own (smoothed) facing in that frame, so a bow reads the same whichever way it is done.
    """
    array = _joints(joints, 1)
    forward = forward_directions(array, SMPL22, smooth_sigma=FACING_SMOOTH_SIGMA)
    trunk = array[:, NECK] - array[:, PELVIS]
    return np.degrees(np.arctan2((trunk * forward).sum(axis=1), trunk[:, 1]))


def front_foot_lift(joints: np.ndarray) -> float:
    """Metres, the highest a foot gets above the other foot while it is in front of the body.

    Per frame and foot: the foot's lowest point (ankle or toe joint) minus the other foot's, counted only when that
    ankle is more than FRONT_MIN_M ahead of the pelvis along the body's facing. Independent of where the floor is;
    a run's heel flick (high but behind the body) does not count, a kick (high and in front) does.
    """
    array = _joints(joints, 1)
    forward = forward_directions(array, SMPL22, smooth_sigma=FACING_SMOOTH_SIGMA)
    lowest = {side: array[:, list(_FOOT[side]), 1].min(axis=1) for side in ("left", "right")}
    best = 0.0
    for side, other in (("left", "right"), ("right", "left")):
        ahead = ((array[:, _FOOT[side][0]] - array[:, PELVIS]) * forward).sum(axis=1)
        lift = np.where(ahead > FRONT_MIN_M, lowest[side] - lowest[other], 0.0)
        best = max(best, float(lift.max()))
    return best


# ------------------------------------------------------------------ probes

def probe_walk_forward(joints: np.ndarray) -> ProbeResult:
    value = forward_displacement(joints)
    return ProbeResult("walk_forward", value, "m", f"> {WALK_FORWARD_MIN_M} m", value > WALK_FORWARD_MIN_M)


def probe_walk_backward(joints: np.ndarray) -> ProbeResult:
    value = forward_displacement(joints)
    return ProbeResult("walk_backward", value, "m", f"< {WALK_BACKWARD_MAX_M} m", value < WALK_BACKWARD_MAX_M)


def probe_run_vs_walk(run_joints: np.ndarray, walk_joints: np.ndarray) -> ProbeResult:
    """A paired probe: the run should cover clearly more floor than a walk of the same length (and seed)."""
    run, walk = path_length(run_joints), path_length(walk_joints)
    ratio = run / max(walk, 1e-3)
    return ProbeResult("run_vs_walk", ratio, "x", f"> {RUN_OVER_WALK_MIN_RATIO}", ratio > RUN_OVER_WALK_MIN_RATIO,
                       {"run_path_m": run, "walk_path_m": walk})


def probe_turn(joints: np.ndarray, side: Side) -> ProbeResult:
    if side not in ("left", "right"):
        raise ValueError(f"side: expected 'left' or 'right', got {side!r}")
    value = heading_change(joints)
    if side == "left":
        return ProbeResult("turn_left", value, "deg", f"> +{TURN_MIN_DEG:g} deg", value > TURN_MIN_DEG)
    return ProbeResult("turn_right", value, "deg", f"< -{TURN_MIN_DEG:g} deg", value < -TURN_MIN_DEG)


def probe_raise_hand(joints: np.ndarray, hands: Hands) -> ProbeResult:
    """The asked hand(s) above the shoulder in >= 20% of frames; a hand not asked for stays down (<= 10%)."""
    if hands not in ("left", "right", "both"):
        raise ValueError(f"hands: expected 'left', 'right' or 'both', got {hands!r}")
    up = {side: wrist_above_shoulder_fraction(joints, side) for side in ("left", "right")}
    asked = ("left", "right") if hands == "both" else (hands,)
    others = tuple(side for side in ("left", "right") if side not in asked)
    value = min(up[side] for side in asked)
    passed = value >= HAND_UP_MIN_FRACTION and all(up[side] <= HAND_DOWN_MAX_FRACTION for side in others)
    rule = f">= {HAND_UP_MIN_FRACTION} of frames" + (
        f", {others[0]} <= {HAND_DOWN_MAX_FRACTION}" if others else "")
    return ProbeResult(f"raise_{hands}", value, "fraction", rule, passed,
                       {"left_up_fraction": up["left"], "right_up_fraction": up["right"]})


def probe_bow(joints: np.ndarray) -> ProbeResult:
    """The trunk pitches forward by > 20 degrees from its starting lean at some frame (walking leans ~5-10)."""
    lean = trunk_lean(joints)
    value = float(lean.max() - lean[:START_FRAMES].mean())
    array = _joints(joints, 1)
    head_above_pelvis = array[:, HEAD, 1] - array[:, PELVIS, 1]
    return ProbeResult("bow", value, "deg", f"> {BOW_MIN_LEAN_DEG:g} deg", value > BOW_MIN_LEAN_DEG,
                       {"head_drop_m": float(head_above_pelvis[:START_FRAMES].mean() - head_above_pelvis.min())})


def probe_kick(joints: np.ndarray) -> ProbeResult:
    """A foot lifted > 0.4 m above the other in front of the body (real runs and dashes stay below 0.3)."""
    value = front_foot_lift(joints)
    return ProbeResult("kick", value, "m", f"> {KICK_MIN_LIFT_M} m", value > KICK_MIN_LIFT_M)


# ------------------------------------------------------------------ join smoothness of a stream

@dataclass(frozen=True)
class JoinSmoothness:
    """Pelvis velocity change (m/s per frame) at each join of a stream, against the changes inside its segments.

    `ratios[k]` = join k's change / the median change inside the segments: about 1-2 at any frame of a real clip,
    tens for two clips pasted together (hundreds if the position jumps too). A stream whose segments stand still
    has a small median, so `p95_ratios` (join change / the segments' 95th percentile change) says whether the join
    is sharper than the segments' own sharpest moments (> 1).
    """

    join_frames: tuple[int, ...]
    join_changes: tuple[float, ...]
    within_median: float
    within_p95: float
    ratios: tuple[float, ...]

    @property
    def p95_ratios(self) -> tuple[float, ...]:
        return tuple(change / max(self.within_p95, 1e-6) for change in self.join_changes)

    @property
    def worst_ratio(self) -> float:
        return max(self.ratios) if self.ratios else 0.0


def join_smoothness(joints: np.ndarray, join_frames: Sequence[int], fps: float = FPS) -> JoinSmoothness:
    """Velocity jumps at the joins `join_frames` (first frame of each segment after the first).

    The pelvis velocity v[t] = (p[t+1] - p[t]) * fps; its change a[t] = |v[t] - v[t-1]| is the frame-to-frame
    change at frame t. A join at frame j is charged the largest change among the steps that straddle it
    (a[j-1], a[j]); the "within" statistics use every change that does not touch a join.
    """
    array = _joints(joints, 4)
    frames = len(array)
    joins = tuple(int(j) for j in join_frames)
    for j in joins:
        if not 2 <= j <= frames - 2:
            raise ValueError(f"join_frames: join at frame {j} must be inside 2..{frames - 2} for a {frames}-frame "
                             "motion")
    velocity = np.diff(array[:, PELVIS], axis=0) * fps             # [T-1], v[t] = p[t+1] - p[t]
    change = np.linalg.norm(np.diff(velocity, axis=0), axis=1)     # [T-2], change[t-1] = |v[t] - v[t-1]|
    at_frame = np.concatenate([[np.nan], change])                   # at_frame[t] = |v[t] - v[t-1]|, t = 1..T-2
    touched = np.zeros(len(at_frame), dtype=bool)
    join_changes = []
    for j in joins:
        straddling = [j - 1, j]
        touched[straddling] = True
        join_changes.append(float(np.nanmax(at_frame[straddling])))
    within = at_frame[1:][~touched[1:]]
    median = float(np.median(within)) if len(within) else float("nan")
    p95 = float(np.percentile(within, 95)) if len(within) else float("nan")
    ratios = tuple(change_j / max(median, 1e-6) for change_j in join_changes)
    return JoinSmoothness(joins, tuple(join_changes), median, p95, ratios)


# ------------------------------------------------------------------ the probe set (sentences + checks)

@dataclass(frozen=True)
class ProbeSpec:
    """A probe as the runner uses it: sentences (none of them a training caption) and the check on the motion.

    A paired probe (`reference_phrasings` set) generates each phrasing and its reference with the same seed and
    calls `check(motion, reference_motion)`.
    """

    name: str
    phrasings: tuple[str, ...]
    check: Callable[..., ProbeResult]
    reference_phrasings: tuple[str, ...] = ()


# Provenance of the phrasings (so that a model card can say which ones could have influenced training): the first
# three of each probe were known when the 0.2.0 caption vocabulary was widened, the fourth and fifth were written
# before 0.2.0 was trained, the sixth before 0.3.0 was trained; none is used to tune anything.
PROBES: tuple[ProbeSpec, ...] = (
    ProbeSpec("walk_forward", ("someone strolls ahead", "a man paces forward at an easy gait",
                               "the person goes for a stroll straight in front of him",
                               "a person heads straight forward on foot", "the man marches onward",
                               "someone takes a leisurely walk forward"),
              probe_walk_forward),
    ProbeSpec("walk_backward", ("the person steps backwards", "someone retreats backwards step by step",
                                "a woman moves back without turning around, walking in reverse",
                                "someone backpedals slowly", "the man takes several steps to the rear",
                                "the woman backs away carefully"),
              probe_walk_backward),
    ProbeSpec("run_vs_walk", ("a man jogs quickly", "someone is running fast",
                              "the person sprints ahead as fast as possible", "a woman runs at a quick pace",
                              "the athlete races along", "a man dashes off at full speed"), probe_run_vs_walk,
              reference_phrasings=("a man strolls ahead", "someone is walking along at a normal pace",
                                   "the person strolls straight ahead", "a woman walks at a slow pace",
                                   "the athlete wanders along", "a man ambles off at a gentle speed")),
    ProbeSpec("turn_left", ("a woman turns to her left while walking", "someone walks and veers round to the left",
                            "the person strolls and then heads off to the left", "someone walking makes a sharp left",
                            "the person walks then turns ninety degrees to the left",
                            "a person walking rounds a corner to the left"),
              lambda joints: probe_turn(joints, "left")),
    ProbeSpec("turn_right", ("a man turns to his right while walking", "someone walks and veers round to the right",
                             "the person strolls and then heads off to the right",
                             "someone walking makes a sharp right",
                             "the person walks then turns ninety degrees to the right",
                             "a person walking rounds a corner to the right"),
              lambda joints: probe_turn(joints, "right")),
    ProbeSpec("raise_right", ("he lifts his right arm up high", "a person greets by waving the right hand",
                              "someone holds the right hand up above the head",
                              "the man reaches his right hand toward the sky",
                              "a person signals with the right hand raised", "someone puts the right arm straight up"),
              lambda joints: probe_raise_hand(joints, "right")),
    ProbeSpec("raise_left", ("she lifts her left arm up high", "a person greets by waving the left hand",
                             "someone holds the left hand up above the head",
                             "she reaches her left hand toward the sky", "a person signals with the left hand raised",
                             "someone puts the left arm straight up"),
              lambda joints: probe_raise_hand(joints, "left")),
    ProbeSpec("raise_both", ("he lifts both arms up high", "a person greets by waving both hands over the head",
                             "someone throws both hands up in the air",
                             "the woman cheers with both arms raised", "someone reaches for the sky with both hands",
                             "a person stretches both hands up overhead"),
              lambda joints: probe_raise_hand(joints, "both")),
    ProbeSpec("bow", ("someone bends forward in a polite bow", "a man bows his upper body deeply",
                      "the person greets with a respectful bow", "a person bows to the audience",
                      "the man bends his torso forward in greeting",
                      "the woman lowers her head and upper body in a bow"), probe_bow),
    ProbeSpec("kick", ("a fighter kicks", "someone kicks a leg out high", "the person does a kick in the air",
                       "someone kicks a ball hard", "the man delivers a front kick",
                       "a person kicks forward with one foot"),
              probe_kick),
)


# The three-sentence stream of the pictures and of the join measure: (sentence, seconds, probe of that segment).
STREAM: tuple[tuple[str, float, str], ...] = (
    ("someone strolls ahead", 3.0, "walk_forward"),
    ("a person greets by waving the right hand", 2.0, "raise_right"),
    ("someone bends forward in a polite bow", 2.0, "bow"),
)


def probe_by_name(name: str) -> ProbeSpec:
    for spec in PROBES:
        if spec.name == name:
            return spec
    raise ValueError(f"probe: unknown probe {name!r}; known: {', '.join(spec.name for spec in PROBES)}")
