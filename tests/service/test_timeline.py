"""engine/timeline.py: each segment's decoded frames fitted to its exact frame count: the identity where the counts
already match, each segment starting on its first decoded frame and the motion ending on its last, a rate that
changes smoothly across joins, monotone in time whatever the rates, exact counts, and the same frames streamed in any
chunks as fitted whole (each output frame as soon as the decoded frames it needs have arrived)."""
from __future__ import annotations

import numpy as np
import pytest

from t2m.runtime.timeline import FittedSink, Timeline, fit_frames
from t2m.runtime.types import frames_for_duration


def _ramp(length: int) -> np.ndarray:
    """Frames [length, 2, 3] whose value is their own time: a fitted frame's value is the time it samples."""
    return np.broadcast_to(np.arange(length, dtype=np.float32)[:, None, None], (length, 2, 3)).copy()


def _random(length: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(length, 22, 3)).astype(np.float32)


@pytest.mark.parametrize("duration, frames", [(3.0, 60), (2.0, 40), (3.1, 62), (2.3, 46), (1.9, 38), (0.5, 10),
                                              (0.525, 10), (0.01, 1), (10.0, 200)])
def test_a_duration_gets_round_duration_times_fps_frames(duration, frames):
    assert frames_for_duration(duration, 20) == frames


def test_matching_counts_and_null_durations_are_the_identity_bit_for_bit():
    frames = _random(40 + 24 + 16)
    np.testing.assert_array_equal(fit_frames(frames, [40, 24, 16], [40, None, 16]), frames)


def _times(fitted: np.ndarray) -> np.ndarray:
    """The decoded time each fitted frame of a _ramp samples."""
    return fitted[:, 0, 0].astype(np.float64)


@pytest.mark.parametrize("decoded, target", [(64, 60), (40, 40), (56, 60), (8, 10), (200, 198), (16, 14), (5, 1),
                                             (1, 4)])
def test_one_segment_keeps_its_ends_and_samples_j_n_minus_1_over_f_minus_1(decoded, target):
    fitted = _times(fit_frames(_ramp(decoded), [decoded], [target]))
    assert len(fitted) == target
    assert fitted[0] == 0 and (target == 1 or fitted[-1] == decoded - 1)
    if target > 1:
        np.testing.assert_allclose(fitted, np.arange(target) * (decoded - 1) / (target - 1), atol=1e-4)


def test_segments_start_on_their_first_decoded_frame_and_the_motion_ends_on_its_last():
    """3.1 + 2.3 + 1.9 s at 8 frames a step: 64, 48, 40 decoded frames fitted to 62, 46, 38."""
    fitted = _times(fit_frames(_ramp(152), [64, 48, 40], [62, 46, 38]))
    assert len(fitted) == 146 and fitted[0] == 0 and fitted[62] == 64 and fitted[108] == 112 and fitted[-1] == 151
    assert np.all(np.diff(fitted) > 0)


def test_the_rate_changes_smoothly_across_a_join():
    """Rates 64 / 62 and 48 / 46 differ by 0.011 decoded frames per frame; the time step changes by at most a
    twentieth of that from one frame to the next (a rate stepping at the join would change it by all of it, and
    segments fitted between their own first and last frames by 0.03 and 0.04)."""
    steps = np.diff(_times(fit_frames(_ramp(152), [64, 48, 40], [62, 46, 38])))
    assert np.abs(np.diff(steps)).max() < (48 / 46 - 64 / 62) / 20


def test_a_kept_segment_stays_the_identity_and_its_neighbours_meet_it_at_rate_1():
    fitted = _times(fit_frames(_ramp(64 + 24 + 40), [64, 24, 40], [60, None, 42]))
    np.testing.assert_array_equal(fitted[60:84], np.arange(64, 88))
    steps = np.diff(fitted)
    assert abs(steps[59] - 1) < 0.01 and abs(steps[84] - 1) < 0.01


@pytest.mark.parametrize("seed", range(20))
def test_the_map_is_monotone_and_exact_whatever_the_rates(seed):
    """Extreme rates too: one frame for a step of 8 (an engine-level request of 0.01 s) beside rate-1 segments."""
    rng = np.random.default_rng(seed)
    decoded = [int(rng.integers(1, 26)) * 8 for _ in range(int(rng.integers(1, 6)))]
    targets: list[int | None] = [None if rng.random() < 0.2 else max(1, int(rng.choice(
        [1, 2, 3, d // 2, d - 3, d, d + 5, 2 * d]))) for d in decoded]
    fitted = _times(fit_frames(_ramp(sum(decoded)), decoded, targets))
    assert len(fitted) == sum(t if t is not None else d for t, d in zip(targets, decoded))
    assert np.all(np.diff(fitted) >= -1e-4) and fitted[0] == 0 and fitted[-1] <= sum(decoded) - 1


def _stream(frames: np.ndarray, decoded: list[int], targets: list[int | None], planned: list[int | None],
            rng: np.random.Generator) -> tuple[list[np.ndarray], list[int]]:
    """Push `frames` in random chunks as the FrameStreamer does: with each chunk, the decoded counts of a prefix of
    segments that holds every segment whose frames end before the chunk's end (a segment the model ends is only
    known once finished). Returns the fitted chunks and, per push, the decoded frames pushed so far."""
    ends = np.cumsum(decoded)
    timeline, sent, chunks, pushed = Timeline(targets, planned), 0, [], []
    finished = 0
    while sent < len(frames):
        size = int(rng.integers(1, 30))
        chunk = frames[sent:sent + size]
        sent += len(chunk)
        finished = max(finished, int(np.searchsorted(ends, sent, side="left")))   # those ending before `sent`
        finished = int(rng.integers(finished, len(decoded) + 1)) if rng.random() < 0.3 else finished
        sink = FittedSink(timeline, chunks.append)
        sink(chunk, decoded[:finished])
        pushed.append(sent)
    return chunks, pushed


@pytest.mark.parametrize("seed", range(12))
def test_streamed_in_random_chunks_equals_the_whole_fit(seed):
    rng = np.random.default_rng(seed)
    count = int(rng.integers(1, 5))
    decoded = [int(rng.integers(1, 26)) * 8 for _ in range(count)]
    targets = [None if rng.random() < 0.3 else int(rng.integers(max(1, d - 12), d + 12)) for d in decoded]
    planned: list[int | None] = [None if t is None else d for t, d in zip(targets, decoded)]
    frames = _random(sum(decoded), seed)
    whole = fit_frames(frames, decoded, targets)
    chunks, _ = _stream(frames, decoded, targets, planned, rng)
    streamed = np.concatenate(chunks) if chunks else whole[:0]
    np.testing.assert_array_equal(streamed, whole)   # every frame streamed, equal to the whole fit
    assert len(whole) == sum(t if t is not None else d for t, d in zip(targets, decoded))


def test_each_fitted_frame_goes_out_as_soon_as_its_decoded_frames_are_there():
    """64 decoded frames fitted to 60, pushed one by one: output j (time j * 63 / 59) goes with the push that
    brings decoded frame ceil(j * 63 / 59)."""
    timeline = Timeline([60], [64])
    frames = _ramp(64)
    arrivals = [len(timeline.push(frames[i:i + 1], [])) for i in range(64)]
    expected = np.bincount(np.ceil(np.arange(60) * 63 / 59 - 1e-9).astype(int), minlength=64)
    assert arrivals == expected.tolist() and sum(arrivals) == 60


def test_a_segment_s_last_frames_wait_for_the_next_segment_s_first():
    """Segment 0 (40 decoded frames slowed to 42) ends sampling between its last decoded frame and the next segment's
    first: its last output frame waits for decoded frame 40."""
    timeline = Timeline([42, 40], [40, 40])
    frames = _ramp(80)
    assert len(timeline.push(frames[:40], [40])) == 41
    assert 39 < _times(timeline.push(frames[40:41], [40]))[0] < 40


def test_a_decoded_length_other_than_the_planned_one_is_refused():
    timeline = Timeline([60, 40], [64, 40])
    with pytest.raises(ValueError, match=r"segments\.0: decoded 56 frames, 64 were planned"):
        timeline.push(_random(8), [56])
