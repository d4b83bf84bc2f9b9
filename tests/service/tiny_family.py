"""A fourth model family written entirely inside the test suite, to prove the family seam.

Recipe ("fourth"): one graph scores every code of a segment at once from its text feature (no autoregression, no
masking), the service draws each code from the guided logits with the request's generator, and a decoder turns
each code into `frames_per_token` frames of features. Random weights: the motion is meaningless, the plumbing is
what is tested. Nothing under t2m/ names this family; it registers itself with `t2m.bundle.register_family`.
"""
from __future__ import annotations

import argparse
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from t2m.bundle import Capabilities, ModelFamily
from t2m.bundle.family import FieldRule
from t2m.bundle.graphs import FLOAT32, INT64, GraphSpec, TensorSpec, features_output
from t2m.bundle.manifest import COMMON_FILES, POSITIVE, is_bool, is_number
from t2m.runtime.types import GenerationRequest, ModelLimits, RequestLimitError, tokens_for_duration

CODES_GRAPH = "fourth_codes.onnx"


@dataclass(frozen=True)
class TinySettings:
    width: int
    unconditional_branch: bool
    default_guidance: float
    length_conditioning: bool = False


@dataclass
class TinyJob:
    """One request: its segments' text features, code counts and generator."""

    conds: np.ndarray
    rows: list[int]
    guidance: float
    temperature: float
    rng: np.random.Generator


class TinyCodes:
    """The served object: all segments of all jobs scored in one graph call, codes drawn per job, in order."""

    def __init__(self, bundle: Any) -> None:
        self.session = bundle.sessions[CODES_GRAPH]

    def job(self, request: GenerationRequest, text: Any, limits: ModelLimits) -> TinyJob:
        rows = []
        for index, segment in enumerate(request.segments):
            if segment.duration is None:
                raise RequestLimitError(f"segments.{index}.duration", "the tiny family needs a duration")
            rows.append(tokens_for_duration(segment.duration, limits.fps, limits.frames_per_token))
            if rows[-1] > limits.max_tokens:
                raise RequestLimitError(f"segments.{index}.duration", f"needs {rows[-1]} tokens, the model makes at "
                                        f"most {limits.max_tokens}")
        return TinyJob(conds=text.encode([s.text for s in request.segments]), rows=rows, guidance=request.guidance,
                       temperature=request.temperature, rng=np.random.default_rng(request.seed))

    def sample(self, jobs: Sequence[TinyJob], max_tokens: int,
               on_step: Callable[[int], None] | None) -> list[list[np.ndarray] | None]:
        conds = np.concatenate([job.conds for job in jobs]).astype(np.float32)
        (cond_logits,) = self.session.run(["logits"], {"cond": conds})
        (null_logits,) = self.session.run(["logits"], {"cond": np.zeros_like(conds)})
        results: list[list[np.ndarray] | None] = []
        start = 0
        for job in jobs:
            segments = []
            for offset, rows in enumerate(job.rows):
                cond, null = cond_logits[start + offset, :rows], null_logits[start + offset, :rows]
                logits = (null + job.guidance * (cond - null)) / max(job.temperature, 1e-6)
                probabilities = np.exp(logits - logits.max(axis=-1, keepdims=True))
                probabilities /= probabilities.sum(axis=-1, keepdims=True)
                segments.append(np.array([job.rng.choice(len(p), p=p) for p in probabilities], np.int64))
            start += len(job.rows)
            results.append(segments)
        if on_step is not None:
            on_step(1)
        return results


class TinyFamily(ModelFamily):
    name = "fourth"
    title = "fourth: every code of a segment scored at once from its text, drawn with guidance"
    fields: ClassVar[Mapping[str, FieldRule]] = {
        "fourth.width": POSITIVE, "fourth.unconditional_branch": (is_bool, "true or false"),
        "fourth.default_guidance": (lambda v: is_number(v) and v >= 0, "a number >= 0")}
    capabilities = Capabilities(why_not_early="a tiny segment is drawn whole")

    def required_files(self, manifest: Mapping[str, Any]) -> tuple[str, ...]:
        return (*COMMON_FILES[:2], CODES_GRAPH, *COMMON_FILES[2:])

    def graphs(self, manifest: Mapping[str, Any]) -> dict[str, GraphSpec]:
        dim, size, rows = manifest["text_encoder"]["dim"], manifest["codebook_size"], manifest["max_tokens"]
        return {CODES_GRAPH: GraphSpec(inputs=(TensorSpec("cond", FLOAT32, (None, dim)),),
                                       outputs=(TensorSpec("logits", FLOAT32, (None, rows, size)),)),
                "decoder.onnx": GraphSpec(inputs=(TensorSpec("codes", INT64, (None, None)),),
                                          outputs=features_output(manifest))}

    def settings(self, manifest: Mapping[str, Any]) -> TinySettings:
        block = manifest["fourth"]
        return TinySettings(block["width"], block["unconditional_branch"], float(block["default_guidance"]))

    def serve(self, bundle: Any) -> TinyCodes:
        return TinyCodes(bundle)

    def add_export_arguments(self, group: argparse._ArgumentGroup) -> None:
        group.add_argument("--fourth-seed", type=int, default=None, help="family fourth: seed of the random weights")

    def export(self, args: argparse.Namespace, int8: frozenset[str]) -> tuple[dict, dict]:
        return export_tiny_bundle(args.output, seed=args.fourth_seed or 0, name=args.name or "t2m-tiny-test",
                                  version=args.version), {"parity": "not checked (random weights)", "int8": {}}


def export_tiny_bundle(out_dir: Path, *, seed: int = 0, name: str = "t2m-tiny-test", version: str = "0.0.0",
                       codebook_size: int = 16, max_tokens: int = 25, width: int = 32) -> dict:
    """Random torch modules -> the tiny family's graphs, text graph, statistics and card -> a verified bundle."""
    import torch
    from torch import nn

    from t2m.export.graphs.export import export_graph
    from t2m.export.graphs.text import export_tiny_text_encoder
    from t2m.export.writing.bundle import render_family_card, write_bundle

    torch.manual_seed(seed)
    feature_dim, frames_per_token, text_dim = 263, 4, 32

    class CodeScorer(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.net = nn.Sequential(nn.Linear(text_dim, width), nn.GELU(),
                                     nn.Linear(width, max_tokens * codebook_size))

        def forward(self, cond: torch.Tensor) -> torch.Tensor:
            return self.net(cond).view(-1, max_tokens, codebook_size)

    class Decoder(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.embedding = nn.Embedding(codebook_size, feature_dim * frames_per_token)
            self.register_buffer("mean", torch.randn(feature_dim) * 0.01)
            self.register_buffer("std", torch.rand(feature_dim) * 0.05 + 0.01)

        def forward(self, codes: torch.Tensor) -> torch.Tensor:
            frames = self.embedding(codes).view(codes.shape[0], -1, feature_dim) * 0.1
            return frames * self.std + self.mean

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    text = export_tiny_text_encoder(out_dir, text_dim, 32, seed=seed)
    export_graph(CodeScorer(), (torch.zeros(2, text_dim),), out_dir / CODES_GRAPH, ["cond"], ["logits"],
                 {"cond": {0: "batch"}, "logits": {0: "batch"}})
    decoder = Decoder()
    export_graph(decoder, (torch.zeros(2, 5, dtype=torch.long),), out_dir / "decoder.onnx", ["codes"], ["features"],
                 {"codes": {0: "batch", 1: "tokens"}, "features": {0: "batch", 1: "frames"}})
    np.save(out_dir / "mean.npy", decoder.mean.numpy())
    np.save(out_dir / "std.npy", decoder.std.numpy())
    manifest: dict[str, Any] = {
        "family": "fourth", "name": name, "version": version, "fps": 20, "skeleton": "smpl22", "num_joints": 22,
        "feature_dim": feature_dim, "frames_per_token": frames_per_token, "max_tokens": max_tokens,
        "codebook_size": codebook_size, "residual_layers": 1, "text_encoder": text,
        "fourth": {"width": width, "unconditional_branch": True, "default_guidance": 2.0},
        "training_data": {"name": "none (random weights)", "license": "Apache-2.0", "attribution": ""},
        "license": "Apache-2.0", "quantization": {"text_encoder": None},
    }
    card = render_family_card(manifest, "A tiny family defined by the test suite (random weights).",
                              [("codes", f"{max_tokens} x {codebook_size} logits from one MLP pass")])
    (out_dir / "MODEL_CARD.md").write_text(card, encoding="utf-8")
    files = {file: out_dir / file for file in (*COMMON_FILES, CODES_GRAPH)}
    return write_bundle(out_dir, files, manifest)


FAMILY = TinyFamily()
