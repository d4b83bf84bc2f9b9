"""`t2m eval --bundle DIR`: Table 1 for exactly what a bundle serves, without its training runs (families that
declare `evaluates_bundle`; each builds its Models with `load_bundle_eval_models`: here the lockstep families, GPT and
T2M-HiFiGPT, whose served object samples jobs of exact lengths; the diffusion family's is
t2m.families.diffusion.evaluation).

The family's codes come from the service's own loop (the family's served object, e.g. t2m.families.gpt.served
over t2m.families.gpt.loop) stepping the bundle's step graphs, its text features from the bundle's tokenizer +
text_encoder.onnx, and the motions from its decoder.onnx, all loaded by the service's loader (hashes checked). So an
int8 graph is measured as served. A bundle has no VQ encoder: the evaluation has no VQ-reconstruction row (and no
"real crops' VQ codes" stream row).
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from t2m.decoding.lockstep import SamplingJob
from t2m.model.evaluation.evaluate import Models

__all__ = ["BundleDecoder", "BundleLockstepFamily", "load_bundle_models", "lockstep_bundle_models"]


class BundleLockstepFamily:
    """Exactly `tokens[i]` time steps per text from a bundle's step graphs (GPT: one code each; T2M-HiFiGPT: a row
    of R codes): every row one target segment of one job, as the PyTorch family's reference job, so both draw the same
    uniforms in the same order."""

    text_encoder = "bundle"        # features from the bundle's own text graph (Models.family_text)
    batch_by_length = False

    def __init__(self, codes: Any, max_tokens: int, path: str, name: str = "gpt") -> None:
        self._codes = codes        # the family's served object (t2m.runtime.family_codes.FamilyCodes)
        self.name = name
        self.max_tokens = max_tokens
        self.paths = {"bundle": path}
        self.settings: dict[str, Any] = {}
        self.labels = {"bundle": "served bundle"}
        self.joined = "codes concatenated"


    def report_note(self) -> str:
        return ""

    def codes(self, cond: np.ndarray, tokens: Sequence[int], guidance: float, temperature: float,
              top_k: int | None, rng: np.random.Generator) -> list[Any]:
        job = SamplingJob.of(cond, [int(t) for t in tokens], max_tokens=self.max_tokens, guidance=guidance,
                             temperature=temperature, top_k=top_k, rng=rng)
        (result,) = self._codes.sample([job], self.max_tokens, None)
        return [np.asarray(c, np.int64) for c in result]

    def estimate_tokens(self, cond: np.ndarray, rng: np.random.Generator) -> list[int] | None:
        return None


class BundleDecoder:
    """decoder.onnx on a batch of equal-length code rows (the service decodes one row at a time; the graph takes
    any batch, and de-normalises inside)."""

    def __init__(self, session: Any, frames_per_token: int) -> None:
        self.session = session
        self.frames_per_token = frames_per_token

    def decode_batch(self, codes: np.ndarray) -> np.ndarray:
        (features,) = self.session.run(["features"], {"codes": np.asarray(codes, np.int64)})
        return np.asarray(features, np.float32)


def load_bundle_models(evaluator_run: str | Path, bundle_dir: str | Path, threads: int = 1) -> Models:
    """The evaluator and a served bundle of a family that `evaluates_bundle`, loaded by the service's loader."""
    from t2m.bundle import get_family, iter_families
    from t2m.model.training.checkpoint import load_model
    from t2m.runtime.bundle_loader import load_bundle

    bundle = load_bundle(bundle_dir, intra_op_threads=threads)
    manifest = bundle.manifest
    model_family = get_family(manifest.family)
    if not model_family.evaluates_bundle:
        which = [family.name for family in iter_families() if family.evaluates_bundle]
        raise ValueError(f"{bundle_dir}: --bundle evaluates bundles of the families {which}; this one is "
                         f"{manifest.family!r}")
    evaluator = load_model(evaluator_run, expect_kind="evaluator")
    if evaluator.config.feature_dim != manifest.feature_dim:
        raise ValueError(f"feature dims differ: evaluator {evaluator.config.feature_dim}, bundle "
                         f"{manifest.feature_dim}")
    return model_family.load_bundle_eval_models(evaluator, str(evaluator_run), bundle)


def lockstep_bundle_models(evaluator: Any, evaluator_run: str, bundle: Any, served: Any) -> Models:
    """A GPT or T2M-HiFiGPT bundle: its text graph, step graphs (through `served`) and decoder in onnxruntime."""
    from t2m.runtime.text import TextEncoder, load_tokenizer

    manifest = bundle.manifest
    family = BundleLockstepFamily(served, manifest.max_tokens, str(bundle.path), manifest.family)
    text = TextEncoder(bundle.text_session, load_tokenizer(bundle.tokenizer_file, manifest.text_max_length))
    return Models(evaluator, None, family, bundle.mean.astype(np.float32), bundle.std.astype(np.float32),
                  evaluator_text=evaluator.config.text_encoder,
                  paths={"evaluator": evaluator_run, "bundle": str(bundle.path)},
                  decoder=BundleDecoder(bundle.decoder_session, manifest.frames_per_token), family_text=text)
