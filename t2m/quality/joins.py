"""Joins before and after exact durations: the pelvis-velocity change at the joins of 3-sentence requests
whose durations are not whole code steps, on each embedded model, for the decoded frames (whole steps, rounded spans)
and for ways of fitting each segment to round(duration * fps) frames.

    t2m eval joins [--seeds 20] [--models default,gpt,masked]

Each request is generated once per seed with the engine's decoded frames (OnnxEngine(exact_durations=False)); the
fits are applied to those same frames, so every row sees the same codes:
- decoded: the frames as the decoder made them, each segment round(d * fps / f) * f frames (the answer before);
- served: engine/timeline.py's fit_frames, what the service answers: output frame j of a segment samples about
  j * n / F from its first decoded frame, the rate n / F changing smoothly across a join (a cubic Hermite time map
  per segment, its slope at a join the mean of the two segments' rates), the last segment ending on its last frame;
- segment ends: each segment alone between its first and last decoded frames, output frame j of a segment of n
  decoded and F target frames at decoded time j * (n - 1) / (F - 1) (the rate steps n / F -> 1 -> n' / F' at a join);
- one rate: output frame j samples j * n / F (the rate steps n / F -> n' / F' at a join; the last segment clamped at
  its last frame);
- cut: the first F decoded frames of each segment, the last one repeated when n < F.
Join change: |v(b) - v(b-1)| of the pelvis (joint 0), v(k) = p(k+1) - p(k) in metres per frame, the larger of the two
changes around each join's first frame b; inside: every other frame boundary at least 3 frames from a join; paired:
the median over joins of (the row's change - the decoded frames' change at the same join). Frame error: |frames of a
segment - round(d * fps)|, per segment; speed change: |n / F - 1| of the stretched segments.
"""
from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence

import numpy as np

from t2m.bundles import DEFAULT_BUNDLE
from t2m.runtime.engine import OnnxEngine
from t2m.runtime.timeline import fit_frames
from t2m.runtime.types import GenerationRequest, SegmentRequest, frames_for_duration

BUNDLES = DEFAULT_BUNDLE.parent
REQUESTS: list[list[tuple[str, float]]] = [
    [("a person walks forward", 3.1), ("a person waves with the right hand", 2.3), ("a person bows", 1.9)],
    [("a person runs forward", 2.7), ("a person kicks with the right leg", 1.3), ("a person walks backwards", 3.3)],
    [("a person raises the left hand", 2.1), ("a person walks forward", 3.5), ("a person bows", 2.9)],
]
MARGIN = 2   # boundaries this close to a join count for neither set

Fit = Callable[[np.ndarray, Sequence[int], Sequence[int]], np.ndarray]


def uniform(frames: np.ndarray, decoded: Sequence[int], targets: Sequence[int]) -> np.ndarray:
    """Output frame j of a segment samples decoded time j * n / F (the next segment's first frame at the join)."""
    times, start = [], 0
    for n, count in zip(decoded, targets):
        times.append(start + np.arange(count) * n / count)
        start += n
    time = np.minimum(np.concatenate(times), len(frames) - 1)
    before = np.floor(time).astype(int)
    after = np.minimum(before + 1, len(frames) - 1)
    weight = (time - before)[:, None, None]
    return (frames[before] * (1 - weight) + frames[after] * weight).astype(np.float32)


def segment_ends(frames: np.ndarray, decoded: Sequence[int], targets: Sequence[int]) -> np.ndarray:
    """Each segment alone between its first and last decoded frames: output j samples j * (n - 1) / (F - 1)."""
    pieces, start = [], 0
    for n, count in zip(decoded, targets):
        time = np.arange(count) * (n - 1) / max(count - 1, 1)
        before = np.floor(time).astype(int)
        after = np.minimum(before + 1, n - 1)
        weight = (time - before)[:, None, None]
        segment = frames[start:start + n]
        pieces.append(segment[before] * (1 - weight) + segment[after] * weight)
        start += n
    return np.concatenate(pieces).astype(np.float32)


def cut(frames: np.ndarray, decoded: Sequence[int], targets: Sequence[int]) -> np.ndarray:
    """The first F decoded frames of each segment (its last frame repeated when it has fewer)."""
    pieces, start = [], 0
    for n, count in zip(decoded, targets):
        segment = frames[start:start + n]
        pieces.append(segment[np.minimum(np.arange(count), n - 1)])
        start += n
    return np.concatenate(pieces)


FITS: dict[str, Fit | None] = {"decoded": None, "served": fit_frames, "segment ends": segment_ends,
                               "one rate": uniform, "cut": cut}


def velocity_changes(joints: np.ndarray, joins: Sequence[int]) -> tuple[list[float], list[float]]:
    """The pelvis-velocity changes (m/frame) at each join's first frame and at the boundaries inside segments."""
    velocity = np.diff(np.asarray(joints, np.float64)[:, 0], axis=0)
    change = np.linalg.norm(np.diff(velocity, axis=0), axis=1)   # change[k]: v(k) -> v(k + 1), around frame k + 1

    def at(boundary: int) -> float:
        return float(max(change[boundary - 2], change[boundary - 1]))

    boundaries = range(2, len(joints) - 1)
    near = {b for j in joins for b in range(j - MARGIN, j + MARGIN + 1)}
    return [at(j) for j in joins if j in boundaries], [at(b) for b in boundaries if b not in near]


def measure(engine: OnnxEngine, seeds: int) -> dict[str, dict[str, list[float]]]:
    figures: dict[str, dict[str, list[float]]] = {name: {"join": [], "inside": [], "error": [], "speed": []}
                                                   for name in FITS}
    for segments in REQUESTS:
        targets = [frames_for_duration(d, engine.limits.fps) for _, d in segments]
        for seed in range(seeds):
            request = GenerationRequest([SegmentRequest(text, d) for text, d in segments], seed=seed,
                                        guidance=engine.limits.guidance())
            motion = engine.generate(request)
            decoded = [span.end_frame - span.start_frame for span in motion.segments]
            for name, fit in FITS.items():
                counts = decoded if fit is None else targets
                joints = motion.joints if fit is None else fit(motion.joints, decoded, targets)
                assert len(joints) == sum(counts), name
                joins = list(np.cumsum(counts)[:-1])
                at_joins, inside = velocity_changes(joints, joins)
                figures[name]["join"] += at_joins
                figures[name]["inside"] += inside
                figures[name]["error"] += [abs(c - t) for c, t in zip(counts, targets)]
                stretched = name not in ("decoded", "cut")   # cut drops or holds frames, at the decoded speed
                figures[name]["speed"] += [abs(n / c - 1) if stretched else 0.0 for n, c in zip(decoded, counts)]
    return figures


def table(model: str, engine: OnnxEngine, figures: dict[str, dict[str, list[float]]], seeds: int) -> list[str]:
    limits = engine.limits
    lines = [f"{model}: {limits.name} {limits.version}, {limits.frames_per_token} frames per step, "
             f"{len(REQUESTS)} requests x {seeds} seeds, {len(figures['served']['join'])} joins; Δv in mm/frame",
             "| frames | join Δv median | p90 | paired vs decoded | inside median | join / inside "
             "| frame error mean / max | speed change mean |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    before = np.asarray(figures["decoded"]["join"])
    for name, f in figures.items():
        join, inside = np.median(f["join"]), np.median(f["inside"])
        paired = np.median(np.asarray(f["join"]) - before)
        lines.append(f"| {name} | {join * 1000:.2f} | {np.percentile(f['join'], 90) * 1000:.2f} "
                     f"| {paired * 1000:+.2f} | {inside * 1000:.2f} | {join / inside:.2f} "
                     f"| {np.mean(f['error']):.2f} / {max(f['error']):.0f} | {np.mean(f['speed']) * 100:.1f} % |")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--models", default="default,gpt,masked")
    args = parser.parse_args(argv)
    print("durations (s): " + "; ".join(" + ".join(f"{d:g}" for _, d in r) for r in REQUESTS))
    for model in args.models.split(","):
        engine = OnnxEngine.load(BUNDLES / model, intra_op_threads=1, exact_durations=False)
        print()
        print("\n".join(table(model, engine, measure(engine, args.seeds), args.seeds)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
