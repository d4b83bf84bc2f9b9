"""Each segment's decoded frames fitted to its exact frame count, round(duration * fps), whatever frames_per_token is.

A model makes frames_per_token (f) frames per code step, so a segment of d seconds decodes to n = round(d * fps / f)
* f frames (3 s at f = 8: 64, not 60). The codes stay what the model samples and are decoded once as before (its
token choices and the decoder's smooth joins unchanged); then the decoded joints are resampled in time, joint
positions linearly interpolated, along a monotone time map that gives segment k exactly F_k output frames:

- output frame j of a segment samples decoded time j * n / F from the segment's first decoded frame, so its first
  frame is its first decoded frame and the next segment starts where its decoded frames start; the last segment
  spans its first to its last decoded frame (j * (n - 1) / (F - 1)), so the motion ends on its last decoded frame;
- the rate n / F changes smoothly across a join instead of jumping: each segment's map is a cubic Hermite whose slope
  at a join is the mean of the two segments' rates (at most three times either, which keeps it monotone); the
  motion's first and last ends keep the segment's own rate. t2m/quality/joins.py measured this against
  resampling each segment alone between its first and last decoded frames (docs/measurements/): the pelvis-velocity
  change at the joins stays that of the decoded frames (paired median -0.04 to +0.01 mm/frame on the three embedded
  models) where the per-segment fit added 0.13 to 0.46 mm/frame (the rate stepping n / F -> 1 -> n' / F' at a join);
- a segment the model ended itself (duration null) keeps its decoded frames, rate 1, and so do the joins next to
  it; where every count already matches, the map is the identity, bit for bit.

One object, `Timeline`, fits the frames for the whole answer and for a stream alike: it takes decoded frames in
order, in any chunks, and returns the fitted frames that the frames received so far determine (an output frame needs
the decoded frames on both sides of its time, possibly the next segment's first). `fit_frames` runs it once over a
whole motion; `FittedSink` sits between the engine's FrameStreamer and a request's `on_frames`, so streamed frames go
out as soon as the decoded frames they interpolate are final and, put together, equal the whole answer's (the same
arithmetic on the same frames, up to onnxruntime's ~1e-6 between a window's decode and the whole one's).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from t2m.runtime.types import FrameSink

__all__ = ["FittedSink", "SegmentMap", "Timeline", "fit_frames", "segment_maps"]

MAX_SLOPE_RATIO = 3.0   # a Hermite segment is monotone when its end slopes are at most 3x its secant (Fritsch-Carlson)


@dataclass(frozen=True)
class SegmentMap:
    """Where a fitted segment's `target` output frames sample its `decoded` frames: a cubic Hermite time map from its
    first decoded frame to the next segment's (`last`: to its own last frame), with these slopes at its two ends
    (decoded frames per output frame)."""

    decoded: int
    target: int
    slope_in: float
    slope_out: float
    last: bool

    @property
    def span(self) -> tuple[int, int]:
        """(output frames, decoded frames) the map's secant covers."""
        return (self.target - 1, self.decoded - 1) if self.last else (self.target, self.decoded)

    @property
    def rate(self) -> float:
        """Decoded frames per output frame along the secant."""
        outputs, decoded = self.span
        return decoded / outputs if outputs > 0 else 1.0

    def times(self) -> tuple[np.ndarray, np.ndarray]:
        """Per output frame: the decoded frame at or before its time (int64, from the segment's first) and the
        weight of the next one (float64, 0 on a frame). The secant part is integer arithmetic, so the identity (rate
        and slopes 1) and the ends are exact."""
        outputs, decoded = self.span
        if outputs <= 0:
            return np.zeros(self.target, np.int64), np.zeros(self.target, np.float64)
        j = np.arange(self.target, dtype=np.int64)
        before, remainder = np.divmod(j * decoded, outputs)
        time = remainder / outputs
        rate = decoded / outputs
        if self.slope_in != rate or self.slope_out != rate:
            u = j / outputs   # the Hermite bases of the end slopes, less the secant's (the line above holds it)
            start, end = u * (1 - u) ** 2, u * u * (u - 1)
            time = time + outputs * (start * (self.slope_in - rate) + end * (self.slope_out - rate))
        whole = np.floor(time).astype(np.int64)
        return before + whole, time - whole


def segment_maps(targets: Sequence[int | None], decoded: Sequence[int | None]) -> list[SegmentMap | None]:
    """The map of every segment with a target (None for the others: they keep their decoded frames, rate 1), from
    the segments' decoded counts (None only where the target is None: the model ends that segment)."""
    count = len(targets)
    maps: list[SegmentMap | None] = []
    for k, (target, frames) in enumerate(zip(targets, decoded)):
        if target is None:
            maps.append(None)
            continue
        if frames is None:
            raise ValueError(f"segments.{k}: a segment with a target needs its decoded frame count")
        maps.append(SegmentMap(int(frames), int(target), 0.0, 0.0, last=k == count - 1))
    secants = [None if m is None else m.rate for m in maps]
    fitted: list[SegmentMap | None] = []
    for k, segment in enumerate(maps):
        if segment is None:
            fitted.append(None)
            continue
        slope_in = _join_slope(secants[k], secants[k - 1], maps[k - 1] is None) if k > 0 else segment.rate
        slope_out = _join_slope(secants[k], secants[k + 1], maps[k + 1] is None) if k < count - 1 else segment.rate
        fitted.append(SegmentMap(segment.decoded, segment.target, slope_in, slope_out, segment.last))
    return fitted


def _join_slope(own: float | None, other: float | None, other_kept: bool) -> float:
    """The rate at a join: 1 next to a kept segment, else the mean of the two rates, at most 3x either."""
    if other_kept or own is None or other is None:
        return 1.0 if own is None else min(1.0, MAX_SLOPE_RATIO * own)
    return min((own + other) / 2, MAX_SLOPE_RATIO * min(own, other))


class Timeline:
    """One request's segments: `targets[k]` output frames for segment k (None: keep its decoded frames), from
    `decoded[k]` decoded frames (None: not known before the model ends the segment; only where the target is None).
    Feed it the decoded frames in order with `push`; it returns the fitted frames that became final."""

    def __init__(self, targets: Sequence[int | None], decoded: Sequence[int | None]) -> None:
        if len(targets) != len(decoded):
            raise ValueError(f"{len(targets)} segment targets for {len(decoded)} decoded lengths")
        self.targets = list(targets)
        self.decoded = list(decoded)
        self.maps = segment_maps(self.targets, self.decoded)
        self.times: tuple[np.ndarray, np.ndarray] | None = None   # the current segment's, once computed
        self.segment = 0            # the segment whose output frames come next
        self.segment_start = 0      # its first decoded frame (over the whole motion)
        self.emitted = 0            # its output frames returned so far
        self.received = 0           # decoded frames pushed so far
        self.buffer: np.ndarray | None = None   # decoded frames from segment_start on

    def push(self, frames: np.ndarray, finished: Sequence[int]) -> np.ndarray:
        """The next decoded frames (in order) and the decoded frame counts of the segments finished so far (in
        order); returns the output frames they complete (possibly none), in order."""
        self._learn(finished)
        frames = np.asarray(frames)
        self.buffer = frames if self.buffer is None else np.concatenate([self.buffer, frames])
        self.received += len(frames)
        out: list[np.ndarray] = []
        while self.segment < len(self.targets):
            decoded = self.decoded[self.segment]
            available = self.received - self.segment_start
            if decoded is None:   # a growing segment the model ends: its frames as they come
                out.append(self.buffer[self.emitted:available])
                self.emitted = available
                break
            out.append(self._fit(available))
            if self.emitted < self._target(self.segment):
                break
            self.buffer = self.buffer[decoded:]
            self.segment_start += decoded
            self.segment, self.emitted, self.times = self.segment + 1, 0, None
        out = [chunk for chunk in out if len(chunk)]
        if not out:
            return frames[:0]
        return out[0] if len(out) == 1 else np.concatenate(out)

    def _learn(self, finished: Sequence[int]) -> None:
        """The lengths of segments the model ended, once they have; a planned length must be the decoded one."""
        for index, length in enumerate(finished[:len(self.decoded)]):
            planned = self.decoded[index]
            if planned is None:
                self.decoded[index] = int(length)
            elif planned != length:
                raise ValueError(f"segments.{index}: decoded {length} frames, {planned} were planned")

    def _target(self, segment: int) -> int:
        target, decoded = self.targets[segment], self.decoded[segment]
        return int(target if target is not None else decoded or 0)

    def _total(self) -> int | None:
        """All decoded frames of the motion, once every segment's count is known."""
        return None if any(frames is None for frames in self.decoded) else sum(self.decoded)  # type: ignore[arg-type]

    def _fit(self, available: int) -> np.ndarray:
        """The current segment's output frames whose decoded frames are among the `available` from its start."""
        assert self.buffer is not None
        segment_map = self.maps[self.segment]
        if segment_map is None:   # kept: the frames themselves
            chunk = self.buffer[self.emitted:min(available, self._target(self.segment))]
            self.emitted += len(chunk)
            return chunk
        if self.times is None:
            before, weight = segment_map.times()
            total = self._total()
            if total is not None:   # the motion's last frame bounds every time (a trailing segment of no frames)
                end = total - 1 - self.segment_start
                weight = np.where(before >= end, 0.0, weight)
                before = np.minimum(before, end)
            self.times = before, weight
        before, weight = self.times
        needed = before + (weight > 0)
        ready = int(np.searchsorted(needed, available, side="left"))   # needed rises: the first not yet here
        before, weight = before[self.emitted:ready], weight[self.emitted:ready]
        self.emitted = max(self.emitted, ready)
        if not len(before):
            return self.buffer[:0]
        after = before + (weight > 0)   # a time on a frame reads that frame alone
        shape = (-1,) + (1,) * (self.buffer.ndim - 1)
        mixed = self.buffer[before] * (1.0 - weight).reshape(shape) + self.buffer[after] * weight.reshape(shape)
        return mixed.astype(self.buffer.dtype)


def fit_frames(frames: np.ndarray, decoded: Sequence[int], targets: Sequence[int | None]) -> np.ndarray:
    """A whole motion's decoded frames (its segments' `decoded` counts end to end) fitted to `targets` (None:
    kept): the same Timeline a stream runs, fed everything at once."""
    if sum(decoded) != len(frames):
        raise ValueError(f"{len(frames)} decoded frames for segments of {list(decoded)} frames")
    fitted = Timeline(targets, list(decoded)).push(frames, decoded)
    expected = sum(t if t is not None else d for t, d in zip(targets, decoded))
    if len(fitted) != expected:
        raise RuntimeError(f"the timeline made {len(fitted)} frames, {expected} expected")
    return fitted


class FittedSink:
    """Between the engine's FrameStreamer (decoded joints, and the finished segments' decoded counts) and a
    request's `on_frames`: sends the fitted frames as soon as the decoded ones they need have arrived."""

    def __init__(self, timeline: Timeline, send: FrameSink) -> None:
        self.timeline, self.send = timeline, send

    def __call__(self, frames: np.ndarray, finished: Sequence[int]) -> None:
        fitted = self.timeline.push(frames, finished)
        if len(fitted):
            self.send(fitted)
