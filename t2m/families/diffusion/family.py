"""The diffusion family (MDM, DiP): an x0-predicting transformer denoised by DDPM ancestral sampling, one
denoiser.onnx call per diffusion step; the model makes HumanML3D feature frames itself, so the family's "codes" are
normalised frames (frames_per_token 1) and its decoder.onnx only de-normalises them (x * std + mean).

- MDM (`pred_len` 0, arch trans_enc): each sentence is a whole motion of at most max_tokens (196) frames; the
  sentences are joined by MDM's own in-betweening over a window at each join (`join_frames`, `join_context`).
- DiP (`pred_len` 40 after `context_len` 20 clean frames, arch trans_dec over text-token states): sentence after
  sentence, each segment its own calls, frames final call by call (early frames); the first call continues a
  standing pose stored in the bundle (`prefix`).

The family's code lives in t2m.families.diffusion.loop (the loop), t2m.families.diffusion.served (served) and
t2m.families.diffusion.export (export; the importers write this format). t2m/families/diffusion/README.md describes the
bundle.
"""
from __future__ import annotations

import argparse
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from t2m.bundle.errors import BundleError
from t2m.bundle.family import Capabilities, FieldRule, ModelFamily
from t2m.bundle.graphs import FLOAT32, INT64, GraphSpec, TensorSpec, features_output
from t2m.bundle.manifest import BOOL, COMMON_FILES, GUIDANCE, MANIFEST_NAME, QUANTIZATION, is_int, is_str

__all__ = ["ARCHS", "DENOISER_GRAPH", "DIFFUSION_FIELDS", "FAMILY", "TEXT_CONDITIONING", "DiffusionFamily",
           "DiffusionSettings"]

DENOISER_GRAPH = "denoiser.onnx"
ARCHS = ("trans_enc", "trans_dec")
TEXT_CONDITIONING = ("pooled", "tokens")
BOOL_DTYPE = "bool"
NON_NEGATIVE: FieldRule = (lambda v: is_int(v) and v >= 0, "an integer >= 0")
DIFFUSION_FIELDS: dict[str, FieldRule] = {
    "diffusion.arch": (lambda v: v in ARCHS, f"one of {list(ARCHS)}"),
    "diffusion.steps": (lambda v: is_int(v) and v >= 2, "an integer >= 2 (the trained diffusion steps)"),
    "diffusion.default_guidance": GUIDANCE,
    "diffusion.unconditional_branch": BOOL,
    "diffusion.text_conditioning": (lambda v: v in TEXT_CONDITIONING, f"one of {list(TEXT_CONDITIONING)}"),
    "diffusion.mask_frames": BOOL,
    "diffusion.context_len": NON_NEGATIVE,
    "diffusion.pred_len": NON_NEGATIVE,
    "diffusion.join_frames": NON_NEGATIVE,
    "diffusion.join_context": NON_NEGATIVE,
}
OPTIONAL_FIELDS: dict[str, FieldRule] = {
    "diffusion.prefix": (is_str, "null or the name of the prefix file, such as 'prefix.npy'"),
    "diffusion.crossfade": NON_NEGATIVE,
    "quantization.denoiser": QUANTIZATION,
}
# POST /edit's kinds both MDM and DiP make (service/diffusion_edits.py)
DIFFUSION_EDITS = frozenset({"regenerate", "append", "prepend", "in_between", "body_part"})
# the common fields whose meaning is fixed here: the "codes" are the frames themselves
FIXED_COMMON = {"frames_per_token": 1, "codebook_size": 1, "residual_layers": 1}


@dataclass(frozen=True)
class DiffusionSettings:
    """The `diffusion` block (t2m/families/diffusion/README.md)."""

    arch: str
    steps: int
    default_guidance: float
    unconditional_branch: bool
    text_conditioning: str
    mask_frames: bool
    context_len: int
    pred_len: int
    join_frames: int
    join_context: int
    prefix: str | None = None
    crossfade: int = 0                  # DiP: frames a later sentence's first call cross-fades its text over
    length_conditioning: bool = False   # lengths are the motion's own (x_t's frames), not a token-graph input

    @property
    def chained(self) -> bool:
        """DiP: calls of pred_len frames after context_len clean ones, sentence after sentence."""
        return self.pred_len > 0

    @property
    def tokens(self) -> bool:
        """The text condition is token states + mask (DiP's DistilBERT), not one pooled vector (MDM's CLIP)."""
        return self.text_conditioning == "tokens"


class DiffusionFamily(ModelFamily):
    name = "diffusion"
    title = ("MDM / DiP: an x0-predicting transformer, DDPM steps over denoiser.onnx; MDM whole motions joined by "
             "in-betweening, DiP 40-frame calls sentence after sentence")
    fields = DIFFUSION_FIELDS
    optional_fields = OPTIONAL_FIELDS
    # what every bundle of the family can do; a bundle's own answer is capabilities_of(manifest)
    capabilities = Capabilities(why_not_early="an MDM motion exists only after its last diffusion step (and its "
                                              "joins are in-betweened after that)")
    training_kinds: ClassVar[Mapping[str, tuple[str, str]]] = {
        "dip": ("t2m.families.diffusion.train_dip", "train a small DiP (MiniLM token states) on a dataset")}
    checkpoint_kinds: ClassVar[Mapping[str, tuple[str, str, str]]] = {
        "dip": ("t2m.families.diffusion.network", "AveragedMDM", "DiffusionConfig")}
    eval_subjects: ClassVar[Mapping[str, tuple[str, str]]] = {"diffusion-joins": (
        "t2m.families.diffusion.join_quality", "MDM's joins with and without its in-between pass")}

    evaluates_bundle = True   # `t2m eval --bundle`: frames of exact lengths, streams as served
    bundle_evaluation = "t2m.families.diffusion.evaluation:diffusion_bundle_models"
    int8_graphs = frozenset({"text"})   # `t2m export --int8 text` (a trained run's MiniLM token-state graph)
    # a request is 50-1000 denoiser calls (MDM) where a token model makes ~50 smaller ones, and parity serves it
    # three times (the original, its quantised twin on the same feeds, the copy): two requests of 2 s
    quantize_parity = (2, 2.0)

    def capabilities_of(self, manifest: Any) -> Capabilities:
        """DiP streams call by call (each call's frames are final: later calls only read them); MDM's whole motions
        do not. Both edit by their loop's known-value inpainting (MDM's editing modes; DiP's calls with known frames
        at their end): every edit kind (service/diffusion_edits.py), their answers' handles recipes."""
        if manifest.settings.chained:
            return Capabilities(early_frames=True, edits=DIFFUSION_EDITS, inpaints=True)
        return Capabilities(edits=DIFFUSION_EDITS, inpaints=True, why_not_early=self.capabilities.why_not_early)

    def check_consistency(self, manifest: Mapping[str, Any]) -> None:
        for field, value in FIXED_COMMON.items():
            if manifest[field] != value:
                raise BundleError(f"{MANIFEST_NAME}: field '{field}' is {manifest[field]}, expected {value} (the "
                                  "diffusion family's codes are its normalised feature frames)")
        block = manifest["diffusion"]
        if block["text_conditioning"] == "tokens" and block["arch"] != "trans_dec":
            raise BundleError(f"{MANIFEST_NAME}: field 'diffusion.text_conditioning' is 'tokens' but "
                              f"'diffusion.arch' is {block['arch']!r} (token states need trans_dec's memory)")
        chained = block["pred_len"] > 0
        if chained != (block["context_len"] > 0):
            raise BundleError(f"{MANIFEST_NAME}: fields 'diffusion.context_len' ({block['context_len']}) and "
                              f"'diffusion.pred_len' ({block['pred_len']}) must both be 0 (whole motions) or both "
                              "positive (DiP's calls)")
        prefix = block.get("prefix")
        if chained and prefix is None:
            raise BundleError(f"{MANIFEST_NAME}: field 'diffusion.prefix' must name the first call's prefix file "
                              "when 'diffusion.pred_len' is positive")
        if not chained and prefix is not None:
            raise BundleError(f"{MANIFEST_NAME}: field 'diffusion.prefix' must be null for whole motions "
                              "('diffusion.pred_len' 0)")
        if prefix is not None and prefix not in manifest["files"]:
            raise BundleError(f"{MANIFEST_NAME}: field 'files' does not list the prefix {prefix!r}")
        fade = block.get("crossfade", 0)
        if fade > block["pred_len"]:
            raise BundleError(f"{MANIFEST_NAME}: field 'diffusion.crossfade' ({fade}) must be at most "
                              f"'diffusion.pred_len' ({block['pred_len']}): it fades in within one call (0 for "
                              "whole motions)")

    def required_files(self, manifest: Mapping[str, Any]) -> tuple[str, ...]:
        prefix = manifest["diffusion"].get("prefix")
        return (*COMMON_FILES[:2], DENOISER_GRAPH, *COMMON_FILES[2:], *([prefix] if prefix else []))

    def graphs(self, manifest: Mapping[str, Any]) -> dict[str, GraphSpec]:
        """denoiser.onnx (one diffusion step of a batch), decoder.onnx (de-normalisation) and, for token states,
        the text graph's own signature (it replaces the common pooled one)."""
        block, features = manifest["diffusion"], manifest["feature_dim"]
        dim = manifest["text_encoder"]["dim"]
        frames = TensorSpec("x_t", FLOAT32, (None, None, features))
        inputs = [frames, TensorSpec("t", INT64, (None,))]
        graphs: dict[str, GraphSpec] = {}
        if block["text_conditioning"] == "tokens":
            inputs += [TensorSpec("text", FLOAT32, (None, None, dim)), TensorSpec("text_mask", BOOL_DTYPE,
                                                                                   (None, None))]
            graphs["text_encoder.onnx"] = GraphSpec(
                inputs=(TensorSpec("input_ids", INT64, (None, None)), TensorSpec("attention_mask", INT64,
                                                                                  (None, None))),
                outputs=(TensorSpec("token_states", FLOAT32, (None, None, dim)),))
        else:
            inputs.append(TensorSpec("text", FLOAT32, (None, dim)))
        if block["mask_frames"]:
            inputs.append(TensorSpec("length", INT64, (None,)))
        if block["pred_len"] > 0:
            inputs.append(TensorSpec("prefix", FLOAT32, (None, block["context_len"], features)))
        graphs[DENOISER_GRAPH] = GraphSpec(inputs=tuple(inputs),
                                           outputs=(TensorSpec("x0", FLOAT32, (None, None, features)),))
        graphs["decoder.onnx"] = GraphSpec(inputs=(TensorSpec("motion", FLOAT32, (None, None, features)),),
                                           outputs=features_output(manifest))
        return graphs

    def settings(self, manifest: Mapping[str, Any]) -> DiffusionSettings:
        block = manifest["diffusion"]
        return DiffusionSettings(
            arch=block["arch"], steps=block["steps"], default_guidance=float(block["default_guidance"]),
            unconditional_branch=block["unconditional_branch"], text_conditioning=block["text_conditioning"],
            mask_frames=block["mask_frames"], context_len=block["context_len"], pred_len=block["pred_len"],
            join_frames=block["join_frames"], join_context=block["join_context"], prefix=block.get("prefix"),
            crossfade=block.get("crossfade", 0))

    def describe(self, manifest: Any, guidance: float) -> str:
        s = manifest.settings
        fade = f", texts cross-faded over {s.crossfade} frames at joins" if s.crossfade else ""
        how = (f"{s.pred_len}-frame calls after {s.context_len} frames{fade}" if s.chained
               else f"whole motions, joins in-betweened over {s.join_frames} + {s.join_context} frames a side")
        return f"diffusion: {s.arch}, {s.steps} steps, {s.text_conditioning} text, {how}, guidance {guidance:g}"

    def quantizable_graphs(self, manifest: Mapping[str, Any]) -> tuple[str, ...]:
        """The denoiser: called at every diffusion step (`t2m quantize`, `t2m import mdm|dip --quantize`)."""
        return (DENOISER_GRAPH,)

    def replayable_graphs(self, manifest: Mapping[str, Any]) -> tuple[str, ...]:
        """The denoiser: a request's diffusion steps (50-1000 for MDM, 10 per DiP window) call it with the same
        shapes, and it has no cache."""
        return (DENOISER_GRAPH,)

    def serve(self, bundle: Any) -> Any:
        from t2m.families.diffusion.served import DiffusionCodes

        return DiffusionCodes(bundle)

    def add_export_arguments(self, group: argparse._ArgumentGroup) -> None:
        group.add_argument("--diffusion-run", type=Path, default=None, metavar="RUN",
                           help="family diffusion: a `t2m train dip` run (its EMA weights, MiniLM token states)")
        group.add_argument("--diffusion-random", choices=("mdm", "dip"), default=None,
                           help="family diffusion: a tiny random-weight MDM or DiP bundle (plumbing tests); released "
                                "models come from `t2m import mdm|dip`")
        group.add_argument("--diffusion-seed", type=int, default=None, metavar="N",
                           help="family diffusion: seed of the random weights (default 0)")
        group.add_argument("--crossfade", type=int, default=0, metavar="FRAMES",
                           help="family diffusion, a DiP run: the first call of each sentence after the first "
                                "cross-fades from the previous sentence's text to its own over FRAMES frames "
                                "(default 0: the official switch, whose joins are near cuts)")

    def check_export_arguments(self, args: argparse.Namespace) -> None:
        if (args.diffusion_random is None) == (args.diffusion_run is None):
            raise ValueError("--family diffusion exports a trained run (--diffusion-run RUN, from `t2m train dip`) "
                             "or a tiny random-weight bundle (--diffusion-random mdm|dip), one of the two; import a "
                             "released MDM or DiP with `t2m import mdm|dip`")
        if args.crossfade and args.diffusion_run is None:
            raise ValueError(f"--crossfade {args.crossfade}: for a trained DiP run (--diffusion-run RUN)")
        if args.crossfade < 0:
            raise ValueError(f"--crossfade must be 0 or more frames, got {args.crossfade}")
        if args.diffusion_random is not None and args.int8 != "none":
            raise ValueError(f"--int8 {args.int8}: quantises a trained run's text graph (--diffusion-run RUN); the "
                             "random bundles keep float32 graphs")

    def export(self, args: argparse.Namespace, int8: frozenset[str]) -> tuple[dict, dict]:
        if args.diffusion_run is not None:
            from t2m.families.diffusion.export import export_dip_from_run

            return export_dip_from_run(args.diffusion_run, args.output, name=args.name, version=args.version,
                                       default_guidance=args.guidance, model_card=args.model_card,
                                       data_summary=args.data_summary, check_parity=not args.skip_parity,
                                       int8_text="text" in int8, crossfade=args.crossfade)
        from t2m.families.diffusion.random_bundle import build_random_diffusion_bundle

        manifest = build_random_diffusion_bundle(
            Path(args.output), arch=args.diffusion_random, seed=args.diffusion_seed or 0,
            name=args.name or f"t2m-random-{args.diffusion_random}", version=args.version or "0.0.0")
        return manifest, {"parity": "not checked (random weights)", "int8": {}}


FAMILY = DiffusionFamily()
