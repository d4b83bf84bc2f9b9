"""The embedded models' motions for fixed seeds are the recorded ones.

The GPT model's recording (tests/data/gpt_model_outputs.npz, by tests/data/record_model_outputs.py) was made with the
code as it was before the package moved under t2m/; on the recording machine the joints came out bit-identical
after it (sha256 in CHANGELOG.md). The default T2M-HiFiGPT model's (tests/data/default_model_outputs.npz) was
recorded when it became the default; the masked model's (tests/data/masked_model_outputs.npz) before the
family seam was built. Across CPUs onnxruntime may differ in the last float bits, hence the tolerance;
segment spans (token counts, End decisions) must match exactly.

Since exact durations, a segment of d seconds answers exactly round(d * fps) frames: the engine fits each segment's
decoded frames to that count (engine/timeline.py). The recordings were not re-recorded for it, on purpose: they hold
the decoded motion, and the test checks both sides of the fit separately. (a) The decoded motion (an engine with
exact_durations=False) is the recording, spans included: the model's codes, its End / stop decisions and the single
decode did not change. (b) The served motion is the recording fitted by the engine's own timeline (fit_frames), and
its spans are the exact ones: 3 + 2 + 2 s gives (0, 60), (60, 100), (100, 140) on every model, where the default
model (8 frames per step) decoded (0, 64), (64, 104), (104, 144). Re-recording the fitted motion instead would have
let a change of codes hide behind a change of timeline.

A model may have more than one recording (tests/data/<stem>.<machine>.npz): the masked model's int8 graphs give
other codes on an AMD EPYC with AVX-512 (VNNI) than on the machine that recorded it (every frame differed,
2026-11-27), as a sampled model's codes do once one logit's last bits differ. The motions must equal one of the
recordings; a change of the service's code matches none of them.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from t2m.runtime.timeline import fit_frames
from t2m.runtime.types import frames_for_duration
from tests.data.record_model_outputs import CASES, record

DATA = Path(__file__).resolve().parents[1] / "data"
EXACT_SPANS = {"walk_3s_g3": [[0, 60]], "stream_g3": [[0, 60], [60, 100], [100, 140]]}


def _compare(actual: dict[str, np.ndarray], expected: dict[str, np.ndarray], what: str) -> None:
    assert sorted(actual) == sorted(expected), what
    for key, array in actual.items():
        if key.endswith("_spans"):
            np.testing.assert_array_equal(array, expected[key], err_msg=f"{what}: {key}")
        else:
            np.testing.assert_allclose(array, expected[key], atol=1e-4, rtol=0, err_msg=f"{what}: {key}")


def _fitted(recorded: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The recording as the service answers it: each segment with a duration fitted to round(duration * fps)."""
    fitted = {}
    for name, request in CASES.items():
        spans = recorded[name + "_spans"]
        targets = [None if s.duration is None else frames_for_duration(s.duration) for s in request.segments]
        counts = [int(end - start) for start, end in spans]
        fitted[name] = fit_frames(recorded[name], counts, targets)
        ends = np.cumsum([count if target is None else target for count, target in zip(counts, targets)])
        fitted[name + "_spans"] = np.stack([ends - np.diff(ends, prepend=0), ends], axis=1).astype(np.int64)
    return fitted


def recordings(stem: str) -> list[Path]:
    """The model's recordings: the first one made, then one per machine type whose CPU computes other bits."""
    return sorted(DATA.glob(f"{stem}*.npz"), key=lambda path: (path.name != f"{stem}.npz", path.name))


@pytest.mark.parametrize("model, stem", [("gpt_model", "gpt_model_outputs"),
                                         ("default_model", "default_model_outputs"),
                                         ("masked_model", "masked_model_outputs")])
def test_model_outputs_match_the_recording(model, stem, request):
    from t2m.runtime.engine import OnnxEngine

    engine = OnnxEngine.load(request.getfixturevalue(model), intra_op_threads=1)
    served = record(engine)
    engine.exact_durations = False
    decoded = record(engine)
    assert len(CASES) == 3
    for name, spans in EXACT_SPANS.items():
        assert served[name + "_spans"].tolist() == spans, name
    mismatches = []
    for path in recordings(stem):
        expected = dict(np.load(path))
        try:
            _compare(decoded, expected, "decoded (codes unchanged)")
            _compare(served, _fitted(expected), "served (the recording fitted)")
            return
        except AssertionError as error:
            mismatches.append(f"{path.name}: {str(error).strip().splitlines()[0]}")
    pytest.fail("the motions match none of the recordings (on a machine type without one of its own, record one "
                "as tests/data/record_model_outputs.py says):\n" + "\n".join(mismatches))
