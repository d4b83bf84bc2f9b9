"""Record an embedded model's outputs for fixed seeds, checked by tests/service/test_fixed_seed_outputs.py.

tests/data/gpt_model_outputs.npz: the 1-layer GPT (t2m/bundles/gpt, the default up to 0.4.0), recorded before the
0.4.0 restructuring (package moved under t2m/, one bundle contract, sampler split);
tests/data/default_model_outputs.npz: the T2M-HiFiGPT default, recorded again for its 0.3.1 (0.3.0's weights, int8
activations quantised per row: other codes);
tests/data/masked_model_outputs.npz: the masked-family model, recorded again for its 0.2.1 (activations per row, as
the default's).
They hold the decoded motion, before the engine fits each segment to round(duration * fps) frames (an
engine with exact_durations=False answers it), so the recordings pin the model's codes and decode; the test fits them
with the engine's own timeline. Re-record only when that model itself changes:

    python tests/data/record_model_outputs.py t2m/bundles/default tests/data/default_model_outputs.npz
    python tests/data/record_model_outputs.py t2m/bundles/gpt tests/data/gpt_model_outputs.npz
    python tests/data/record_model_outputs.py t2m/bundles/masked tests/data/masked_model_outputs.npz

A machine type whose CPU gives other codes for the same model (other SIMD kernels, other last bits) gets a recording
of its own beside the first, made with the code that matched the first one on its machine, e.g.
tests/data/masked_model_outputs.epyc-avx512.npz (AMD EPYC with AVX-512 VNNI, 2026-11-27); the test accepts any.
"""
from __future__ import annotations

import hashlib
import sys

import numpy as np

from t2m.runtime.engine import OnnxEngine
from t2m.runtime.types import GenerationRequest, SegmentRequest

CASES = {
    "walk_3s_g3": GenerationRequest([SegmentRequest("a person walks forward", 3.0)], seed=123, guidance=3.0),
    "stream_g3": GenerationRequest([SegmentRequest("a person walks forward", 3.0),
                                    SegmentRequest("a person waves with the right hand", 2.0),
                                    SegmentRequest("a person bows", 2.0)], seed=7, guidance=3.0),
    "free_g1_topk": GenerationRequest([SegmentRequest("someone runs", None)], seed=5, guidance=1.0, top_k=20,
                                      temperature=0.8),
}


def record(engine: OnnxEngine) -> dict[str, np.ndarray]:
    """Joints and segment spans of every case."""
    arrays = {}
    for name, request in CASES.items():
        motion = engine.generate(request)
        arrays[name] = motion.joints
        arrays[name + "_spans"] = np.asarray([[s.start_frame, s.end_frame] for s in motion.segments], np.int64)
    return arrays


if __name__ == "__main__":
    bundle, out = sys.argv[1], sys.argv[2]
    arrays = record(OnnxEngine.load(bundle, intra_op_threads=1, exact_durations=False))
    for key, array in arrays.items():
        print(key, array.shape, hashlib.sha256(array.tobytes()).hexdigest()[:16])
    np.savez_compressed(out, **arrays)
