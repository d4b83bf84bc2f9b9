"""Does an edited span follow its new text, and are the edit's borders as smooth as a generated stream's joins?
("Measured"). Engine level, the path POST /edit takes (t2m.runtime.edit_runner.edit_with_engine).

Per model and seed: "walk 3 s, wave 2 s, bow 3 s" is generated; its wave is edited into "a person raises the left
hand"; as the reference, "walk 3 s, raise the left hand 2 s, bow 3 s" is generated whole with the same seed. Printed:
- the raise-left probe (t2m.model.evaluation.probes) on segment 2 of the original (a control: a right-hand wave
  should fail it), of the edit and of the generated reference: pass rates over the seeds;
- the pelvis-velocity change at segment 2's two borders (t2m.model.evaluation.probes.join_smoothness, m/s per frame)
  in the edit and in the reference, and each one's ratio to its motion's median change inside segments;
- frames bit-identical to the original before the edit (the rest is outside the decoder's reach).
For models whose family declares in_between: "walk 3 s, bow 3 s" gets "a person raises both hands" for 2 s put
between its two segments (the in-between, filled with both sides known), against "walk, raise both hands, bow"
generated whole with the same seed: the raise-both probe on the new segment, the pelvis-velocity change at its two
borders, and foot skating over it (t2m.model.evaluation.foot_skating: planted toes' speed, sliding share).
Nothing is asserted: figures to read side by side.

    t2m eval edits [--model t2m/bundles/default] [--model t2m/bundles/gpt] [--seeds 10]
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from t2m.api import InBetweenEdit, RegenerateEdit
from t2m.bundles import EMBEDDED_BUNDLES
from t2m.model.evaluation.foot_skating import foot_skating
from t2m.model.evaluation.probes import join_smoothness, probe_by_name
from t2m.runtime.edit_runner import edit_with_engine
from t2m.runtime.engine import OnnxEngine
from t2m.runtime.handles import make_handle
from t2m.runtime.types import GenerationRequest, Motion, SegmentRequest

BEFORE, AFTER = ("a person walks forward", 3.0), ("a person bows", 3.0)
ORIGINAL = ("a person waves with the right hand", 2.0)
NEW_TEXT = "a person raises the left hand"
EDITED = 1


GAP = ("a person raises both hands", 2.0)


@dataclass
class Tally:
    """Per-seed figures of one kind of motion (original, edit, reference)."""

    passes: list[bool] = field(default_factory=list)
    border_changes: list[float] = field(default_factory=list)
    border_ratios: list[float] = field(default_factory=list)

    skating: list[float] = field(default_factory=list)
    probe: str = "raise_left"

    def add(self, motion: Motion) -> None:
        span = motion.segments[EDITED]
        frames = motion.joints[span.start_frame:span.end_frame]
        self.passes.append(probe_by_name(self.probe).check(frames).passed)
        smooth = join_smoothness(motion.joints, [s.start_frame for s in motion.segments[1:]], fps=motion.fps)
        self.border_changes += smooth.join_changes
        self.border_ratios += smooth.ratios
        self.skating.append(foot_skating(frames, fps=motion.fps).sliding_fraction)

    def line(self, name: str) -> str:
        return (f"  {name:34s} {self.probe} pass {sum(self.passes):2d}/{len(self.passes):<2d}  border change median "
                f"{np.median(self.border_changes):5.2f} p90 {np.percentile(self.border_changes, 90):5.2f}  ratio "
                f"median {np.median(self.border_ratios):5.1f} p90 {np.percentile(self.border_ratios, 90):5.1f}  "
                f"sliding {np.mean(self.skating):.2f}")


def measure(model: Path, seeds: int, threads: int) -> None:
    engine = OnnxEngine.load(model, intra_op_threads=threads)
    limits = engine.limits
    if "regenerate" not in limits.edits:
        print(f"{limits.name}: its family declares no regenerate edit; skipped")
        return
    guidance = limits.guidance()
    original, edited, reference = Tally(), Tally(), Tally()
    kept: list[int] = []
    for seed in range(seeds):
        texts = [BEFORE, ORIGINAL, AFTER]
        request = GenerationRequest([SegmentRequest(t, d) for t, d in texts], seed=seed, guidance=guidance)
        motion = engine.generate(request)
        handle = make_handle(limits, request, motion.codes)
        assert handle is not None, f"{model}: no handle"
        edit = edit_with_engine(engine, handle, [RegenerateEdit(segment=EDITED, text=NEW_TEXT)]).motion
        whole = engine.generate(GenerationRequest(
            [SegmentRequest(t, d) for t, d in (BEFORE, (NEW_TEXT, ORIGINAL[1]), AFTER)], seed=seed,
            guidance=guidance))
        original.add(motion)
        edited.add(edit)
        reference.add(whole)
        same = np.all(edit.joints == motion.joints, axis=(1, 2))
        kept.append(int(np.argmin(same)) if not same.all() else len(same))
    start = motion.segments[EDITED].start_frame
    print(f"{limits.name} {limits.version}: {seeds} seeds, guidance {guidance:g}; edit starts at frame {start}, "
          f"frames kept bit-identical before it: min {min(kept)}, median {int(np.median(kept))}")
    print(original.line('original (wave, right hand)'))
    print(edited.line('edit (wave -> raise left)'))
    print(reference.line('generated whole (raise left)'))
    if "in_between" in limits.edits:
        in_between(engine, seeds, guidance)


def in_between(engine: OnnxEngine, seeds: int, guidance: float) -> None:
    """The new segment between "walk" and "bow" against the same three sentences generated whole."""
    limits = engine.limits
    filled, whole = Tally(probe="raise_both"), Tally(probe="raise_both")
    for seed in range(seeds):
        request = GenerationRequest([SegmentRequest(t, d) for t, d in (BEFORE, AFTER)], seed=seed, guidance=guidance)
        motion = engine.generate(request)
        handle = make_handle(limits, request, motion.codes)
        assert handle is not None
        edit = InBetweenEdit(op="in_between", after=0, text=GAP[0], duration=GAP[1])
        filled.add(edit_with_engine(engine, handle, [edit]).motion)
        whole.add(engine.generate(GenerationRequest([SegmentRequest(t, d) for t, d in (BEFORE, GAP, AFTER)],
                                                    seed=seed, guidance=guidance)))
    print(filled.line('in-between (walk | raise both | bow)'))
    print(whole.line('generated whole (same 3 sentences)'))


def real_skating(data: Path) -> None:
    """Foot skating of real motion: every test clip of a built dataset, as the service would draw it."""
    from t2m.model.data.motion_data import MotionDirectory
    from t2m.motion.features import features_to_joints

    reader = MotionDirectory(data, "test")
    sliding = [foot_skating(features_to_joints(reader.features(item))).sliding_fraction for item in reader.ids]
    print(f"real test clips of {data} ({len(sliding)}): sliding {np.mean(sliding):.2f} (mean of per-clip shares)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", type=Path, action="append", default=None,
                        help="bundle directory (repeatable; default: the three embedded models)")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--data", type=Path, default=None, metavar="DIR",
                        help="a built dataset: print its test clips' foot skating as the scale to read it against")
    args = parser.parse_args(argv)
    if args.data is not None:
        real_skating(args.data)
    for model in args.model or [EMBEDDED_BUNDLES[name] for name in ("default", "gpt", "masked")]:
        measure(model, args.seeds, args.threads)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
