"""Write model bundles (docs/contracts.md "The bundle"): files + manifest.json with sha256 and sizes, then verify.

``write_bundle`` is the only place a manifest's ``files`` table is computed, so every bundle -
exported from our runs, imported from T2M-GPT, or a random test bundle (t2m.families.gpt.random_bundle) - is
hashed and checked the same way.
"""
from __future__ import annotations

import json
import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from t2m.bundle import COMMON_FILES, FORMAT_VERSION, MANIFEST_NAME, OPTIONAL_FILES, BundleError, files_table
from t2m.export.writing.verify import verify_bundle
from t2m.motion.constants import FPS

__all__ = [
    "FORMAT_VERSION",
    "BundleError",
    "check_out_dir",
    "prepare_out_dir",
    "render_family_card",
    "render_model_card",
    "verify_bundle",
    "write_bundle",
]

# feature_dim -> (skeleton name, joints): HumanML3D (SMPL-22) and KIT-ML layouts
SKELETON_OF_FEATURE_DIM = {263: ("smpl22", 22), 251: ("kit21", 21)}


def _old_bundle_files(out_dir: Path) -> list[str] | None:
    """Names of the files an existing bundle in out_dir lists (None: out_dir holds no bundle)."""
    manifest = out_dir / MANIFEST_NAME
    if not manifest.is_file():
        return None
    try:
        return list(json.loads(manifest.read_text(encoding="utf-8")).get("files", {}))
    except (json.JSONDecodeError, AttributeError) as error:
        raise ValueError(
            f"{manifest}: an earlier bundle's manifest is unreadable ({error}); remove it first"
        ) from error


def check_out_dir(out_dir: str | Path) -> Path:
    """``out_dir`` may be written: absent, empty, or an earlier bundle (never clobber unrelated files)."""
    out_dir = Path(out_dir)
    if out_dir.exists():
        if not out_dir.is_dir():
            raise ValueError(f"{out_dir}: exists and is not a directory")
        if any(out_dir.iterdir()) and _old_bundle_files(out_dir) is None:
            raise ValueError(f"{out_dir}: exists, is not empty and holds no bundle; refusing to overwrite it")
    return out_dir


def prepare_out_dir(out_dir: str | Path) -> Path:
    """Create ``out_dir`` after :func:`check_out_dir`, removing an earlier bundle's files."""
    out_dir = check_out_dir(out_dir)
    for name in [MANIFEST_NAME, *(_old_bundle_files(out_dir) or []), *COMMON_FILES, *OPTIONAL_FILES]:
        target = out_dir / name
        if target.is_file():
            target.unlink()
    out_dir.mkdir(parents=True, exist_ok=True)
    return out_dir


def write_bundle(out_dir: str | Path, files: Mapping[str, str | Path | bytes], manifest: Mapping[str, Any]) -> dict:
    """Place ``files`` (name -> source path or bytes) in ``out_dir``, hash them, write manifest.json, verify.

    ``manifest`` holds every contract field except ``files`` (computed here); sources already at
    ``out_dir/name`` are used in place. Returns the written manifest. Raises BundleError
    (a ValueError) naming the file or field if the result does not satisfy the contract.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    for name, source in files.items():
        if name == MANIFEST_NAME or Path(name).is_absolute() or ".." in Path(name).parts:
            raise ValueError(f"bundle file name {name!r} is not allowed")
        target = out_dir / name
        target.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(source, (bytes, bytearray)):
            target.write_bytes(bytes(source))
        else:
            source = Path(source)
            if not source.is_file():
                raise FileNotFoundError(source)
            if source.resolve() != target.resolve():
                shutil.copyfile(source, target)
    full = {key: value for key, value in manifest.items() if key != "files"}
    full.setdefault("format_version", FORMAT_VERSION)
    full["files"] = files_table(out_dir, files)
    (out_dir / MANIFEST_NAME).write_text(json.dumps(full, indent=2) + "\n", encoding="utf-8")
    return verify_bundle(out_dir)


def render_model_card(manifest: Mapping[str, Any], notes: str = "") -> str:
    """MODEL_CARD.md from the manifest's facts (+ free-form notes, e.g. the user's --model-card file)."""
    gpt = manifest["gpt"]
    text = manifest["text_encoder"]
    data = manifest["training_data"]
    quant = manifest.get("quantization") or {}
    max_seconds = manifest["max_tokens"] * manifest["frames_per_token"] / manifest["fps"]
    lines = [
        f"# {manifest['name']} {manifest['version']}",
        "",
        "Text-to-motion model bundle (VQ-VAE decoder + GPT over motion codes + text encoder, ONNX).",
        "",
        "| | |",
        "| --- | --- |",
        f"| motion | {manifest['skeleton']} ({manifest['num_joints']} joints), {manifest['feature_dim']}-dim features,"
        f" {manifest['fps']} fps, {manifest['frames_per_token']} frames per code |",
        f"| codes | codebook {manifest['codebook_size']}, residual layers {manifest['residual_layers']},"
        f" at most {manifest['max_tokens']} codes ({max_seconds:.1f} s) |",
        f"| GPT | {gpt['n_layer']} layers, {gpt['n_head']} heads x {gpt['head_dim']}, block {gpt['block_size']},"
        f" length conditioning {'yes' if gpt['length_conditioning'] else 'no'} |",
        f"| guidance | trained unconditional branch: {'yes' if gpt['unconditional_branch'] else 'no'};"
        f" default scale {gpt['default_guidance']} |",
        f"| text encoder | {text['kind']} ({text['dim']}-d, {text['pooling']} pooling,"
        f" {'L2-normalised' if text['normalize'] else 'not normalised'}, max {text['max_length']} tokens) |",
        f"| quantisation | text encoder: {quant.get('text_encoder') or 'float32'};"
        f" GPT step: {quant.get('gpt_step') or 'float32'} |",
        f"| training data | {data['name']} ({data['license']}) |",
        f"| licence of the weights | {manifest['license']} |",
        "",
    ]
    if data.get("attribution"):
        lines += ["## Attribution", "", data["attribution"], ""]
    if not gpt["unconditional_branch"]:
        lines += [
            "## Guidance",
            "",
            "This GPT was trained without condition dropout: it has no trained unconditional branch. Classifier-free",
            "guidance with a zero null condition is an untested assumption for it; "
            "use guidance 1.0 (the default here).",
            "",
        ]
    if notes.strip():
        lines += [notes.strip(), ""]
    return "\n".join(lines)


def render_family_card(manifest: Mapping[str, Any], description: str, rows: list[tuple[str, str]],
                       notes: str = "") -> str:
    """A family's MODEL_CARD.md: title, what the bundle is, the motion row, the family's `rows` (label, text), the text
    encoder, data and licence rows, the attribution and free-form notes."""
    text, data = manifest["text_encoder"], manifest["training_data"]
    lines = [
        f"# {manifest['name']} {manifest['version']}", "", description, "",
        "| | |", "| --- | --- |",
        f"| motion | {manifest['skeleton']} ({manifest['num_joints']} joints), {manifest['feature_dim']}-dim features,"
        f" {manifest['fps']} fps, {manifest['frames_per_token']} frames per token row |",
        *(f"| {label} | {value} |" for label, value in rows),
        f"| text encoder | {text['kind']} ({text['dim']}-d, {text['pooling']} pooling,"
        f" {'L2-normalised' if text['normalize'] else 'not normalised'}, max {text['max_length']} tokens) |",
        f"| training data | {data['name']} ({data['license']}) |",
        f"| licence of the weights | {manifest['license']} |", "",
    ]
    if data.get("attribution"):
        lines += ["## Attribution", "", data["attribution"], ""]
    if notes.strip():
        lines += [notes.strip(), ""]
    return "\n".join(lines)


def max_seconds(manifest: Mapping[str, Any]) -> float:
    """The longest segment a bundle generates: max_tokens rows of frames_per_token frames."""
    return manifest["max_tokens"] * manifest["frames_per_token"] / manifest["fps"]


def motion_fields(feature_dim: int, frames_per_token: int, max_tokens: int) -> dict[str, Any]:
    """The manifest's motion fields for a feature layout (HumanML3D 263 -> smpl22, KIT 251 -> kit21)."""
    if feature_dim not in SKELETON_OF_FEATURE_DIM:
        raise ValueError(f"feature_dim {feature_dim} matches no known skeleton (263 = smpl22, 251 = kit21)")
    skeleton, joints = SKELETON_OF_FEATURE_DIM[feature_dim]
    return {"fps": FPS, "skeleton": skeleton, "num_joints": joints, "feature_dim": feature_dim,
            "frames_per_token": frames_per_token, "max_tokens": max_tokens}
