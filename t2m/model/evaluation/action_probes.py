"""Probes for the actions the captioned CMU trials add: jump, invert (cartwheel, handstand, flip), get up.

Written before any model was trained on those trials, so that the model that learns them is measured by rules it
could not have been tuned to. Like t2m.model.evaluation.probes, each checks one physically obvious consequence of
the sentence on the SMPL-22 joints [T, 22, 3] (metres, Y up, 20 fps) against a fixed threshold. The floor is the
motion's own (5th percentile of the lower foot's height), since a generated motion may float or sink a little.

| probe | measured quantity | passes when |
| --- | --- | --- |
| jump | both feet off the floor at once (m); the pelvis over its median height (m) | off > 0.10, rise > 0.12 |
| invert | the lower foot above the head, at the most inverted frame (m) | > 0.10 m |
| get_up | pelvis height over the floor at the start and at the end (m) | start < 0.45 m, end > 0.70 m |

Calibration on motion capture (`t2m eval probes --cmu-clips data/cmu`, whole clips cut by the sentences'
timings; measured 2026-11-26): jump passes on 0.91 of the 70 clips whose sentences say jump or hop and on 0.17 of
the other 172 CMU clips (leaps, flips and dances do leave the floor); invert on 0.92 of the 26 cartwheel / handstand
/ flip clips and 0.01 of the others; get_up on 0.57 of the 14 "gets up / stands up" clips (the others start
standing: the sentence covers lying down first) and on none of the others. None of the three passes on any of
the Bandai-Namco walk, run, dash, bow, bye, raise, wave, punch or guide clips.

No dance probe: a dance has no single kinematic consequence these measures can hold to a threshold. The best
simple rule tried (limb speed over 0.8 m/s with under 1 m of travel) passed on 0.23 of the CMU dance clips and on
0.17-0.19 of Bandai-Namco's waving and raised-hands clips; dance is left to the evaluator's retrieval scores.
"""
from __future__ import annotations

import numpy as np

from t2m.model.evaluation.probes import HEAD, PELVIS, START_FRAMES, ProbeResult, ProbeSpec
from t2m.motion.features import validate_joints
from t2m.motion.skeleton import SMPL22

__all__ = ["ACTION_PROBES", "airborne_height", "feet_over_head", "pelvis_over_floor", "probe_get_up",
           "probe_invert", "probe_jump"]

JUMP_MIN_OFF_M = 0.10
JUMP_MIN_RISE_M = 0.12
INVERT_MIN_M = 0.10
GET_UP_START_MAX_M = 0.45
GET_UP_END_MIN_M = 0.70
FLOOR_PERCENTILE = 5.0

_J = {name: index for index, name in enumerate(SMPL22.joint_names)}
_FEET = ((_J["left_ankle"], _J["left_foot"]), (_J["right_ankle"], _J["right_foot"]))


def _lower_points(joints: np.ndarray) -> np.ndarray:
    """[T, 2]: each foot's lowest point (ankle or toe joint) per frame."""
    return np.stack([joints[:, list(foot), 1].min(axis=1) for foot in _FEET], axis=1)


def _floor(joints: np.ndarray) -> float:
    return float(np.percentile(_lower_points(joints).min(axis=1), FLOOR_PERCENTILE))


def airborne_height(joints: np.ndarray) -> float:
    """Metres both feet are above the floor at once, at the frame where the lower of them is highest."""
    array = validate_joints(joints, SMPL22, min_frames=1)
    return float(_lower_points(array).min(axis=1).max() - _floor(array))


def pelvis_over_floor(joints: np.ndarray) -> np.ndarray:
    """[T] the pelvis height above the motion's floor (m)."""
    array = validate_joints(joints, SMPL22, min_frames=1)
    return array[:, PELVIS, 1] - _floor(array)


def feet_over_head(joints: np.ndarray) -> float:
    """Metres the lower foot is above the head at the most inverted frame (negative: the head stays above)."""
    array = validate_joints(joints, SMPL22, min_frames=1)
    return float((_lower_points(array).min(axis=1) - array[:, HEAD, 1]).max())


def probe_jump(joints: np.ndarray) -> ProbeResult:
    """Both feet leave the floor (> 0.10 m) and the pelvis rises (> 0.12 m above its median height)."""
    off = airborne_height(joints)
    pelvis = pelvis_over_floor(joints)
    rise = float(pelvis.max() - np.median(pelvis))
    passed = off > JUMP_MIN_OFF_M and rise > JUMP_MIN_RISE_M
    return ProbeResult("jump", off, "m", f"feet off > {JUMP_MIN_OFF_M} m, pelvis rise > {JUMP_MIN_RISE_M} m", passed,
                       {"pelvis_rise_m": rise})


def probe_invert(joints: np.ndarray) -> ProbeResult:
    """The body turns upside down: a frame with both feet more than 0.10 m above the head."""
    value = feet_over_head(joints)
    return ProbeResult("invert", value, "m", f"> {INVERT_MIN_M} m", value > INVERT_MIN_M)


def probe_get_up(joints: np.ndarray) -> ProbeResult:
    """Starts on the floor (pelvis < 0.45 m over it) and ends standing (> 0.70 m; standing is ~0.8-0.95)."""
    pelvis = pelvis_over_floor(joints)
    start, end = float(pelvis[:START_FRAMES].mean()), float(pelvis[-START_FRAMES:].mean())
    passed = start < GET_UP_START_MAX_M and end > GET_UP_END_MIN_M
    return ProbeResult("get_up", end - start, "m", f"start < {GET_UP_START_MAX_M} m, end > {GET_UP_END_MIN_M} m",
                       passed, {"start_m": start, "end_m": end})


# Written 2026-11-26, before any model was trained on the CMU trials; none is a caption of the training data
# (tests/test_action_probes.py checks that against the CMU build when the shared data is there).
ACTION_PROBES: tuple[ProbeSpec, ...] = (
    ProbeSpec("jump", ("a person jumps up and down on the spot", "someone leaps straight up into the air",
                       "the man hops with both feet together", "a child bounces up in a big jump",
                       "the athlete springs off the ground with both legs", "someone does a vertical jump"),
              probe_jump),
    ProbeSpec("invert", ("someone does a cartwheel", "a gymnast turns a cartwheel to the side",
                         "the person kicks up into a handstand", "a woman flips upside down onto her hands",
                         "an acrobat does a handspring", "someone goes over into a handstand and back"),
              probe_invert),
    ProbeSpec("get_up", ("a person lying on the floor gets up", "someone stands up from the ground",
                         "the man rises from lying down to standing", "a woman pushes herself up off the floor",
                         "someone who has fallen climbs back onto their feet",
                         "a person on the ground gets back up"),
              probe_get_up),
)
