"""The masked family (MoMask / MoGenTS): token maps [rows, C, R] filled by confidence re-masking (masked.onnx) and
one residual pass per layer (residual.onnx), optional further generators ("branches", MoGenTS's 1D tokens) and a
length estimator; not autoregressive, so batches run to their end and frames come once the map is decoded.

The family's code lives in t2m.families.masked.loop (the loop), t2m.families.masked.served (served),
t2m.families.masked.export (export; the MoMask and MoGenTS importers write this family too) and
t2m.families.masked.evaluation (`t2m eval --masked`)."""
from __future__ import annotations

import argparse
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from t2m.bundle.errors import BundleError
from t2m.bundle.family import SEGMENT_EDITS, Capabilities, FieldRule, ModelFamily
from t2m.bundle.graphs import FLOAT32, INT64, GraphSpec, TensorSpec, branch_graphs, features_output
from t2m.bundle.manifest import (
    BOOL,
    GUIDANCE,
    LENGTH_GRAPH,
    MANIFEST_NAME,
    POSITIVE,
    QUANTIZATION,
    check_fields,
    is_int,
    is_number,
    is_optional_positive,
)

__all__ = ["BRANCH_FIELDS", "FAMILY", "MASKED_FIELDS", "BranchSettings", "MaskedFamily", "MaskedSettings",
           "branch_graphs"]

TOP_K: FieldRule = (is_optional_positive, "null or a positive integer")
MASKED_FIELDS: dict[str, FieldRule] = {
    "masked.columns": POSITIVE,
    "masked.steps": POSITIVE,
    "masked.guidance": GUIDANCE,
    "masked.residual_guidance": GUIDANCE,
    "masked.top_k": TOP_K,
    "masked.residual_top_k": TOP_K,
    "masked.mask_id": (is_int, "an integer"),
    "masked.pad_id": (is_int, "an integer"),
    "masked.unconditional_branch": BOOL,
    "masked.length_estimator": BOOL,
}
OPTIONAL_FIELDS: dict[str, FieldRule] = {
    "masked.residual_temperature": (lambda v: is_number(v) and v > 0, "null or a number > 0"),
    "quantization.masked": QUANTIZATION,
    "quantization.residual": QUANTIZATION,
    "masked.temperature": (lambda v: is_number(v) and v > 0, "null or a number > 0"),
    "masked.residual_mask_class": BOOL,
    "masked.branches": (lambda v: isinstance(v, list), "a list of branch objects"),
}
# the optional `masked.branches` list (MoGenTS: its 1D "aux" tokens beside the 2D map): each entry's fields
BRANCH_FIELDS: dict[str, FieldRule] = {
    "name": (lambda v: isinstance(v, str) and v.isidentifier() and v.islower(), "a lower-case identifier"),
    "columns": POSITIVE,
    "codebook_size": POSITIVE,
    **{field: MASKED_FIELDS[f"masked.{field}"] for field in ("top_k", "residual_top_k", "mask_id", "pad_id")},
    "residual_mask_class": BOOL,
}
# MaskedSettings fields `t2m eval --masked` takes from its options
EVAL_OPTIONS = ("steps", "residual_guidance", "residual_top_k")


@dataclass(frozen=True)
class BranchSettings:
    """A `masked.branches` entry: one more token generator on the same rows (its own masked and residual graphs),
    whose map joins the primary one along the columns before decoding."""

    name: str
    columns: int
    codebook_size: int
    top_k: int | None
    residual_top_k: int | None
    mask_id: int
    pad_id: int
    residual_mask_class: bool

    @property
    def graphs(self) -> tuple[str, str]:
        return branch_graphs(self.name)


@dataclass(frozen=True)
class MaskedSettings:
    """The `masked` block: the token map's width and the two stages' decoding settings (t2m.families.masked.loop)."""

    columns: int
    steps: int
    guidance: float
    residual_guidance: float
    top_k: int | None
    residual_top_k: int | None
    mask_id: int
    pad_id: int
    unconditional_branch: bool
    length_estimator: bool
    residual_temperature: float | None = None  # null: the request's temperature (MoMask's imports: 1.0)
    temperature: float | None = None  # null: the request's; MoGenTS's imports: 1 (its sampler ignores temperature)
    residual_mask_class: bool = False  # the residual graph also scores the mask id (MoGenTS's 2D model)
    branches: tuple[BranchSettings, ...] = ()
    length_conditioning: bool = True   # each map's rows are an input of its graphs

    @property
    def default_guidance(self) -> float:
        """A request's default guidance: the mask stage's."""
        return self.guidance

    @property
    def decoder_columns(self) -> int:
        """Columns of the decoder's code map: this block's, then every branch's."""
        return self.columns + sum(branch.columns for branch in self.branches)


def _check_token_ids(block: Mapping[str, Any], where: str, size: int) -> None:
    """mask_id = K (the class after the codes), pad_id = K (the residual stage's "layer unused" class; K + 1 when
    the residual stage also scores the mask class), top-k at most K."""
    pad = size + int(bool(block.get("residual_mask_class")))
    for field, want, what in (("mask_id", size, "codebook_size"), ("pad_id", pad, "codebook_size" if pad == size
                                                                   else "codebook_size + 1 (residual_mask_class)")):
        if block[field] != want:
            raise BundleError(f"{MANIFEST_NAME}: field '{where}.{field}' is {block[field]}, expected {what} {want}")
    for field in ("top_k", "residual_top_k"):
        if block[field] is not None and block[field] > size:
            raise BundleError(f"{MANIFEST_NAME}: field '{where}.{field}' is {block[field]}, more than codebook_size "
                              f"{size}")


def _check_branches(manifest: Mapping[str, Any]) -> None:
    """Each `masked.branches` entry: its fields, its token ids, a name of its own, its graphs listed."""
    names = {"masked"}
    for index, branch in enumerate(manifest["masked"].get("branches") or []):
        where = f"masked.branches.{index}"
        if not isinstance(branch, Mapping):
            raise BundleError(f"{MANIFEST_NAME}: field '{where}' must be an object, got {branch!r}")
        for field, (check, expected) in BRANCH_FIELDS.items():
            if field not in branch:
                raise BundleError(f"{MANIFEST_NAME}: missing field '{where}.{field}'")
            if not check(branch[field]):
                raise BundleError(f"{MANIFEST_NAME}: field '{where}.{field}' must be {expected}, got "
                                  f"{branch[field]!r}")
        if branch["name"] in names:
            raise BundleError(f"{MANIFEST_NAME}: field '{where}.name' {branch['name']!r} is used twice")
        names.add(branch["name"])
        _check_token_ids(branch, where, branch["codebook_size"])


def _token_graphs(files: tuple[str, str], block: Mapping[str, Any], size: int, layers: int,
                  cond: TensorSpec, length: TensorSpec) -> dict[str, GraphSpec]:
    """One generator's masked graph and (R > 1) residual graph: K logits, and K + 1 (K + 2 with the mask class)."""
    columns = block["columns"]
    graphs = {files[0]: GraphSpec(
        inputs=(TensorSpec("tokens", INT64, (None, None, columns)), cond, length),
        outputs=(TensorSpec("logits", FLOAT32, (None, None, columns, size)),))}
    if layers > 1:
        classes = size + 1 + int(bool(block.get("residual_mask_class")))
        graphs[files[1]] = GraphSpec(
            inputs=(TensorSpec("codes", INT64, (None, None, columns, layers)), TensorSpec("layer", INT64, (None,)),
                    cond, length),
            outputs=(TensorSpec("logits", FLOAT32, (None, None, columns, classes)),))
    return graphs


class MaskedFamily(ModelFamily):
    name = "masked"
    title = "MoMask / MoGenTS: token maps by confidence re-masking + residual passes, batches run to their end"
    fields = MASKED_FIELDS
    optional_fields = OPTIONAL_FIELDS
    encodes = True
    capabilities = Capabilities(why_not_early="the whole token map exists only at the end (masked family)",
                                edits=SEGMENT_EDITS | {"in_between"}, inpaints=True)
    training_kinds: ClassVar[Mapping[str, tuple[str, str]]] = {
        "joint-vq": ("t2m.model.training.train_joint_vq", "train the 2D joint VQ-VAE (time x joint token maps)"),
        "masked": ("t2m.families.masked.train_masked", "train the masked transformer on a VQ's first-layer codes"),
        "residual": ("t2m.families.masked.train_residual", "train the residual transformer on a VQ's later layers"),
        "length": ("t2m.families.masked.train_length", "train the length estimator (free length for masked models)"),
    }
    checkpoint_kinds: ClassVar[Mapping[str, tuple[str, str, str]]] = {
        "joint_vq": ("t2m.model.networks.joint_vqvae", "JointVQVAE", "JointVQConfig"),
        "masked": ("t2m.families.masked.masked_transformer", "MaskedTransformer", "TokenTransformerConfig"),
        "residual": ("t2m.families.masked.residual_transformer", "ResidualTransformer", "TokenTransformerConfig"),
        "length": ("t2m.families.masked.length_estimator", "LengthEstimator", "LengthEstimatorConfig"),
    }
    eval_run_option = "masked"
    default_eval_guidance = (1.0, 4.0)
    export_needs_vq = True
    int8_graphs = frozenset({"text", "masked", "residual"})

    def check_consistency(self, manifest: Mapping[str, Any]) -> None:
        masked = manifest["masked"]
        _check_token_ids(masked, "masked", manifest["codebook_size"])
        _check_branches(manifest)
        # each branch's graphs may be quantised too: `quantization.masked_<name>`, `quantization.residual_<name>`
        check_fields(manifest, {f"quantization.{Path(graph).stem}": QUANTIZATION
                                for branch in masked.get("branches") or [] if isinstance(branch, Mapping)
                                for graph in branch_graphs(str(branch.get("name")))}, required=False)
        if masked["length_estimator"] and LENGTH_GRAPH not in manifest["files"]:
            raise BundleError(f"{MANIFEST_NAME}: field 'masked.length_estimator' is true but 'files' does not list "
                              f"{LENGTH_GRAPH!r}")

    def required_files(self, manifest: Mapping[str, Any]) -> tuple[str, ...]:
        """The graphs of every generator (residual ones only with more than one quantiser layer), length.onnx only
        with a length estimator."""
        masked = manifest["masked"]
        names = ["text_encoder.onnx", "tokenizer.json", "masked.onnx"]
        if manifest["residual_layers"] > 1:
            names.append("residual.onnx")
        for branch in masked.get("branches") or []:
            graphs = branch_graphs(branch["name"])
            names += graphs if manifest["residual_layers"] > 1 else graphs[:1]
        if masked["length_estimator"]:
            names.append(LENGTH_GRAPH)
        return (*names, "decoder.onnx", "mean.npy", "std.npy", "MODEL_CARD.md")

    def quantizable_graphs(self, manifest: Mapping[str, Any]) -> tuple[str, ...]:
        """Every generator's token graphs (masked.onnx, residual.onnx, each branch's pair); not length.onnx (a small
        MLP run once per request) nor the decoder."""
        return tuple(name for name in self.required_files(manifest)
                     if name.endswith(".onnx") and name.startswith(("masked", "residual")))

    def replayable_graphs(self, manifest: Mapping[str, Any]) -> tuple[str, ...]:
        """The token graphs: each mask pass and each residual pass of a batch calls them with the same shapes."""
        return self.quantizable_graphs(manifest)

    def graphs(self, manifest: Mapping[str, Any]) -> dict[str, GraphSpec]:
        """masked.onnx, residual.onnx (R > 1), each branch's pair, length.onnx (with an estimator), decoder.onnx over
        [B, T, C, R] maps (C: the primary columns plus every branch's)."""
        masked, dim = manifest["masked"], manifest["text_encoder"]["dim"]
        layers, branches = manifest["residual_layers"], masked.get("branches") or []
        cond, length = TensorSpec("cond", FLOAT32, (None, dim)), TensorSpec("length", INT64, (None,))
        graphs = _token_graphs(("masked.onnx", "residual.onnx"), masked, manifest["codebook_size"], layers, cond,
                               length)
        for branch in branches:
            graphs.update(_token_graphs(branch_graphs(branch["name"]), branch, branch["codebook_size"], layers,
                                        cond, length))
        if masked["length_estimator"]:
            graphs[LENGTH_GRAPH] = GraphSpec(
                inputs=(cond,), outputs=(TensorSpec("logits", FLOAT32, (None, manifest["max_tokens"] + 1)),))
        columns = masked["columns"] + sum(branch["columns"] for branch in branches)
        graphs["decoder.onnx"] = GraphSpec(inputs=(TensorSpec("codes", INT64, (None, None, columns, layers)),),
                                           outputs=features_output(manifest))
        return graphs

    def settings(self, manifest: Mapping[str, Any]) -> MaskedSettings:
        m = manifest["masked"]
        return MaskedSettings(
            columns=m["columns"], steps=m["steps"], guidance=float(m["guidance"]),
            residual_guidance=float(m["residual_guidance"]), top_k=m["top_k"], residual_top_k=m["residual_top_k"],
            mask_id=m["mask_id"], pad_id=m["pad_id"], unconditional_branch=m["unconditional_branch"],
            length_estimator=m["length_estimator"],
            residual_temperature=(None if m.get("residual_temperature") is None
                                  else float(m["residual_temperature"])),
            temperature=None if m.get("temperature") is None else float(m["temperature"]),
            residual_mask_class=bool(m.get("residual_mask_class", False)),
            branches=tuple(BranchSettings(**{key: b[key] for key in BRANCH_FIELDS}) for b in m.get("branches") or []))

    def describe(self, manifest: Any, guidance: float) -> str:
        m = manifest.settings
        branches = "".join(f", + branch {b.name} (top-k {b.top_k} / {b.residual_top_k})" for b in m.branches)
        return (f"masked: {m.columns} column(s) x {manifest.residual_layers} layers, {m.steps} steps, guidance "
                f"{m.guidance:g} / residual {m.residual_guidance:g}, top-k {m.top_k} / {m.residual_top_k}{branches}, "
                f"length estimator {'yes' if m.length_estimator else 'no'}")

    def capabilities_of(self, manifest: Any) -> Capabilities:
        """Edits fill the edited tokens by inpainting; `body_part` too where the map's columns are joint groups (a
        joint-token map: t2m.runtime.body_parts), not for MoMask's one column."""
        from dataclasses import replace

        from t2m.motion.skeleton import get_skeleton
        from t2m.runtime.body_parts import part_columns

        if not part_columns(get_skeleton(manifest.skeleton).joint_names, manifest.settings.columns):
            return self.capabilities
        return replace(self.capabilities, edits=self.capabilities.edits | {"body_part"})

    def serve(self, bundle: Any) -> Any:
        from t2m.families.masked.served import MaskedCodes

        return MaskedCodes(bundle)

    def add_export_arguments(self, group: argparse._ArgumentGroup) -> None:
        group.add_argument("--masked", type=Path, default=None, metavar="RUN",
                           help="masked run directory (family masked)")
        group.add_argument("--residual", type=Path, default=None, metavar="RUN",
                           help="residual run directory (family masked, a VQ with more than one layer)")
        group.add_argument("--length", type=Path, default=None, metavar="RUN",
                           help="length estimator run directory (family masked, optional: null durations)")
        group.add_argument("--steps", type=int, default=None, help="family masked: re-masking steps (default 10)")
        group.add_argument("--residual-guidance", type=float, default=None,
                           help="family masked: the residual stage's guidance scale (default 5.0)")
        group.add_argument("--top-k", type=int, default=None, metavar="K",
                           help="family masked: sample the mask stage from the K likeliest codes (MoMask's and "
                                "MoGenTS's eval: 10%% of the codebook; default: all codes)")
        group.add_argument("--residual-top-k", type=int, default=None, metavar="K",
                           help="family masked: the residual stage's top-k (default: all codes)")

    def check_export_arguments(self, args: argparse.Namespace) -> None:
        if args.masked is None:
            raise ValueError("--family masked needs --masked RUN")
        if args.steps is not None and args.steps < 1:
            raise ValueError(f"--steps must be >= 1, got {args.steps}")
        if args.residual_guidance is not None and args.residual_guidance < 0:
            raise ValueError(f"--residual-guidance must be >= 0, got {args.residual_guidance}")
        for option, value in (("--top-k", args.top_k), ("--residual-top-k", args.residual_top_k)):
            if value is not None and value < 1:
                raise ValueError(f"{option} must be >= 1, got {value}")

    def export(self, args: argparse.Namespace, int8: frozenset[str]) -> tuple[dict, dict]:
        from t2m.families.masked.export import MaskedDecoding, export_masked_from_runs

        decoding = MaskedDecoding(steps=10 if args.steps is None else args.steps,
                                  guidance=4.0 if args.guidance is None else args.guidance,
                                  residual_guidance=5.0 if args.residual_guidance is None else args.residual_guidance,
                                  top_k=args.top_k, residual_top_k=args.residual_top_k)
        manifest, checks = export_masked_from_runs(
            args.vq, args.masked, args.output, residual_run=args.residual, length_run=args.length, name=args.name,
            version=args.version, model_card=args.model_card, data_summary=args.data_summary, decoding=decoding,
            check_parity=not args.skip_parity, int8=int8)
        return manifest, {"parity": checks.parity, "int8": checks.int8}

    def add_eval_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--residual", default=None,
                            help="masked family: residual transformer run (without it only the first quantiser "
                                 "layer is generated)")
        parser.add_argument("--length", default=None,
                            help="masked family: length estimator run; adds rows generated at its estimated lengths")
        parser.add_argument("--steps", type=int, default=None, help="masked family: re-masking steps (default 10)")
        parser.add_argument("--residual-guidance", type=float, default=None,
                            help="masked family: the residual stage's guidance scale (default 5, MoMask's)")
        parser.add_argument("--residual-top-k", type=int, default=None,
                            help="masked family: the residual stage's top-k (default: all codes)")

    def check_eval_arguments(self, args: argparse.Namespace) -> None:
        if args.steps is not None and args.steps < 1:
            raise ValueError(f"--steps must be at least 1, got {args.steps}")
        if args.residual_top_k is not None and args.residual_top_k < 1:
            raise ValueError(f"--residual-top-k must be at least 1, got {args.residual_top_k}")
        if args.residual_guidance is not None and args.residual_guidance < 0:
            raise ValueError(f"--residual-guidance must be >= 0, got {args.residual_guidance}")

    def load_eval_models(self, args: argparse.Namespace, mean: Any, std: Any) -> Any:
        from t2m.families.masked.evaluation import MaskedSettings as EvalSettings
        from t2m.families.masked.evaluation import load_masked_models

        settings = EvalSettings(**{name: getattr(args, name) for name in EVAL_OPTIONS
                                   if getattr(args, name) is not None})
        return load_masked_models(args.evaluator, args.vq, args.masked, args.residual, args.length, settings, mean,
                                  std)


FAMILY = MaskedFamily()
