"""Each segment's decoded frames fitted to its exact frame count, round(duration * fps), whatever frames_per_token is.

A model makes frames_per_token (f) frames per code step, so a segment of d seconds decodes to round(d * fps / f) * f
frames (3 s at f = 8: 64, not 60). The codes stay what the model samples and are decoded once as before (its token
choices and the decoder's smooth joins unchanged); then each segment's decoded joints are resampled in time to its
frame count by a monotone warp that keeps its first and last decoded frames: output frame j of a segment of n
decoded frames and F target frames is the decoded motion at time j * (n - 1) / (F - 1) within the segment, joint
positions linearly interpolated. A join (the last frame of one segment, then the first of the next) stays the two
neighbouring decoded frames. A segment the model ended itself (duration null) keeps its decoded frames; so does one
whose count already matches (the warp is the identity, bit for bit).

One object, `Timeline`, fits the frames for the whole answer and for a stream alike: it takes decoded frames in
order, in any chunks, and returns the fitted frames that the frames received so far determine (an output frame needs
the decoded frames on both sides of its time). `fit_frames` runs it once over a whole motion; `FittedSink` sits
between the engine's FrameStreamer and a request's `on_frames`, so streamed frames go out as soon as the decoded
frames they interpolate are final and, put together, equal the whole answer's (the same arithmetic on the same
frames, up to onnxruntime's ~1e-6 between a window's decode and the whole one's).
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from t2m.service.engine.types import FrameSink

__all__ = ["FittedSink", "Timeline", "fit_frames", "source_times"]


def source_times(decoded: int, target: int) -> tuple[np.ndarray, np.ndarray]:
    """Where each of `target` output frames samples a segment of `decoded` frames: the decoded frame at or before
    its time (int64) and the weight of the next one (float64, 0 when the time falls on a frame). Integer arithmetic,
    so the identity (decoded == target) and both endpoints are exact."""
    if target <= 0 or decoded <= 0:
        return np.zeros(0, np.int64), np.zeros(0, np.float64)
    if target == 1:
        return np.zeros(1, np.int64), np.zeros(1, np.float64)
    numerator = np.arange(target, dtype=np.int64) * (decoded - 1)
    before, remainder = np.divmod(numerator, target - 1)
    return before, remainder / (target - 1)


class Timeline:
    """One request's segments: `targets[k]` output frames for segment k (None: keep its decoded frames), from
    `decoded[k]` decoded frames (None: not known before the model ends the segment). Feed it the decoded frames in
    order with `push`; it returns the fitted frames that became final."""

    def __init__(self, targets: Sequence[int | None], decoded: Sequence[int | None]) -> None:
        if len(targets) != len(decoded):
            raise ValueError(f"{len(targets)} segment targets for {len(decoded)} decoded lengths")
        self.targets = list(targets)
        self.decoded = list(decoded)
        self.segment = 0            # the segment whose output frames come next
        self.segment_start = 0      # its first decoded frame (over the whole motion)
        self.emitted = 0            # its output frames returned so far
        self.received = 0           # decoded frames pushed so far
        self.buffer = np.zeros(0, np.float32)   # decoded frames from segment_start on

    def push(self, frames: np.ndarray, finished: Sequence[int]) -> np.ndarray:
        """The next decoded frames (in order) and the decoded frame counts of the segments finished so far (in
        order); returns the output frames they complete (possibly none), in order."""
        self._learn(finished)
        frames = np.asarray(frames)
        self.buffer = frames if not len(self.buffer) else np.concatenate([self.buffer, frames])
        self.received += len(frames)
        out: list[np.ndarray] = []
        while self.segment < len(self.targets):
            decoded = self.decoded[self.segment]
            available = self.received - self.segment_start
            if decoded is None:   # a growing segment the model ends: its frames as they come
                out.append(self.buffer[self.emitted:available])
                self.emitted = available
                break
            out.append(self._fit(decoded, min(available, decoded)))
            if self.emitted < self._target(self.segment):
                break
            self.buffer = self.buffer[decoded:]
            self.segment_start += decoded
            self.segment, self.emitted = self.segment + 1, 0
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

    def _fit(self, decoded: int, available: int) -> np.ndarray:
        """The current segment's output frames whose decoded frames are among the first `available`."""
        target = self._target(self.segment)
        frames = self.buffer[:decoded]
        if target == decoded:   # nothing to fit: the frames themselves
            chunk = frames[self.emitted:available]
            self.emitted += len(chunk)
            return chunk
        before, weight = source_times(decoded, target)
        needed = before + (weight > 0)
        ready = int(np.searchsorted(needed, available, side="left"))   # needed is sorted: the first not yet here
        before, weight = before[self.emitted:ready], weight[self.emitted:ready]
        self.emitted = max(self.emitted, ready)
        if not len(before):
            return frames[:0]
        after = before + (weight > 0)   # a time on a frame reads that frame alone
        shape = (-1,) + (1,) * (frames.ndim - 1)
        mixed = frames[before] * (1.0 - weight).reshape(shape) + frames[after] * weight.reshape(shape)
        return mixed.astype(frames.dtype)


def fit_frames(frames: np.ndarray, decoded: Sequence[int], targets: Sequence[int | None]) -> np.ndarray:
    """A whole motion's decoded frames (its segments' `decoded` counts end to end) fitted to `targets` (None:
    kept): the same Timeline a stream runs, fed everything at once."""
    if sum(decoded) != len(frames):
        raise ValueError(f"{len(frames)} decoded frames for segments of {list(decoded)} frames")
    timeline = Timeline(targets, list(decoded))
    fitted = timeline.push(frames, decoded)
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
