"""MDM's joins: the pelvis-velocity change at the joins of 3-sentence requests with and without the
in-between pass (t2m.families.diffusion.loop.join_windows), with t2m/quality/joins.py's measure.

    t2m eval diffusion-joins [--bundle DIR] [--seeds 20]

Without --bundle it builds the tiny random-weight MDM (t2m.families.diffusion.random_bundle) with the exporter's
default window (10 frames made anew a side after 10 known ones): random weights make no real motion, so the figures
say what the pass does to a discontinuity between independently made sentences, not how a trained MDM's joins look.
Each request is generated once per seed with the pass and once without it (the same draws for the sentences: the
join pass draws after them), so every pair differs only by the pass. Join change: |v(b) - v(b-1)| of the pelvis at
each join (join_smoothness.velocity_changes); inside: every other frame boundary at least 3 frames from a join.
"""
from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from t2m.quality.joins import velocity_changes
from t2m.runtime.engine import OnnxEngine
from t2m.runtime.types import GenerationRequest, SegmentRequest

REQUESTS = [
    [("a person walks forward", 3.1), ("a person waves with the right hand", 2.3), ("a person bows", 1.9)],
    [("a person runs forward", 2.7), ("a person kicks with the right leg", 1.3), ("a person walks backwards", 3.3)],
]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--bundle", type=Path, default=None)
    parser.add_argument("--seeds", type=int, default=20)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as scratch:
        bundle = args.bundle
        if bundle is None:
            from t2m.families.diffusion.random_bundle import build_random_diffusion_bundle

            bundle = Path(scratch) / "mdm"
            build_random_diffusion_bundle(bundle, arch="mdm", join_frames=10, join_context=10,
                                          max_frames=196)
        engine = OnnxEngine.load(bundle, intra_op_threads=1)
        codes: Any = engine.codes   # t2m.families.diffusion.served.DiffusionCodes
        joined = codes.settings
        figures: dict[str, tuple[list[float], list[float]]] = {"with the pass": ([], []), "without": ([], [])}
        for seed in range(args.seeds):
            for segments in REQUESTS:
                request = GenerationRequest([SegmentRequest(t, d) for t, d in segments], seed=seed,
                                            guidance=engine.limits.default_guidance)
                for label, settings in (("with the pass", joined),
                                        ("without", dataclasses.replace(joined, join_frames=0))):
                    codes.settings = settings
                    motion = engine.generate(request)
                    joins = [span.start_frame for span in motion.segments[1:]]
                    at, inside = velocity_changes(motion.joints, joins)
                    figures[label][0].extend(at)
                    figures[label][1].extend(inside)
        codes.settings = joined
    print(f"{engine.limits.name}: {args.seeds} seeds x {len(REQUESTS)} requests, join window "
          f"{joined.join_frames} + {joined.join_context} frames a side")
    print("| | joins: median pelvis-velocity change (mm/frame) | inside segments: median | joins / inside |")
    print("| --- | --- | --- | --- |")
    for label, (at, inside) in figures.items():
        print(f"| {label} | {1000 * np.median(at):.2f} | {1000 * np.median(inside):.2f} | "
              f"{np.median(at) / np.median(inside):.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
