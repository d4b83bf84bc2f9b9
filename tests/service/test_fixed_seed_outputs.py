"""The embedded models' motions for fixed seeds are the recorded ones.

The GPT model's recording (tests/data/gpt_model_outputs.npz, by tests/data/record_model_outputs.py) was made with the
code as it was before the package moved under t2m/; on the recording machine the joints came out bit-identical
after it (sha256 in CHANGELOG.md). The default T2M-HiFiGPT model's (tests/data/default_model_outputs.npz) was
recorded when it became the default; the masked model's (tests/data/masked_model_outputs.npz) before the
family seam (issue 24) was built. Across CPUs onnxruntime may differ in the last float bits, hence the tolerance;
segment spans (token counts, End decisions) must match exactly.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "data"))
from record_model_outputs import CASES, record

DATA = Path(__file__).resolve().parents[1] / "data"


@pytest.mark.parametrize("model, recording", [("gpt_model", "gpt_model_outputs.npz"),
                                              ("default_model", "default_model_outputs.npz"),
                                              ("masked_model", "masked_model_outputs.npz")])
def test_model_outputs_match_the_recording(model, recording, request):
    from t2m.service.engine.engine import OnnxEngine

    expected = np.load(DATA / recording)
    actual = record(OnnxEngine.load(request.getfixturevalue(model), intra_op_threads=1))
    assert sorted(actual) == sorted(expected.files) and len(CASES) == 3
    for key, array in actual.items():
        if key.endswith("_spans"):
            np.testing.assert_array_equal(array, expected[key], err_msg=key)
        else:
            np.testing.assert_allclose(array, expected[key], atol=1e-4, rtol=0, err_msg=key)
