"""manifest.json: its fields, their types and consistency rules, and the typed view the loaders use.

`COMMON_FIELDS` says what the fields every family has must be; the manifest's `family` (t2m.bundle.family) adds its
own block and checks. `check_manifest_fields` applies both to the raw JSON and `parse_manifest` turns checked JSON
into a `Manifest` whose `settings` is the family's typed block. Optional fields have defaults that keep older
bundles valid: `family` ("gpt", the only family of format 1's first bundles) and `caption_index` (null: the bundle
carries no index of its training captions, e.g. an imported release).
"""
from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from t2m.bundle.errors import BundleError
from t2m.bundle.family import FieldRule, ModelFamily, family_names, get_family

__all__ = [
    "BOOL",
    "CAPTION_INDEX_FILE",
    "COMMON_FIELDS",
    "COMMON_FILES",
    "COMMON_OPTIONAL_FIELDS",
    "FORMAT_VERSION",
    "GUIDANCE",
    "INT8_LABEL",
    "INT8_LABELS",
    "INTEGER_ABOVE_1",
    "LENGTH_GRAPH",
    "MANIFEST_NAME",
    "OPTIONAL_FILES",
    "POSITIVE",
    "QUANTIZATION",
    "ROW_INT8_LABEL",
    "CaptionIndexInfo",
    "Manifest",
    "check_block_size",
    "check_fields",
    "check_manifest_fields",
    "family_of",
    "is_bool",
    "is_int",
    "is_number",
    "is_optional_positive",
    "is_optional_str",
    "is_positive_int",
    "is_str",
    "lookup",
    "parse_manifest",
    "read_manifest",
    "read_manifest_dict",
    "required_files",
]

FORMAT_VERSION = 1
MANIFEST_NAME = "manifest.json"
CAPTION_INDEX_FILE = "caption_index.npz"
LENGTH_GRAPH = "length.onnx"
OPTIONAL_FILES = (CAPTION_INDEX_FILE, LENGTH_GRAPH)
# every family's bundle holds these; the family's own graphs come between the tokenizer and the decoder
COMMON_FILES = ("text_encoder.onnx", "tokenizer.json", "decoder.onnx", "mean.npy", "std.npy", "MODEL_CARD.md")


def is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def is_positive_int(value: Any) -> bool:
    return is_int(value) and value > 0


def is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def is_str(value: Any) -> bool:
    return isinstance(value, str) and value != ""


def is_bool(value: Any) -> bool:
    return isinstance(value, bool)


def is_optional_str(value: Any) -> bool:
    return value is None or is_str(value)


def is_optional_positive(value: Any) -> bool:
    return value is None or is_positive_int(value)


Check = Callable[[Any], bool]
POSITIVE: FieldRule = (is_positive_int, "a positive integer")
# rules the families' blocks share
BOOL: FieldRule = (is_bool, "true or false")
GUIDANCE: FieldRule = (lambda v: is_number(v) and v >= 0, "a number >= 0")
INTEGER_ABOVE_1: FieldRule = (lambda v: is_int(v) and v > 1, "an integer > 1")
QUANTIZATION: FieldRule = (is_optional_str, "null or a string such as 'int8-dynamic'")
INT8_LABEL = "int8-dynamic"              # activations quantised per tensor (text encoders)
ROW_INT8_LABEL = "int8-dynamic-rows"     # per row (token graphs: a row's result never depends on its batch)
INT8_LABELS = (INT8_LABEL, ROW_INT8_LABEL)
# field path -> (check, what it must be); every field is required, for every family
COMMON_FIELDS: dict[str, FieldRule] = {
    "format_version": (lambda v: v == FORMAT_VERSION, f"the integer {FORMAT_VERSION}"),
    "name": (is_str, "a non-empty string"),
    "version": (is_str, "a non-empty string"),
    "fps": POSITIVE,
    "skeleton": (is_str, "a skeleton name such as 'smpl22'"),
    "num_joints": POSITIVE,
    "feature_dim": POSITIVE,
    "frames_per_token": POSITIVE,
    "max_tokens": POSITIVE,
    "codebook_size": POSITIVE,
    "residual_layers": POSITIVE,
    "text_encoder.kind": (is_str, "a string such as 'minilm' or 'clip'"),
    "text_encoder.dim": POSITIVE,
    "text_encoder.max_length": INTEGER_ABOVE_1,
    "text_encoder.pooling": (is_str, "a string such as 'mean' or 'eot'"),
    "text_encoder.normalize": BOOL,
    "text_encoder.null_condition": (lambda v: v == "zeros", "'zeros'"),
    "training_data.name": (is_str, "a non-empty string"),
    "training_data.license": (is_str, "a non-empty string"),
    "training_data.attribution": (lambda v: isinstance(v, str), "a string"),
    "license": (is_str, "a non-empty string"),
    "quantization.text_encoder": QUANTIZATION,
    "files": (lambda v: isinstance(v, dict) and bool(v), "an object {file name: {sha256, bytes}}"),
}
# optional fields of every family: path -> (check, what it must be)
COMMON_OPTIONAL_FIELDS: dict[str, FieldRule] = {
    "caption_index": (lambda v: v is None or isinstance(v, dict), "null or an object"),
    "caption_index.file": (lambda v: v == CAPTION_INDEX_FILE, f"'{CAPTION_INDEX_FILE}'"),
    "caption_index.count": POSITIVE,
    "caption_index.threshold": (lambda v: is_number(v) and -1 <= v <= 1, "a cosine similarity in [-1, 1]"),
}
_MISSING = object()


def lookup(manifest: Mapping[str, Any], dotted: str, default: Any = _MISSING) -> Any:
    """The value at a dotted path; absent: `default`, or a BundleError naming the field when none is given."""
    value: Any = manifest
    for part in dotted.split("."):
        if not isinstance(value, Mapping) or part not in value:
            if default is not _MISSING:
                return default
            raise BundleError(f"{MANIFEST_NAME}: missing field '{dotted}'")
        value = value[part]
    return value


def check_fields(manifest: Mapping[str, Any], table: Mapping[str, FieldRule], *, required: bool,
                 where: str = "") -> None:
    """Each field of `table` (absent or null allowed unless `required`) against its rule, naming the first bad one."""
    for dotted, (check, expected) in table.items():
        value = lookup(manifest, dotted) if required else lookup(manifest, dotted, None)
        if (required or value is not None) and not check(value):
            raise BundleError(f"{MANIFEST_NAME}: field '{where}{dotted}' must be {expected}, got {value!r}")


def check_block_size(manifest: Mapping[str, Any], block: str) -> None:
    """A step graph's `<block>.block_size` holds the condition token and max_tokens steps."""
    block_size = manifest[block]["block_size"]
    if manifest["max_tokens"] > block_size - 1:
        raise BundleError(f"{MANIFEST_NAME}: field '{block}.block_size' {block_size} is smaller than max_tokens + 1 "
                          f"= {manifest['max_tokens'] + 1}")


def family_of(manifest: Mapping[str, Any]) -> str:
    """The manifest's family ("gpt" when absent); an unknown one is refused naming the field."""
    family = manifest.get("family", "gpt")
    if not isinstance(family, str):
        raise BundleError(f"{MANIFEST_NAME}: field 'family' must be one of {list(family_names())}, got {family!r}")
    return get_family(family).name


def _family(manifest: Mapping[str, Any]) -> ModelFamily:
    return get_family(family_of(manifest))


def required_files(manifest: Mapping[str, Any]) -> tuple[str, ...]:
    """The files a bundle of this manifest must hold (its family says which)."""
    return _family(manifest).required_files(manifest)


def check_manifest_fields(manifest: Mapping[str, Any]) -> None:
    """Every contract field of the manifest's family present with the right type, and the fields consistent."""
    if not isinstance(manifest, Mapping):
        raise BundleError(f"{MANIFEST_NAME}: must hold a JSON object")
    family = _family(manifest)
    check_fields(manifest, family.field_table(COMMON_FIELDS), required=True)
    check_fields(manifest, {**COMMON_OPTIONAL_FIELDS, **family.optional_fields}, required=False)
    family.check_consistency(manifest)
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
class Manifest:
    """The typed manifest: the fields every family has, and `settings`, its family's typed block (the family's
    `settings(raw)`); the full JSON is `raw`."""

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
    settings: Any = None

    @property
    def length_conditioning(self) -> bool:
        """Whether the token graphs take each segment's length as an input."""
        return bool(self.settings.length_conditioning)

    @property
    def unconditional_branch(self) -> bool:
        """Whether condition dropout trained the null-condition branch that guidance uses."""
        return bool(self.settings.unconditional_branch)

    @property
    def default_guidance(self) -> float:
        """The guidance scale a request gets by default."""
        return float(self.settings.default_guidance)


def parse_manifest(raw: dict[str, Any]) -> Manifest:
    """Check `raw` (check_manifest_fields) and return its typed view."""
    check_manifest_fields(raw)
    family, text, index = _family(raw), raw["text_encoder"], raw.get("caption_index")
    return Manifest(
        family=family.name, name=raw["name"], version=raw["version"], fps=raw["fps"],
        skeleton=raw["skeleton"], num_joints=raw["num_joints"], feature_dim=raw["feature_dim"],
        frames_per_token=raw["frames_per_token"], max_tokens=raw["max_tokens"], codebook_size=raw["codebook_size"],
        residual_layers=raw["residual_layers"], text_dim=text["dim"], text_max_length=text["max_length"],
        caption_index=None if index is None else CaptionIndexInfo(index["file"], index["count"],
                                                                  float(index["threshold"])),
        files=raw["files"], raw=raw, settings=family.settings(raw))


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
