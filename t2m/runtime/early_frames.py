"""Frames sent while the lockstep families' codes are still being sampled (a request's `on_frames`).

The codes of a request grow one per step and per segment (T2M-HiFiGPT: one row of R codes per step); its motion is
the decode of its segments' codes put end to end, so the codes known for good are those of its finished segments
followed by the first unfinished one's so far.
Once codes up to t + reach.ahead are known, the frames of code t are final (engine/reach.py): a window of codes from
reach.behind before the first unsent code decodes them exactly as the whole decode would (up to onnxruntime's
rounding, which differs by ~1e-6 between lengths), and their joints follow from the frames before them alone
(motion.features.JointRecovery). The frames of the last `ahead` codes come with the whole decode at the end; the
service sends what is left of the Motion then. The joints go to `send` with the decoded frame counts of the segments
finished so far: the engine's sink (engine/timeline.py's FittedSink) fits them to the segments' exact frame counts.

When to decode: the first final code's frames at once (time to first frame), then whenever the newly final codes
are at least `every` and at least as many as were sent before. Chunks doubling in size cost about log2(N) decodes
for N codes instead of N / every, and once they are larger than `every`, a player is never left waiting while
sampling is at least twice as fast as real time (a chunk arrives before the frames sent before it have been played).
Only right after the first chunk (one code, 0.2 s of motion) may a player wait, for a model that takes longer than
0.2 s to sample `every` codes; the default model samples hundreds of times faster than real time.
"""
from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from t2m.motion.features import JointRecovery
from t2m.motion.skeleton import Skeleton
from t2m.runtime.reach import DecoderReach

__all__ = ["DecodedSink", "FrameStreamer"]

DecodedSink = Callable[[np.ndarray, Sequence[int]], None]
"""Receives decoded joints (float32 [n, J, 3]) in order, with the decoded frame counts of the segments finished so
far (in order)."""

log = logging.getLogger(__name__)


class FrameStreamer:
    """One request's early frames: decode a window when enough codes' frames are newly final (see the module's
    docstring) and hand the joints of those frames to `send`, in order."""

    def __init__(self, decode: Callable[[np.ndarray], np.ndarray], skeleton: Skeleton, reach: DecoderReach,
                 frames_per_token: int, every: int, send: DecodedSink) -> None:
        self.decode, self.reach, self.frames_per_token = decode, reach, frames_per_token
        self.every, self.send = max(1, every), send
        self.recovery = JointRecovery(skeleton)
        self.sent_codes = 0          # the codes whose frames have been sent
        self.failed = False

    def codes_arrived(self, segments: Sequence[Sequence[Any]], done: Sequence[bool]) -> None:
        """After a sampling step: each segment's codes so far and whether it is finished. Never raises: a failure
        stops the early frames (the rest still comes with the whole motion) rather than the batch."""
        if self.failed:
            return
        try:
            self._send_final(segments, done)
        except Exception:
            log.exception("early frames failed; the rest of the motion comes whole")
            self.failed = True

    def _send_final(self, segments: Sequence[Sequence[Any]], done: Sequence[bool]) -> None:
        unfinished = next((index for index, finished in enumerate(done) if not finished), None)
        if unfinished is None:
            return   # every segment is finished: the whole decode follows
        known = segments[:unfinished + 1]   # the codes known for good: finished segments, then the growing one
        final = sum(len(tokens) for tokens in known) - self.reach.ahead
        if final <= self.sent_codes or (self.sent_codes and final - self.sent_codes < max(self.every,
                                                                                           self.sent_codes)):
            return
        start = max(0, self.sent_codes - self.reach.behind)
        # (a code map's rows for T2M-HiFiGPT, normalised frames for the diffusion family: the decoder casts to its
        # input's type; a segment with no codes yet has no shape to join)
        codes = np.concatenate([np.asarray(tokens) for tokens in known if len(tokens)])[start:]
        per = self.frames_per_token
        rows = self.decode(codes)[(self.sent_codes - start) * per:(final - start) * per]
        self.sent_codes = final
        self.send(self.recovery.push(rows).astype(np.float32), [len(tokens) * per for tokens in known[:-1]])
