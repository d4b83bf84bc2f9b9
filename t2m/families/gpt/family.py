"""T2M-GPT: one code per step from gpt_step.onnx (KV cache, End token), decoded by a 1D VQ decoder.

The family's code lives in t2m.families.gpt.loop (the loop), t2m.families.gpt.served (served), t2m.families.gpt.export
(export) and t2m.families.gpt.evaluation (`t2m eval --gpt`)."""
from __future__ import annotations

import argparse
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from t2m.bundle.errors import BundleError
from t2m.bundle.family import SEGMENT_EDITS, Capabilities, FieldRule, ModelFamily
from t2m.bundle.graphs import FIXED_STEP_GRAPH, FLOAT32, INT64, GraphSpec, TensorSpec, features_output, kv_shape
from t2m.bundle.manifest import (
    BOOL,
    COMMON_FILES,
    GUIDANCE,
    INTEGER_ABOVE_1,
    MANIFEST_NAME,
    POSITIVE,
    QUANTIZATION,
    check_block_size,
    check_fields,
    is_int,
)

__all__ = ["FAMILY", "GPT_FIELDS", "REQUIRED_FILES", "GptFamily", "GptSettings"]

REQUIRED_FILES = (*COMMON_FILES[:2], "gpt_step.onnx", *COMMON_FILES[2:])
GPT_FIELDS: dict[str, FieldRule] = {
    "end_id": (is_int, "an integer"),
    "gpt.n_layer": POSITIVE,
    "gpt.n_head": POSITIVE,
    "gpt.head_dim": POSITIVE,
    "gpt.block_size": INTEGER_ABOVE_1,
    "gpt.length_conditioning": BOOL,
    "gpt.unconditional_branch": BOOL,
    "gpt.default_guidance": GUIDANCE,
}


@dataclass(frozen=True)
class GptSettings:
    """The `gpt` block: the step graph's sizes and the GPT loop's settings."""

    n_layer: int
    n_head: int
    head_dim: int
    block_size: int
    length_conditioning: bool
    unconditional_branch: bool
    default_guidance: float
    end_id: int


class GptFamily(ModelFamily):
    name = "gpt"
    title = "T2M-GPT: one code per step from a KV-cached GPT, End token, 1D VQ decoder"
    fields = GPT_FIELDS
    encodes = True
    capabilities = Capabilities(continuous_batching=True, early_frames=True, edits=SEGMENT_EDITS)
    training_kinds: ClassVar[Mapping[str, tuple[str, str]]] = {
        "gpt": ("t2m.families.gpt.training", "train the text-to-code GPT on a trained VQ's codes")}
    checkpoint_kinds: ClassVar[Mapping[str, tuple[str, str, str]]] = {
        "gpt": ("t2m.families.gpt.network", "MotionGPT", "GPTConfig")}
    eval_run_option = "gpt"
    evaluates_bundle = True
    export_needs_vq = True
    int8_graphs = frozenset({"text", "gpt"})

    def field_table(self, common: Mapping[str, FieldRule]) -> dict[str, FieldRule]:
        """Format 1's first table, in its order: end_id and the block after the code fields, the step graph's
        quantisation after the text encoder's (so messages come out as they always have)."""
        table: dict[str, FieldRule] = {}
        for path, rule in common.items():
            if path == "text_encoder.kind":
                table.update(GPT_FIELDS)
            if path == "files":
                table["quantization.gpt_step"] = QUANTIZATION
            table[path] = rule
        return table

    def check_consistency(self, manifest: Mapping[str, Any]) -> None:
        if manifest["end_id"] != manifest["codebook_size"]:
            raise BundleError(f"{MANIFEST_NAME}: field 'end_id' is {manifest['end_id']}, expected codebook_size "
                              f"{manifest['codebook_size']} (End is the last logit)")
        check_block_size(manifest, "gpt")
        # gpt_step_fixed.onnx, where a bundle has one, may be converted too (`t2m quantize --scheme fp16`)
        check_fields(manifest, {"quantization.gpt_step_fixed": QUANTIZATION}, required=False)

    def required_files(self, manifest: Mapping[str, Any]) -> tuple[str, ...]:
        return REQUIRED_FILES

    def quantizable_graphs(self, manifest: Mapping[str, Any]) -> tuple[str, ...]:
        return ("gpt_step.onnx",)

    def graphs(self, manifest: Mapping[str, Any]) -> dict[str, GraphSpec]:
        gpt = manifest["gpt"]
        kv = kv_shape(gpt["n_layer"], gpt)
        step_inputs = [TensorSpec("cond", FLOAT32, (None, manifest["text_encoder"]["dim"])),
                       TensorSpec("token", INT64, (None,)), TensorSpec("position", INT64, (1,))]
        if gpt["length_conditioning"]:
            step_inputs.append(TensorSpec("length", INT64, (None,)))
        step_inputs.append(TensorSpec("past_kv", FLOAT32, kv))
        residual = manifest["residual_layers"]
        codes_shape: tuple[int | None, ...] = (None, None) if residual == 1 else (None, None, residual)
        return {
            "gpt_step.onnx": GraphSpec(
                inputs=tuple(step_inputs),
                outputs=(TensorSpec("logits", FLOAT32, (None, manifest["codebook_size"] + 1)),
                         TensorSpec("present_kv", FLOAT32, kv))),
            "decoder.onnx": GraphSpec(inputs=(TensorSpec("codes", INT64, codes_shape),),
                                      outputs=features_output(manifest)),
        }

    def captured_graphs(self, manifest: Mapping[str, Any]) -> dict[str, GraphSpec]:
        """gpt_step_fixed.onnx (`t2m import t2m-gpt --cuda-graph-step`): the step over a cache of block_size
        positions with a position per row (t2m/families/gpt/fixed_cache.py), for CUDA graphs."""
        gpt = manifest["gpt"]
        kv = (gpt["n_layer"], 2, None, gpt["n_head"], gpt["block_size"], gpt["head_dim"])
        inputs = [TensorSpec("cond", FLOAT32, (None, manifest["text_encoder"]["dim"])),
                  TensorSpec("token", INT64, (None,)), TensorSpec("position", INT64, (None,))]
        if gpt["length_conditioning"]:
            inputs.append(TensorSpec("length", INT64, (None,)))
        inputs.append(TensorSpec("past_kv", FLOAT32, kv))
        return {FIXED_STEP_GRAPH: GraphSpec(
            inputs=tuple(inputs), outputs=(TensorSpec("logits", FLOAT32, (None, manifest["codebook_size"] + 1)),
                                           TensorSpec("present_kv", FLOAT32, kv)))}

    def settings(self, manifest: Mapping[str, Any]) -> GptSettings:
        gpt = manifest["gpt"]
        return GptSettings(n_layer=gpt["n_layer"], n_head=gpt["n_head"], head_dim=gpt["head_dim"],
                           block_size=gpt["block_size"], length_conditioning=gpt["length_conditioning"],
                           unconditional_branch=gpt["unconditional_branch"],
                           default_guidance=float(gpt["default_guidance"]), end_id=manifest["end_id"])

    def describe(self, manifest: Any, guidance: float) -> str:
        return f"gpt: 1 code per step, guidance {guidance:g}"

    def check_servable(self, manifest: Any) -> None:
        if manifest.residual_layers != 1:
            raise BundleError(f"manifest.json: field 'residual_layers' is {manifest.residual_layers}; this service "
                              "samples one code per step and serves single-layer bundles only")

    def serve(self, bundle: Any) -> Any:
        from t2m.families.gpt.served import GptCodes

        return GptCodes(bundle)

    def add_export_arguments(self, group: argparse._ArgumentGroup) -> None:
        group.add_argument("--gpt", type=Path, default=None, metavar="RUN", help="GPT run directory (family gpt)")
        group.add_argument("--text-encoder", choices=("minilm", "clip"), default=None,
                           help="family gpt: text encoder (default: the one the GPT run was trained with)")
        group.add_argument("--clip-weights", type=Path, default=None, metavar="PATH",
                           help="family gpt: local CLIP ViT-B/32 weights")

    def check_export_arguments(self, args: argparse.Namespace) -> None:
        if args.gpt is None:
            raise ValueError("--gpt RUN is required (or --family masked with --masked RUN, --family hifigpt with "
                             "--hifigpt RUN)")

    def export(self, args: argparse.Namespace, int8: frozenset[str]) -> tuple[dict, dict]:
        from t2m.families.gpt.export import export_from_runs

        choice = "none" if not int8 else "all" if len(int8) > 1 else next(iter(int8))
        manifest, checks = export_from_runs(
            args.vq, args.gpt, args.output, text_encoder=args.text_encoder, clip_weights=args.clip_weights,
            int8=choice, name=args.name, version=args.version, model_card=args.model_card,
            data_summary=args.data_summary, default_guidance=args.guidance, check_parity=not args.skip_parity)
        return manifest, {"parity": checks.parity, "int8": checks.int8}

    def load_eval_models(self, args: argparse.Namespace, mean: Any, std: Any) -> Any:
        from t2m.families.gpt.evaluation import load_gpt_models

        return load_gpt_models(args.evaluator, args.vq, args.gpt, mean, std)


FAMILY = GptFamily()
