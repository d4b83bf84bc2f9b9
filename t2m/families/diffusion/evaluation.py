"""`t2m eval --bundle DIR` for the diffusion family: Table 1 and the stream table of exactly what a bundle serves.

The motions come from the service's own object (t2m.families.diffusion.served.DiffusionCodes over the bundle's
denoiser graph): one request per caption of exactly the crop's frames, and one request per stream whose sentences are
its segments, so DiP chains them call after call and MDM in-betweens its joins as served. The family's "codes" are
normalised frames (frames_per_token 1); the bundle's decoder.onnx de-normalises them. The text features are the
bundle's own text graph: pooled features (MDM) or token states with their mask (DiP).
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from t2m.model.evaluation.evaluate import Models

__all__ = ["BundleDiffusionFamily", "FrameDecoder", "TokenStateFeatures", "diffusion_bundle_models"]


class TokenStateFeatures:
    """Captions -> token states padded to the bundle's text length, the attention mask as one more last channel
    ([N, L, D + 1]): the evaluation keeps one array per caption, and the family splits it again."""

    def __init__(self, text: Any, max_length: int) -> None:
        self.text = text              # t2m.runtime.text.TextEncoder (the bundle's tokenizer and text graph)
        self.max_length = max_length

    def encode(self, texts: Sequence[str]) -> np.ndarray:
        from t2m.runtime.text import encode_token_states

        states, masks = encode_token_states(self.text, texts)
        out = np.zeros((len(texts), self.max_length, states[0].shape[-1] + 1), np.float32)
        for row, (state, mask) in enumerate(zip(states, masks)):
            out[row, :len(state), :-1] = state
            out[row, :len(mask), -1] = mask
        return out


def split_token_states(cond: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One TokenStateFeatures row -> (the real tokens' states [n, D], their mask [n])."""
    keep = cond[:, -1] > 0.5
    return np.ascontiguousarray(cond[keep, :-1]), np.ones(int(keep.sum()), bool)


class BundleDiffusionFamily:
    """Exactly `tokens[i]` frames per caption (and per stream sentence) from the served diffusion object."""

    text_encoder = "bundle"
    batch_by_length = False
    joined = "one request per stream (the service's own joins)"

    def __init__(self, served: Any, max_frames: int, path: str, describe: str) -> None:
        self._served = served          # t2m.families.diffusion.served.DiffusionCodes
        self.name = "diffusion"
        self.max_tokens = max_frames
        self.paths = {"bundle": path}
        self.labels = {"bundle": "served bundle"}
        self.settings: dict[str, Any] = {"steps": served.settings.steps, "arch": served.settings.arch}
        self._describe = describe

    def report_note(self) -> str:
        return self._describe

    def _request(self, conds: Sequence[np.ndarray], frames: Sequence[int], guidance: float,
                 rng: np.random.Generator) -> Any:
        from t2m.families.diffusion.served import DiffusionRequest
        from t2m.runtime.text import pooled_token_states

        if self._served.settings.tokens:
            split = [split_token_states(np.asarray(cond, np.float32)) for cond in conds]
            texts, masks = [states for states, _ in split], [mask for _, mask in split]
            pooled = pooled_token_states(texts)
        else:
            texts, masks = [np.asarray(cond, np.float32) for cond in conds], None
            pooled = np.stack(texts)
        return DiffusionRequest(conds=pooled.astype(np.float32), texts=texts, text_masks=masks,
                                frames=[int(f) for f in frames], guidance=guidance, rng=rng,
                                cancelled=lambda: False)

    def codes(self, cond: np.ndarray, tokens: Sequence[int], guidance: float, temperature: float,
              top_k: int | None, rng: np.random.Generator) -> list[Any]:
        """One request per row (a one-sentence motion of exactly tokens[i] frames); temperature and top_k do not
        apply to DDPM sampling."""
        jobs = [self._request([row], [frames], guidance, rng) for row, frames in zip(cond, tokens)]
        made = self._served.sample(jobs, self.max_tokens, None)
        return [np.asarray(parts[0], np.float32) for parts in made]

    def sample_streams(self, conds: Sequence[np.ndarray], tokens: Sequence[Sequence[int]], guidance: float,
                       rng: np.random.Generator) -> list[list[np.ndarray]]:
        """One request per stream, its sentences the segments: the frames of each segment as served."""
        jobs = [self._request(list(cond), frames, guidance, rng) for cond, frames in zip(conds, tokens)]
        made = self._served.sample(jobs, self.max_tokens, None)
        return [[np.asarray(part, np.float32) for part in parts] for parts in made]

    def estimate_tokens(self, cond: np.ndarray, rng: np.random.Generator) -> list[int] | None:
        return None   # no length estimator: every segment needs a duration


class FrameDecoder:
    """decoder.onnx of a diffusion bundle: normalised frames [B, T, D] -> raw features (x * std + mean)."""

    frames_per_token = 1
    code_dtype = np.float32

    def __init__(self, session: Any) -> None:
        self.session = session

    def decode_batch(self, codes: np.ndarray) -> np.ndarray:
        (features,) = self.session.run(None, {"motion": np.asarray(codes, np.float32)})
        return np.asarray(features, np.float32)


def diffusion_bundle_models(evaluator: Any, evaluator_run: str, bundle: Any, served: Any) -> Models:
    """The evaluator and a served diffusion bundle (text graph, denoiser and decoder in onnxruntime)."""
    from t2m.bundle import get_family
    from t2m.runtime.text import TextEncoder, load_tokenizer

    manifest = bundle.manifest
    describe = get_family(manifest.family).describe(manifest, manifest.settings.default_guidance)
    text = TextEncoder(bundle.text_session, load_tokenizer(bundle.tokenizer_file, manifest.text_max_length))
    source = TokenStateFeatures(text, manifest.text_max_length) if served.settings.tokens else text
    family = BundleDiffusionFamily(served, manifest.max_tokens, str(bundle.path), describe)
    return Models(evaluator, None, family, bundle.mean.astype(np.float32), bundle.std.astype(np.float32),
                  evaluator_text=evaluator.config.text_encoder,
                  paths={"evaluator": str(evaluator_run), "bundle": str(bundle.path)},
                  decoder=FrameDecoder(bundle.decoder_session), family_text=source)
