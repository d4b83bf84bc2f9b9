"""Editing one segment of a motion vs generating the whole motion again, engine level (no HTTP).

A 3-sentence 8 s motion ("walk 3 s, wave 2 s, bow 3 s") is generated once; then, alternating, the whole request is
generated again (what a client without /edit does to change the wave) and the wave alone is edited the way POST
/edit does it (t2m.runtime.edit_runner.edit_with_engine): for a token model the handle read back and checked, the
edited segment sampled alone with its own seed (the masked family: inpainted with the kept codes around it), every
code decoded once (OnnxEngine.compose), the new handle written; for a diffusion model the recipe replayed, the
segment made again and its joins re-made. Medians and p90 of
--repeats, the handle's size, and how many leading frames stayed bit-identical. Printed, never asserted.

    t2m bench edits [--model t2m/bundles/default] [--model t2m/bundles/gpt] [--repeats 20]
        [--threads 1]
"""
from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from t2m.api import RegenerateEdit
from t2m.bundles import EMBEDDED_BUNDLES
from t2m.runtime.edit_runner import edit_with_engine
from t2m.runtime.engine import OnnxEngine
from t2m.runtime.handles import make_handle, read_handle
from t2m.runtime.recipes import read_recipe
from t2m.runtime.types import GenerationRequest, Motion, SegmentRequest

SENTENCES = [("a person walks forward", 3.0), ("a person waves with the right hand", 2.0), ("a person bows", 3.0)]
EDITED = 1
NEW_TEXT = "a person raises the left hand"
SEED = 7


def _times(fn: Callable[[], object], repeats: int) -> list[float]:
    fn()   # warm-up
    out = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        out.append((time.perf_counter() - start) * 1000)
    return out


def measure(model: Path, repeats: int, threads: int) -> None:
    engine = OnnxEngine.load(model, intra_op_threads=threads)
    request = GenerationRequest([SegmentRequest(t, d) for t, d in SENTENCES], seed=SEED,
                                guidance=engine.limits.guidance())
    motion = engine.generate(request)
    handle = make_handle(engine.limits, request, motion.codes)
    assert handle is not None, f"{model}: its codes are not tokens (no handle)"

    def again() -> object:
        return engine.generate(request)

    edits = [RegenerateEdit(segment=EDITED, text=NEW_TEXT)]

    def edit() -> object:
        return edit_with_engine(engine, handle, edits).motion

    # alternate the two so that a change of the machine's load touches both alike
    whole_ms: list[float] = []
    edit_ms: list[float] = []
    for _ in range(repeats):
        whole_ms += _times(again, 1)
        edit_ms += _times(edit, 1)
    edited = edit()
    assert isinstance(edited, Motion)
    same = np.all(edited.joints == motion.joints, axis=(1, 2))
    kept_frames = int(np.argmin(same)) if not same.all() else len(same)
    read = read_recipe if engine.limits.recipe else read_handle   # a diffusion model's handle is its recipe
    read_ms = _times(lambda: read(handle, engine.limits), repeats)
    shown = model.name
    print(f"{engine.limits.name} {engine.limits.version} ({shown}): {len(motion.joints)} frames, "
          f"{sum(len(c) for c in motion.codes or [])} code steps, handle {len(handle)} characters "
          f"(read + checked in {np.median(read_ms):.2f} ms)")
    for name, values in (("generate all 3 again", whole_ms), ("edit segment 1 only", edit_ms)):
        print(f"  {name:22s} p50 {np.median(values):7.1f} ms   p90 {np.percentile(values, 90):7.1f} ms")
    print(f"  edit / generate (p50): {np.median(edit_ms) / np.median(whole_ms):.2f}; first {kept_frames} of "
          f"{motion.segments[EDITED].start_frame} frames before the edited segment bit-identical")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", type=Path, action="append",
                        help="a bundle directory (repeatable); default: the three embedded models")
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--threads", type=int, default=1, help="onnxruntime intra-op threads")
    args = parser.parse_args(argv)
    models = args.model or [EMBEDDED_BUNDLES[name] for name in ("default", "gpt", "masked")]
    for model in models:
        measure(model, args.repeats, args.threads)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
