"""The PyTorch reference of a served motion, for the importers' end-to-end tests.

The modules an importer built (our PyTorch networks loaded from the release's files), run through the service's
shared decoding loop (t2m.decoding, via t2m.families.gpt.sampling's and t2m.families.masked.sampling's steps) with the
request's seed, decoded by the PyTorch VQ and turned into joints; the text features come from the PyTorch CLIP tower
read from the same ViT-B-32.pt. `compare_served` runs the same request through the service's engine over the imported
bundle: codes must be identical, text features, decoded features and joints equal to float rounding. Sampling at the
release's own settings (top-k, guidance), not greedy: the draws of the shared loop are part of what is compared.
"""
from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from t2m.export.graphs.decoder import DecoderGraph
from t2m.families.gpt.sampling import sample_codes
from t2m.families.masked.export import MaskedDecoding
from t2m.families.masked.export_graphs import map_decoder_graph
from t2m.families.masked.length_estimator import LengthEstimator
from t2m.families.masked.loop import MaskedJob, sample_branch_maps, sample_token_maps
from t2m.families.masked.masked_transformer import MaskedTransformer
from t2m.families.masked.residual_transformer import ResidualTransformer
from t2m.families.masked.sampling import TorchMaskedStep, TorchResidualStep
from t2m.families.masked.served import draw_rows
from t2m.motion.features import features_to_joints
from t2m.runtime.types import GenerationRequest, SegmentRequest, tokens_for_duration

Segments = Sequence[tuple[str, float | None]]
FRAMES_PER_TOKEN = 4


@dataclasses.dataclass
class ReferenceMotion:
    codes: list[np.ndarray]      # per segment: [n] (GPT) or [rows, C, R] (masked)
    features: np.ndarray         # [frames, D], de-normalised
    joints: np.ndarray           # [frames, J, 3]


@dataclasses.dataclass
class Generator:
    """One token generator of a masked release and its top-k (MoGenTS has two: ts, then aux)."""

    masked: MaskedTransformer
    residual: ResidualTransformer | None
    top_k: int | None
    residual_top_k: int | None


@torch.no_grad()
def clip_features(clip: Path, texts: Sequence[str]) -> np.ndarray:
    """OpenAI's CLIP encode_text, our PyTorch tower read from the file, on OpenAI's tokenization."""
    from t2m.model.networks.clip_tokenizer import build_clip_tokenizer
    from t2m.model.networks.clip_weights import load_clip_text

    ids = [e.ids for e in build_clip_tokenizer().encode_batch(list(texts))]
    return load_clip_text(clip).encode_text(torch.tensor(ids)).numpy()


@torch.no_grad()
def _decode(decoder: torch.nn.Module, codes: list[np.ndarray], skeleton: str) -> ReferenceMotion:
    features = decoder(torch.from_numpy(np.concatenate(codes))[None])[0].numpy()
    return ReferenceMotion(codes, features, features_to_joints(features, skeleton))


def gpt_motion(models, conds: np.ndarray, segments: Segments, seed: int, guidance: float,
               skeleton: str = "smpl22") -> ReferenceMotion:
    """T2M-GPT's release (t2m_gpt_import.ImportedModels): codes by t2m.families.gpt.sampling (End stops a free segment),
    the VQ decode x std + mean, joints."""
    targets = [None if d is None else tokens_for_duration(d) for _, d in segments]
    codes = sample_codes(models.gpt, conds, targets, guidance=guidance, rng=seed)
    decoder = DecoderGraph(models.vq, models.mean, models.std).eval()
    return _decode(decoder, [np.asarray(c, dtype=np.int64) for c in codes], skeleton)


@torch.no_grad()
def masked_rows(length: LengthEstimator | None, conds: np.ndarray, segments: Segments, rng: np.random.Generator,
                max_tokens: int) -> list[int]:
    """Rows per segment: from the duration, or drawn from the length estimator's logits (one uniform per free
    segment, in segment order, before any token)."""
    rows = []
    for cond, (_, duration) in zip(conds, segments):
        if duration is None:
            assert length is not None, "a free segment needs the length estimator"
            logits = length(torch.from_numpy(cond[None]))[0].numpy()
            rows.append(draw_rows(logits, rng, max_tokens))
        else:
            rows.append(tokens_for_duration(duration))
    return rows


def masked_motion(generators: Sequence[Generator], decoding: MaskedDecoding, vq, mean: np.ndarray, std: np.ndarray,
                  length: LengthEstimator | None, conds: np.ndarray, segments: Segments, seed: int, max_tokens: int,
                  skeleton: str = "smpl22") -> ReferenceMotion:
    """A masked release (MoMask: one generator; MoGenTS: ts then aux on the same rows and generator) at the release's
    decoding settings: token maps by t2m.families.masked.loop over the PyTorch modules, joined along the columns,
    decoded
    once by the release's VQ."""
    rng = np.random.default_rng(seed)
    rows = masked_rows(length, conds, segments, rng, max_tokens)
    first = generators[0]
    job = MaskedJob(conds=conds, rows=rows, rng=rng, steps=decoding.steps, guidance=decoding.guidance,
                    residual_guidance=decoding.residual_guidance,
                    temperature=1.0 if decoding.temperature is None else decoding.temperature,
                    top_k=first.top_k, residual_top_k=first.residual_top_k,
                    residual_temperature=decoding.residual_temperature)
    job.branches = [dataclasses.replace(job, top_k=g.top_k, residual_top_k=g.residual_top_k, branches=[])
                    for g in generators[1:]]
    steps = [(TorchMaskedStep(g.masked), None if g.residual is None else TorchResidualStep(g.residual))
             for g in generators]
    (maps,) = (sample_branch_maps(steps, [job]) if job.branches else sample_token_maps(*steps[0], [job]))
    assert maps is not None
    return _decode(map_decoder_graph(vq, mean, std), maps, skeleton)


def compare_served(bundle: Path, segments: Segments, seed: int, expected: ReferenceMotion,
                   conds: np.ndarray) -> dict[str, float]:
    """The service's engine over the bundle on the same request (the model's default guidance, temperature and
    top-k): codes and segment spans must be identical; returns max |diff| of text features, decoded features and
    joints."""
    from t2m.runtime.engine import OnnxEngine

    engine = OnnxEngine.load(bundle, intra_op_threads=1)
    seen: list[tuple[np.ndarray, np.ndarray]] = []
    original = engine.decoder.decode

    def decode(codes: np.ndarray) -> np.ndarray:
        features = original(codes)
        seen.append((np.asarray(codes), features))
        return features

    engine.decoder.decode = decode  # type: ignore[method-assign]
    request = GenerationRequest(segments=[SegmentRequest(text, duration) for text, duration in segments], seed=seed,
                                guidance=engine.limits.default_guidance)
    motion = engine.generate(request)
    (codes, features), = seen
    np.testing.assert_array_equal(codes, np.concatenate(expected.codes))
    lengths = np.cumsum([0] + [len(c) * FRAMES_PER_TOKEN for c in expected.codes])
    assert [(s.start_frame, s.end_frame) for s in motion.segments] == list(itertools.pairwise(lengths))
    assert motion.joints.shape == expected.joints.shape and np.isfinite(motion.joints).all()
    return {"text": float(np.abs(engine.text.encode([t for t, _ in segments]) - conds).max()),
            "features": float(np.abs(features - expected.features).max()),
            "joints": float(np.abs(motion.joints - expected.joints).max()),
            "largest_joint": float(np.abs(expected.joints).max()),
            "largest_feature": float(np.abs(expected.features).max())}


def within_rounding(diffs: dict[str, float]) -> bool:
    """Text features to 1e-5; decoded features and joints to 1e-5 of their largest value: joints integrate the root's
    velocities over the motion, and random weights drift tens of metres, which scales float32's rounding."""
    return (diffs["text"] <= 1e-5 and diffs["features"] <= 1e-5 * max(1.0, diffs["largest_feature"])
            and diffs["joints"] <= 1e-5 * max(1.0, diffs["largest_joint"]))
