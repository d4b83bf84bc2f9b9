"""T2M-HiFiGPT: a double-tier GPT over a residual VQ's [steps, R] code maps (temporal_step.onnx gives a context and
a stop logit per time step, residual_step.onnx the R codes of that step), decoded by the RVQ-VAE decoder.

The family's code lives in t2m.families.hifigpt.loop (the loop), t2m.families.hifigpt.served (served),
t2m.families.hifigpt.export (export) and t2m.families.hifigpt.evaluation (`t2m eval --hifigpt`)."""
from __future__ import annotations

import argparse
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, ClassVar

from t2m.bundle.family import SEGMENT_EDITS, Capabilities, FieldRule, ModelFamily
from t2m.bundle.graphs import FLOAT32, INT64, GraphSpec, TensorSpec, features_output, kv_shape
from t2m.bundle.manifest import (
    BOOL,
    COMMON_FILES,
    GUIDANCE,
    INTEGER_ABOVE_1,
    POSITIVE,
    QUANTIZATION,
    check_block_size,
)

__all__ = ["FAMILY", "HIFIGPT_FIELDS", "HIFIGPT_GRAPHS", "HiFiGPTFamily", "HiFiGPTSettings"]

HIFIGPT_GRAPHS = ("temporal_step.onnx", "residual_step.onnx")
HIFIGPT_FIELDS: dict[str, FieldRule] = {
    "hifigpt.n_layer_temporal": POSITIVE,
    "hifigpt.n_layer_residual": POSITIVE,
    "hifigpt.n_head": POSITIVE,
    "hifigpt.head_dim": POSITIVE,
    "hifigpt.block_size": INTEGER_ABOVE_1,
    "hifigpt.length_conditioning": BOOL,
    "hifigpt.unconditional_branch": BOOL,
    "hifigpt.default_guidance": GUIDANCE,
}
OPTIONAL_FIELDS: dict[str, FieldRule] = {
    "quantization.temporal_step": QUANTIZATION,
    "quantization.residual_step": QUANTIZATION,
}


@dataclass(frozen=True)
class HiFiGPTSettings:
    """The `hifigpt` block: the two step graphs' sizes and the loop's defaults (t2m.families.hifigpt.loop)."""

    n_layer_temporal: int
    n_layer_residual: int
    n_head: int
    head_dim: int
    block_size: int
    length_conditioning: bool
    unconditional_branch: bool
    default_guidance: float


class HiFiGPTFamily(ModelFamily):
    name = "hifigpt"
    title = "T2M-HiFiGPT: a temporal GPT step and R residual-depth steps per 8 frames, RVQ-VAE decoder"
    fields = HIFIGPT_FIELDS
    optional_fields = OPTIONAL_FIELDS
    encodes = True
    capabilities = Capabilities(continuous_batching=True, early_frames=True, code_depth=True,
                                edits=SEGMENT_EDITS)
    training_kinds: ClassVar[Mapping[str, tuple[str, str]]] = {"hifigpt": ("t2m.families.hifigpt.training",
                                  "train T2M-HiFiGPT's double-tier GPT on a residual VQ's codes")}
    bench_subjects: ClassVar[Mapping[str, tuple[str, str]]] = {"hifigpt-vs-gpt": (
        "t2m.families.hifigpt.bench", "T2M-HiFiGPT vs the GPT at equal width and depth: ms per step and per motion")}
    checkpoint_kinds: ClassVar[Mapping[str, tuple[str, str, str]]] = {
        "hifigpt": ("t2m.families.hifigpt.network", "HiFiGPT", "HiFiGPTConfig")}
    eval_run_option = "hifigpt"
    evaluates_bundle = True
    export_needs_vq = True
    int8_graphs = frozenset({"text", "temporal", "residual"})

    def check_consistency(self, manifest: Mapping[str, Any]) -> None:
        check_block_size(manifest, "hifigpt")

    def required_files(self, manifest: Mapping[str, Any]) -> tuple[str, ...]:
        return (*COMMON_FILES[:2], *HIFIGPT_GRAPHS, *COMMON_FILES[2:])

    def quantizable_graphs(self, manifest: Mapping[str, Any]) -> tuple[str, ...]:
        return HIFIGPT_GRAPHS

    def graphs(self, manifest: Mapping[str, Any]) -> dict[str, GraphSpec]:
        """temporal_step.onnx and residual_step.onnx (each with its own KV cache), decoder.onnx over [B, T, R]."""
        block, dim, depth = manifest["hifigpt"], manifest["text_encoder"]["dim"], manifest["residual_layers"]
        embed = block["n_head"] * block["head_dim"]
        temporal_kv = kv_shape(block["n_layer_temporal"], block)
        residual_kv = kv_shape(block["n_layer_residual"], block)
        temporal_inputs = [TensorSpec("cond", FLOAT32, (None, dim)), TensorSpec("codes", INT64, (None, depth)),
                           TensorSpec("position", INT64, (1,))]
        if block["length_conditioning"]:
            temporal_inputs.append(TensorSpec("length", INT64, (None,)))
        temporal_inputs.append(TensorSpec("past_kv", FLOAT32, temporal_kv))
        return {
            "temporal_step.onnx": GraphSpec(
                inputs=tuple(temporal_inputs),
                outputs=(TensorSpec("context", FLOAT32, (None, embed)), TensorSpec("stop_logit", FLOAT32, (None,)),
                         TensorSpec("present_kv", FLOAT32, temporal_kv))),
            "residual_step.onnx": GraphSpec(
                inputs=(TensorSpec("context", FLOAT32, (None, embed)), TensorSpec("code", INT64, (None,)),
                        TensorSpec("depth", INT64, (1,)), TensorSpec("past_kv", FLOAT32, residual_kv)),
                outputs=(TensorSpec("logits", FLOAT32, (None, manifest["codebook_size"])),
                         TensorSpec("present_kv", FLOAT32, residual_kv))),
            "decoder.onnx": GraphSpec(inputs=(TensorSpec("codes", INT64, (None, None, depth)),),
                                      outputs=features_output(manifest)),
        }

    def settings(self, manifest: Mapping[str, Any]) -> HiFiGPTSettings:
        block = {f.name: manifest["hifigpt"][f.name] for f in fields(HiFiGPTSettings)}
        return HiFiGPTSettings(**{**block, "default_guidance": float(block["default_guidance"])})

    def describe(self, manifest: Any, guidance: float) -> str:
        h = manifest.settings
        return (f"hifigpt: 1 temporal + {manifest.residual_layers} residual steps per {manifest.frames_per_token} "
                f"frames ({h.n_layer_temporal} + {h.n_layer_residual} layers), guidance {guidance:g}")

    def serve(self, bundle: Any) -> Any:
        from t2m.families.hifigpt.served import HiFiGPTCodes

        return HiFiGPTCodes(bundle)

    def add_export_arguments(self, group: argparse._ArgumentGroup) -> None:
        group.add_argument("--hifigpt", type=Path, default=None, metavar="RUN",
                           help="HiFiGPT run directory (family hifigpt; --vq is its residual VQ)")

    def check_export_arguments(self, args: argparse.Namespace) -> None:
        if args.hifigpt is None:
            raise ValueError("--family hifigpt needs --hifigpt RUN")

    def export(self, args: argparse.Namespace, int8: frozenset[str]) -> tuple[dict, dict]:
        from t2m.families.hifigpt.export import export_hifigpt_from_runs

        manifest, checks = export_hifigpt_from_runs(
            args.vq, args.hifigpt, args.output, name=args.name, version=args.version, model_card=args.model_card,
            data_summary=args.data_summary, default_guidance=args.guidance, check_parity=not args.skip_parity,
            int8=int8)
        return manifest, {"parity": checks.parity, "int8": checks.int8}

    def load_eval_models(self, args: argparse.Namespace, mean: Any, std: Any) -> Any:
        from t2m.families.hifigpt.evaluation import load_hifigpt_models

        return load_hifigpt_models(args.evaluator, args.vq, args.hifigpt, mean, std)


FAMILY = HiFiGPTFamily()
