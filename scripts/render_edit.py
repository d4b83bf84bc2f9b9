"""The README's picture of an edit: a motion and the same motion with one segment regenerated.

"walk 3 s, wave 2 s, bow 3 s" is generated once; POST /edit's path (t2m.runtime.edit_runner.edit_with_engine)
replaces the wave by "a person raises the left hand" and keeps the rest. docs/images/edit.png draws both as rows of
the contact sheet (scripts/render_motions.py), each titled with what the raise-left probe measures on its middle
segment, and the edited row with how many frames stayed bit-identical.

    python scripts/render_edit.py                          # t2m/bundles/default, seed 7
    python scripts/render_edit.py --bundle DIR --seed 3 --out docs/images/edit.png
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from scripts.render_motions import SheetRow, contact_sheet, load_engine
from t2m.model.evaluation.probes import probe_by_name

REPO = Path(__file__).resolve().parent.parent
SENTENCES = [("a person walks forward", 3.0), ("a person waves with the right hand", 2.0), ("a person bows", 3.0)]
EDITED, NEW_TEXT, PROBE = 1, "a person raises the left hand", "raise_left"


def _span_probe(motion, segment: int) -> str:
    """The raise-left probe on one segment's frames: which hand is up, measured."""
    span = motion.segments[segment]
    result = probe_by_name(PROBE).check(motion.joints[span.start_frame:span.end_frame])
    verdict = "pass" if result.passed else "fail"
    return f"[{PROBE} on segment {segment + 1}: {result.value:+.2f} {result.unit}, {verdict}]"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--bundle", default=str(REPO / "t2m" / "bundles" / "default"), help="bundle directory")
    parser.add_argument("--out", default=str(REPO / "docs" / "images" / "edit.png"), help="the PNG to write")
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args(argv)
    from t2m.api import RegenerateEdit
    from t2m.runtime.edit_runner import edit_with_engine
    from t2m.runtime.handles import make_handle
    from t2m.runtime.types import GenerationRequest, SegmentRequest

    engine = load_engine(args.bundle)
    if engine is None:
        return 2
    limits = engine.limits
    request = GenerationRequest([SegmentRequest(t, d) for t, d in SENTENCES], seed=args.seed,
                                guidance=limits.guidance())
    motion = engine.generate(request)
    handle = make_handle(limits, request, motion.codes)
    if handle is None:
        print(f"error: model {limits.name} makes no handle (its family has no edits)", file=sys.stderr)
        return 2
    edited = edit_with_engine(engine, handle, [RegenerateEdit(segment=EDITED, text=NEW_TEXT)]).motion
    same = np.all(edited.joints == motion.joints, axis=(1, 2))
    kept = int(np.argmin(same)) if not same.all() else len(same)
    joins = tuple(span.start_frame for span in motion.segments[1:])
    sentences = " -> ".join(f'"{text}" {seconds:g} s' for text, seconds in SENTENCES)
    rows = [SheetRow(motion.joints, f"generated, seed {args.seed}: {sentences}  {_span_probe(motion, EDITED)}",
                     joins),
            SheetRow(edited.joints, f'edited: segment {EDITED + 1} regenerated as "{NEW_TEXT}"; the first {kept} '
                                    f"frames bit-identical  {_span_probe(edited, EDITED)}",
                     tuple(span.start_frame for span in edited.segments[1:]))]
    written = contact_sheet(rows, args.out, frames_per_row=10)
    print(f"wrote {written} ({written.stat().st_size / 1024:.0f} KiB); model {limits.name} {limits.version}, "
          f"first {kept} of {len(motion.joints)} frames bit-identical")
    return 0


if __name__ == "__main__":
    sys.exit(main())
