"""manifest.json: its fields, their types and consistency rules, and the typed view the loaders use.

One table (`MANIFEST_FIELDS`) says what every field must be; `check_manifest_fields` applies it to the raw JSON and
`parse_manifest` turns checked JSON into a `Manifest`. Optional fields have defaults that keep older bundles valid:
`family` ("gpt", the only family of format 1's first bundles) and `caption_index` (null: the bundle carries no
index of its training captions, e.g. an imported release).

Each family has its own table: the common fields plus its block (`gpt`, `masked` for MoMask / MoGenTS token maps, or
`hifigpt` for T2M-HiFiGPT's double-tier GPT over residual codes),
so a GPT manifest is checked, field by field and message by message, exactly as before the masked family existed.
"""
from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from t2m.bundle.errors import BundleError

__all__ = [
    "BRANCH_FIELDS",
    "FAMILIES",
    "FAMILY_FIELDS",
    "FORMAT_VERSION",
    "HIFIGPT_FIELDS",
    "LENGTH_GRAPH",
    "MANIFEST_FIELDS",
    "MANIFEST_NAME",
    "MASKED_FIELDS",
    "OPTIONAL_FILES",
    "REQUIRED_FILES",
    "BranchSettings",
    "CaptionIndexInfo",
    "GptSettings",
    "HiFiGPTSettings",
    "Manifest",
    "MaskedSettings",
    "branch_graphs",
    "check_manifest_fields",
    "family_of",
    "parse_manifest",
    "read_manifest",
    "read_manifest_dict",
    "required_files",
]

FORMAT_VERSION = 1
MANIFEST_NAME = "manifest.json"
REQUIRED_FILES = ("text_encoder.onnx", "tokenizer.json", "gpt_step.onnx", "decoder.onnx", "mean.npy", "std.npy",
                  "MODEL_CARD.md")
CAPTION_INDEX_FILE = "caption_index.npz"
LENGTH_GRAPH = "length.onnx"
OPTIONAL_FILES = (CAPTION_INDEX_FILE, LENGTH_GRAPH)
FAMILIES = ("gpt", "masked", "hifigpt")
COMMON_FILES = ("text_encoder.onnx", "tokenizer.json", "decoder.onnx", "mean.npy", "std.npy", "MODEL_CARD.md")


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_positive_int(value: Any) -> bool:
    return _is_int(value) and value > 0


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _is_str(value: Any) -> bool:
    return isinstance(value, str) and value != ""


def _is_bool(value: Any) -> bool:
    return isinstance(value, bool)


def _is_optional_str(value: Any) -> bool:
    return value is None or _is_str(value)


def _is_optional_positive(value: Any) -> bool:
    return value is None or _is_positive_int(value)


Check = Callable[[Any], bool]
POSITIVE = (_is_positive_int, "a positive integer")
# field path -> (check, what it must be); every field is required. The GPT family's table (format 1's first).
MANIFEST_FIELDS: dict[str, tuple[Check, str]] = {
    "format_version": (lambda v: v == FORMAT_VERSION, f"the integer {FORMAT_VERSION}"),
    "name": (_is_str, "a non-empty string"),
    "version": (_is_str, "a non-empty string"),
    "fps": POSITIVE,
    "skeleton": (_is_str, "a skeleton name such as 'smpl22'"),
    "num_joints": POSITIVE,
    "feature_dim": POSITIVE,
    "frames_per_token": POSITIVE,
    "max_tokens": POSITIVE,
    "codebook_size": POSITIVE,
    "residual_layers": POSITIVE,
    "end_id": (_is_int, "an integer"),
    "gpt.n_layer": POSITIVE,
    "gpt.n_head": POSITIVE,
    "gpt.head_dim": POSITIVE,
    "gpt.block_size": (lambda v: _is_int(v) and v > 1, "an integer > 1"),
    "gpt.length_conditioning": (_is_bool, "true or false"),
    "gpt.unconditional_branch": (_is_bool, "true or false"),
    "gpt.default_guidance": (lambda v: _is_number(v) and v >= 0, "a number >= 0"),
    "text_encoder.kind": (_is_str, "a string such as 'minilm' or 'clip'"),
    "text_encoder.dim": POSITIVE,
    "text_encoder.max_length": (lambda v: _is_int(v) and v > 1, "an integer > 1"),
    "text_encoder.pooling": (_is_str, "a string such as 'mean' or 'eot'"),
    "text_encoder.normalize": (_is_bool, "true or false"),
    "text_encoder.null_condition": (lambda v: v == "zeros", "'zeros'"),
    "training_data.name": (_is_str, "a non-empty string"),
    "training_data.license": (_is_str, "a non-empty string"),
    "training_data.attribution": (lambda v: isinstance(v, str), "a string"),
    "license": (_is_str, "a non-empty string"),
    "quantization.text_encoder": (_is_optional_str, "null or a string such as 'int8-dynamic'"),
    "quantization.gpt_step": (_is_optional_str, "null or a string such as 'int8-dynamic'"),
    "files": (lambda v: isinstance(v, dict) and bool(v), "an object {file name: {sha256, bytes}}"),
}
_GPT_ONLY = ("end_id", "quantization.gpt_step")
COMMON_FIELDS = {path: rule for path, rule in MANIFEST_FIELDS.items()
                 if not path.startswith("gpt.") and path not in _GPT_ONLY}
_GUIDANCE = (lambda v: _is_number(v) and v >= 0, "a number >= 0")
_TOP_K = (_is_optional_positive, "null or a positive integer")
# the masked family (t2m.decoding.masked): token maps of `columns` tokens a row, mask stage then residual layers
MASKED_FIELDS: dict[str, tuple[Check, str]] = {
    **{path: rule for path, rule in COMMON_FIELDS.items() if path != "files"},
    "masked.columns": POSITIVE,
    "masked.steps": POSITIVE,
    "masked.guidance": _GUIDANCE,
    "masked.residual_guidance": _GUIDANCE,
    "masked.top_k": _TOP_K,
    "masked.residual_top_k": _TOP_K,
    "masked.mask_id": (_is_int, "an integer"),
    "masked.pad_id": (_is_int, "an integer"),
    "masked.unconditional_branch": (_is_bool, "true or false"),
    "masked.length_estimator": (_is_bool, "true or false"),
    "files": COMMON_FIELDS["files"],
}
# T2M-HiFiGPT (t2m.decoding.hifigpt): a temporal step graph and a residual step graph, each with its KV cache
HIFIGPT_FIELDS: dict[str, tuple[Check, str]] = {
    **{path: rule for path, rule in COMMON_FIELDS.items() if path != "files"},
    "hifigpt.n_layer_temporal": POSITIVE,
    "hifigpt.n_layer_residual": POSITIVE,
    "hifigpt.n_head": POSITIVE,
    "hifigpt.head_dim": POSITIVE,
    "hifigpt.block_size": MANIFEST_FIELDS["gpt.block_size"],
    "hifigpt.length_conditioning": (_is_bool, "true or false"),
    "hifigpt.unconditional_branch": (_is_bool, "true or false"),
    "hifigpt.default_guidance": _GUIDANCE,
    "files": COMMON_FIELDS["files"],
}
FAMILY_FIELDS: dict[str, dict[str, tuple[Check, str]]] = {"gpt": MANIFEST_FIELDS, "masked": MASKED_FIELDS,
                                                          "hifigpt": HIFIGPT_FIELDS}
HIFIGPT_GRAPHS = ("temporal_step.onnx", "residual_step.onnx")
# optional fields: path -> (check, what it must be)
OPTIONAL_FIELDS: dict[str, tuple[Check, str]] = {
    "family": (lambda v: v in FAMILIES, f"one of {list(FAMILIES)}"),
    "masked.residual_temperature": (lambda v: _is_number(v) and v > 0, "null or a number > 0"),
    "quantization.masked": (_is_optional_str, "null or a string such as 'int8-dynamic'"),
    "quantization.residual": (_is_optional_str, "null or a string such as 'int8-dynamic'"),
    "quantization.temporal_step": (_is_optional_str, "null or a string such as 'int8-dynamic'"),
    "quantization.residual_step": (_is_optional_str, "null or a string such as 'int8-dynamic'"),
    "masked.temperature": (lambda v: _is_number(v) and v > 0, "null or a number > 0"),
    "masked.residual_mask_class": (_is_bool, "true or false"),
    "masked.branches": (lambda v: isinstance(v, list), "a list of branch objects"),
    "caption_index": (lambda v: v is None or isinstance(v, dict), "null or an object"),
    "caption_index.file": (lambda v: v == CAPTION_INDEX_FILE, f"'{CAPTION_INDEX_FILE}'"),
    "caption_index.count": POSITIVE,
    "caption_index.threshold": (lambda v: _is_number(v) and -1 <= v <= 1, "a cosine similarity in [-1, 1]"),
}
# the optional `masked.branches` list (MoGenTS: its 1D "aux" tokens beside the 2D map): each entry's fields
BRANCH_FIELDS: dict[str, tuple[Check, str]] = {
    "name": (lambda v: isinstance(v, str) and v.isidentifier() and v.islower(), "a lower-case identifier"),
    "columns": POSITIVE,
    "codebook_size": POSITIVE,
    **{field: MASKED_FIELDS[f"masked.{field}"] for field in ("top_k", "residual_top_k", "mask_id", "pad_id")},
    "residual_mask_class": OPTIONAL_FIELDS["masked.residual_mask_class"],
}
_MISSING = object()


def branch_graphs(name: str) -> tuple[str, str]:
    """(masked graph, residual graph) file names of a `masked.branches` entry."""
    return f"masked_{name}.onnx", f"residual_{name}.onnx"


def _lookup(manifest: Mapping[str, Any], dotted: str, default: Any = _MISSING) -> Any:
    value: Any = manifest
    for part in dotted.split("."):
        if not isinstance(value, Mapping) or part not in value:
            if default is not _MISSING:
                return default
            raise BundleError(f"{MANIFEST_NAME}: missing field '{dotted}'")
        value = value[part]
    return value


def family_of(manifest: Mapping[str, Any]) -> str:
    """The manifest's family ("gpt" when absent); an unknown one is refused naming the field."""
    family = manifest.get("family", "gpt")
    check, expected = OPTIONAL_FIELDS["family"]
    if family is None or not check(family):
        raise BundleError(f"{MANIFEST_NAME}: field 'family' must be {expected}, got {family!r}")
    return str(family)


def required_files(manifest: Mapping[str, Any]) -> tuple[str, ...]:
    """The files a bundle of this manifest must hold: the GPT's table, T2M-HiFiGPT's two step graphs, or the masked
    family's graphs (residual.onnx only with more than one quantiser layer, length.onnx only with a length
    estimator)."""
    family = family_of(manifest)
    if family == "gpt":
        return REQUIRED_FILES
    if family == "hifigpt":
        return (*COMMON_FILES[:2], *HIFIGPT_GRAPHS, *COMMON_FILES[2:])
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


def _check_gpt_consistency(manifest: Mapping[str, Any]) -> None:
    if manifest["end_id"] != manifest["codebook_size"]:
        raise BundleError(f"{MANIFEST_NAME}: field 'end_id' is {manifest['end_id']}, expected codebook_size "
                          f"{manifest['codebook_size']} (End is the last logit)")
    block_size = manifest["gpt"]["block_size"]
    if manifest["max_tokens"] > block_size - 1:
        raise BundleError(f"{MANIFEST_NAME}: field 'gpt.block_size' {block_size} is smaller than max_tokens + 1 = "
                          f"{manifest['max_tokens'] + 1}")


def _check_hifigpt_consistency(manifest: Mapping[str, Any]) -> None:
    block_size = manifest["hifigpt"]["block_size"]
    if manifest["max_tokens"] > block_size - 1:
        raise BundleError(f"{MANIFEST_NAME}: field 'hifigpt.block_size' {block_size} is smaller than max_tokens + 1 "
                          f"= {manifest['max_tokens'] + 1}")


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
            value = branch.get(field, _MISSING)
            if value is _MISSING:
                raise BundleError(f"{MANIFEST_NAME}: missing field '{where}.{field}'")
            if not check(value):
                raise BundleError(f"{MANIFEST_NAME}: field '{where}.{field}' must be {expected}, got {value!r}")
        if branch["name"] in names:
            raise BundleError(f"{MANIFEST_NAME}: field '{where}.name' {branch['name']!r} is used twice")
        names.add(branch["name"])
        _check_token_ids(branch, where, branch["codebook_size"])


def _check_masked_consistency(manifest: Mapping[str, Any]) -> None:
    masked = manifest["masked"]
    _check_token_ids(masked, "masked", manifest["codebook_size"])
    _check_branches(manifest)
    if masked["length_estimator"] and LENGTH_GRAPH not in manifest["files"]:
        raise BundleError(f"{MANIFEST_NAME}: field 'masked.length_estimator' is true but 'files' does not list "
                          f"{LENGTH_GRAPH!r}")


def check_manifest_fields(manifest: Mapping[str, Any]) -> None:
    """Every contract field of the manifest's family present with the right type, and the fields consistent."""
    if not isinstance(manifest, Mapping):
        raise BundleError(f"{MANIFEST_NAME}: must hold a JSON object")
    family = family_of(manifest)
    for dotted, (check, expected) in FAMILY_FIELDS[family].items():
        value = _lookup(manifest, dotted)
        if not check(value):
            raise BundleError(f"{MANIFEST_NAME}: field '{dotted}' must be {expected}, got {value!r}")
    for dotted, (check, expected) in OPTIONAL_FIELDS.items():
        value = _lookup(manifest, dotted, None)
        if value is not None and not check(value):
            raise BundleError(f"{MANIFEST_NAME}: field '{dotted}' must be {expected}, got {value!r}")
    {"gpt": _check_gpt_consistency, "masked": _check_masked_consistency,
     "hifigpt": _check_hifigpt_consistency}[family](manifest)
    index = manifest.get("caption_index")
    if index is not None and index.get("file") not in manifest["files"]:
        raise BundleError(f"{MANIFEST_NAME}: field 'files' does not list the caption index {index.get('file')!r}")


@dataclass(frozen=True)
class CaptionIndexInfo:
    """Where the bundle's index of training-caption text features is, and the similarity below which a sentence
    counts as far from everything the model was trained on."""

    file: str
    count: int
    threshold: float


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
    """The `masked` block: the token map's width and the two stages' decoding settings (t2m.decoding.masked)."""

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

    @property
    def decoder_columns(self) -> int:
        """Columns of the decoder's code map: this block's, then every branch's."""
        return self.columns + sum(branch.columns for branch in self.branches)


@dataclass(frozen=True)
class HiFiGPTSettings:
    """The `hifigpt` block: the two step graphs' sizes and the loop's defaults (t2m.decoding.hifigpt)."""

    n_layer_temporal: int
    n_layer_residual: int
    n_head: int
    head_dim: int
    block_size: int
    length_conditioning: bool
    unconditional_branch: bool
    default_guidance: float


@dataclass(frozen=True)
class Manifest:
    """The typed manifest: the fields every family has, and its family's block (`gpt`, `masked` or `hifigpt`, the
    others None).
    The GPT block's fields stay readable as before (`manifest.n_layer`, ...); the full JSON is `raw`."""

    family: str
    name: str
    version: str
    fps: int
    skeleton: str
    num_joints: int
    feature_dim: int
    frames_per_token: int
    max_tokens: int
    codebook_size: int
    residual_layers: int
    text_dim: int
    text_max_length: int
    caption_index: CaptionIndexInfo | None
    files: dict[str, dict[str, Any]]
    raw: dict[str, Any]
    gpt: GptSettings | None = None
    masked: MaskedSettings | None = None
    hifigpt: HiFiGPTSettings | None = None

    def _gpt(self) -> GptSettings:
        if self.gpt is None:
            raise AttributeError(f"a {self.family!r} manifest has no 'gpt' block")
        return self.gpt

    @property
    def end_id(self) -> int:
        return self._gpt().end_id

    @property
    def n_layer(self) -> int:
        return self._gpt().n_layer

    @property
    def n_head(self) -> int:
        return self._gpt().n_head

    @property
    def head_dim(self) -> int:
        return self._gpt().head_dim

    @property
    def block_size(self) -> int:
        return self._gpt().block_size

    @property
    def length_conditioning(self) -> bool:
        """GPT and HiFiGPT: the length input; the masked family always knows each map's rows (its length is an
        input)."""
        if self.hifigpt is not None:
            return self.hifigpt.length_conditioning
        return self._gpt().length_conditioning if self.masked is None else True

    @property
    def unconditional_branch(self) -> bool:
        block = self.masked or self.hifigpt
        return block.unconditional_branch if block is not None else self._gpt().unconditional_branch

    @property
    def default_guidance(self) -> float:
        """The guidance scale a request gets by default (the masked family: its mask stage's)."""
        if self.hifigpt is not None:
            return self.hifigpt.default_guidance
        return self.masked.guidance if self.masked is not None else self._gpt().default_guidance


def _gpt_settings(raw: dict[str, Any]) -> GptSettings:
    gpt = raw["gpt"]
    return GptSettings(n_layer=gpt["n_layer"], n_head=gpt["n_head"], head_dim=gpt["head_dim"],
                       block_size=gpt["block_size"], length_conditioning=gpt["length_conditioning"],
                       unconditional_branch=gpt["unconditional_branch"],
                       default_guidance=float(gpt["default_guidance"]), end_id=raw["end_id"])


def _masked_settings(raw: dict[str, Any]) -> MaskedSettings:
    m = raw["masked"]
    return MaskedSettings(columns=m["columns"], steps=m["steps"], guidance=float(m["guidance"]),
                          residual_guidance=float(m["residual_guidance"]), top_k=m["top_k"],
                          residual_top_k=m["residual_top_k"], mask_id=m["mask_id"], pad_id=m["pad_id"],
                          unconditional_branch=m["unconditional_branch"], length_estimator=m["length_estimator"],
                          residual_temperature=(None if m.get("residual_temperature") is None
                                                else float(m["residual_temperature"])),
                          temperature=None if m.get("temperature") is None else float(m["temperature"]),
                          residual_mask_class=bool(m.get("residual_mask_class", False)),
                          branches=tuple(BranchSettings(**{key: b[key] for key in BRANCH_FIELDS})
                                         for b in m.get("branches") or []))


def _hifigpt_settings(raw: dict[str, Any]) -> HiFiGPTSettings:
    block = {f.name: raw["hifigpt"][f.name] for f in fields(HiFiGPTSettings)}
    return HiFiGPTSettings(**{**block, "default_guidance": float(block["default_guidance"])})


def parse_manifest(raw: dict[str, Any]) -> Manifest:
    """Check `raw` (check_manifest_fields) and return its typed view."""
    check_manifest_fields(raw)
    family, text, index = family_of(raw), raw["text_encoder"], raw.get("caption_index")
    return Manifest(
        family=family, name=raw["name"], version=raw["version"], fps=raw["fps"],
        skeleton=raw["skeleton"], num_joints=raw["num_joints"], feature_dim=raw["feature_dim"],
        frames_per_token=raw["frames_per_token"], max_tokens=raw["max_tokens"], codebook_size=raw["codebook_size"],
        residual_layers=raw["residual_layers"], text_dim=text["dim"], text_max_length=text["max_length"],
        caption_index=None if index is None else CaptionIndexInfo(index["file"], index["count"],
                                                                  float(index["threshold"])),
        files=raw["files"], raw=raw,
        gpt=_gpt_settings(raw) if family == "gpt" else None,
        masked=_masked_settings(raw) if family == "masked" else None,
        hifigpt=_hifigpt_settings(raw) if family == "hifigpt" else None)


def read_manifest_dict(bundle_dir: Path) -> dict[str, Any]:
    """The raw JSON of `bundle_dir/manifest.json` (not yet checked)."""
    if not bundle_dir.is_dir():
        raise BundleError(f"bundle directory {bundle_dir} does not exist")
    path = bundle_dir / MANIFEST_NAME
    if not path.is_file():
        raise BundleError(f"{path}: missing file (a bundle needs {MANIFEST_NAME})")
    try:
        raw = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as error:
        raise BundleError(f"{path}: invalid JSON at line {error.lineno}: {error.msg}") from None
    except UnicodeDecodeError as error:
        raise BundleError(f"{path}: not UTF-8 text ({error})") from None
    if not isinstance(raw, dict):
        raise BundleError(f"{path}: must hold a JSON object")
    return raw


def read_manifest(bundle_dir: Path) -> Manifest:
    """Read and check `bundle_dir/manifest.json`."""
    return parse_manifest(read_manifest_dict(bundle_dir))
