"""An MDM / DiP release folder: where its files are, reading them, and what an import read from them
(../shared/docs/diffusion-models.md §4).

A release is one folder, as the official ``save/<name>/``:

    args.json            json.dump(vars(args), indent=4, sort_keys=True) of the training arguments
    model<step>.pt       a plain state dict (2022 models) or {'model': sd, 'model_avg': sd_ema} (2025 code, --use_ema)
    opt<step>.pt         the optimiser (not read)

The weights are chosen as the official generate/edit/eval choose them: ``model_avg`` iff args.json says
``use_ema`` (loading the other one computes another model), else ``model`` or the plain dict. ``clip_model.*`` keys
(CLIP or DistilBERT saved inside by the pre-2022-12 trainer) are dropped; both positional tables
(``sequence_pos_encoder.pe``, ``embed_timestep.sequence_pos_encoder.pe``) are ignored whatever their shape and
recomputed, as the official loader does. Every other tensor is checked against the module (present, its shape,
nothing extra) and loaded strictly. No text-encoder weights are in a release: CLIP comes from OpenAI's ``ViT-B-32.pt``,
DistilBERT from a Hugging Face ``distilbert-base-uncased`` folder.
"""
from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from t2m.export.importers.kit import load_checked, read_torch_file
from t2m.families.diffusion.network import MDM, DiffusionConfig, released_weights
from t2m.families.diffusion.text_encoders import MdmClipEncoder, TokenStateEncoder, distilbert_encoder

__all__ = ["DATASETS", "DiffusionFiles", "ImportedDiffusion", "build_text_encoder", "load_denoiser", "load_release",
           "locate_release", "read_args", "read_checked_config", "weights_entry"]

ARGS_FILE = "args.json"
PE_KEYS = ("sequence_pos_encoder.pe", "embed_timestep.sequence_pos_encoder.pe")
DATASETS = ("humanml",)          # the service's 263-d HumanML3D features at 20 fps
EXPECTED = "a release folder with args.json and model<step>.pt (the official save/<name>/)"
CLIP_FILE = "pass --clip ViT-B-32.pt (OpenAI's file, as clip.load downloads it)"
BERT_FOLDER = ("pass --bert DIR (a Hugging Face distilbert-base-uncased folder: config.json, model.safetensors or "
               "pytorch_model.bin, vocab.txt or tokenizer.json)")


@dataclass(frozen=True)
class DiffusionFiles:
    folder: Path
    model: Path
    args: Path


def locate_release(folder: str | Path | None, model: str | Path | None = None) -> DiffusionFiles:
    """args.json and the weights of a release folder; ``model`` names the weights file when the folder holds
    several ``model*.pt`` (or any other file). Each missing or ambiguous file refused in one line."""
    if folder is None:
        raise ValueError(f"no release folder: pass {EXPECTED}")
    root = Path(folder)
    if not root.is_dir():
        raise ValueError(f"{root}: no such folder (expected {EXPECTED})")
    args = root / ARGS_FILE
    if not args.is_file():
        raise ValueError(f"{args}: missing file: the release's training arguments (arch, steps, text encoder)")
    if model is not None:
        weights = Path(model)
        if not weights.is_file():
            raise ValueError(f"{weights}: missing file: the release's weights")
        return DiffusionFiles(root, weights, args)
    found = sorted(p for p in root.glob("model*.pt") if p.is_file())
    if not found:
        raise ValueError(f"{root}: missing file model<step>.pt: the release's weights")
    if len(found) > 1:
        raise ValueError(f"{root}: {len(found)} weights files ({', '.join(p.name for p in found)}): pass --model "
                         "FILE to choose one")
    return DiffusionFiles(root, found[0], args)


def read_args(path: Path) -> dict[str, Any]:
    """args.json as a dict, refused in one line if it is not a JSON object."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, OSError) as error:
        raise ValueError(f"{path}: not JSON ({' '.join(str(error).split())[:160]})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: not a JSON object (expected the release's training arguments)")
    return data


def read_checked_config(files: DiffusionFiles) -> tuple[dict[str, Any], DiffusionConfig]:
    """(args.json, the config it gives), refusing a dataset other than HumanML3D and what the modules do not build
    (t2m.families.diffusion.network.DiffusionConfig.from_args), one line naming the file and the arguments."""
    args = read_args(files.args)
    dataset = args.get("dataset", "humanml")
    if dataset not in DATASETS:
        raise ValueError(f"{files.args}: dataset {dataset!r}: only HumanML3D releases ('humanml') are imported (the "
                         "service's 263-d features at 20 fps)")
    try:
        config = DiffusionConfig.from_args(args)
    except ValueError as error:
        raise ValueError(f"{files.args}: {error}") from None
    return args, config


def weights_entry(checkpoint: Mapping[str, Any], use_ema: bool) -> str:
    """Which state dict of the file the import reads: 'model_avg', 'model' or 'state dict' (a plain one)."""
    if "model" in checkpoint and isinstance(checkpoint["model"], Mapping):
        return "model_avg" if use_ema else "model"
    return "state dict"


def load_denoiser(files: DiffusionFiles, config: DiffusionConfig, use_ema: bool, release: str,
                  allow_pickle: bool = False) -> tuple[MDM, str]:
    """(the release's denoiser as our module in eval mode, the entry read): the EMA choice of args.json, text-encoder
    keys dropped, the pe tables recomputed, every other tensor checked and loaded strictly."""
    checkpoint = read_torch_file(files.model, allow_pickle)
    if not isinstance(checkpoint, Mapping):
        raise ValueError(f"{files.model}: holds a {type(checkpoint).__name__}, expected a state dict or "
                         "{'model', 'model_avg'}")
    try:
        state = released_weights(checkpoint, use_ema)
    except ValueError as error:
        raise ValueError(f"{files.model}: {error} (args.json: use_ema {use_ema})") from None
    entry = weights_entry(checkpoint, use_ema)
    where = f"{files.model}" + (f" ['{entry}']" if entry != "state dict" else "")
    bad = next((str(k) for k, v in state.items() if not isinstance(v, torch.Tensor)), None)
    if bad is not None:
        raise ValueError(f"{where}: '{bad}' is not a tensor (expected a state dict of tensors)")
    module = MDM(config)
    own = module.state_dict()
    tensors = {str(k): v.float() if v.is_floating_point() else v for k, v in state.items() if k not in PE_KEYS}
    tensors |= {key: own[key] for key in PE_KEYS}          # recomputed, as the official loader does
    return load_checked(module, tensors, where, release), entry


def build_text_encoder(config: DiffusionConfig, clip_file: str | Path | None, bert_dir: str | Path | None,
                       release: str) -> MdmClipEncoder | TokenStateEncoder:
    """The release's text encoder: CLIP ViT-B/32 cut to 20 tokens (text_encoder_type clip) or DistilBERT token
    states (bert), with its output size checked against the denoiser's ``embed_text``."""
    encoder: MdmClipEncoder | TokenStateEncoder
    kind = "DistilBERT (args.json: text_encoder_type 'bert')" if config.text_tokens else (
        "CLIP ViT-B/32 (args.json: text_encoder_type 'clip')")
    if config.text_tokens and clip_file is not None:
        raise ValueError(f"--clip {clip_file}: {release}'s text encoder is {kind}, not CLIP: {BERT_FOLDER}")
    if not config.text_tokens and bert_dir is not None:
        raise ValueError(f"--bert {bert_dir}: {release}'s text encoder is {kind}, not DistilBERT: {CLIP_FILE}")
    if config.text_tokens:
        if bert_dir is None:
            raise ValueError(f"{release}'s text encoder is {kind}: {BERT_FOLDER}")
        encoder = distilbert_encoder(bert_dir)
        source = f"{bert_dir}: DistilBERT dim"
    else:
        if clip_file is None:
            raise ValueError(f"{release}'s text encoder is {kind}: {CLIP_FILE}")
        if not Path(clip_file).is_file():
            raise ValueError(f"{clip_file}: missing file: CLIP ViT-B/32 weights (OpenAI's ViT-B-32.pt)")
        encoder = MdmClipEncoder(clip_file)
        source = f"{clip_file}: CLIP embed dim"
    if encoder.dim != config.text_dim:
        raise ValueError(f"{source} {encoder.dim}, the release's embed_text takes {config.text_dim}")
    return encoder


@dataclass
class ImportedDiffusion:
    """A release as our modules: its files and arguments, the config, the denoiser (eval), the text encoder, and
    which state dict of the weights file was read ('model_avg', 'model' or 'state dict')."""

    release: str                               # "MDM" or "DiP"
    files: DiffusionFiles
    args: dict[str, Any]
    config: DiffusionConfig
    model: MDM
    text: MdmClipEncoder | TokenStateEncoder
    entry: str

    def __iter__(self):
        """(config, model, text): ``config, model, text = load_mdm_release(...)``."""
        return iter((self.config, self.model, self.text))


def load_release(release: str, check: Callable[[dict[str, Any], DiffusionConfig, str], None],
                 folder: str | Path | None, clip_file: str | Path | None, bert_dir: str | Path | None,
                 model_file: str | Path | None, allow_pickle: bool) -> ImportedDiffusion:
    """What both importers do: the files, args.json and its config (``check``: the importer's own refusals), the text
    encoder (its file refused before the slow checkpoint load), then the weights."""
    files = locate_release(folder, model_file)
    args, config = read_checked_config(files)
    check(args, config, str(files.args))
    text = build_text_encoder(config, clip_file, bert_dir, release)
    model, entry = load_denoiser(files, config, bool(args.get("use_ema", False)), release, allow_pickle)
    return ImportedDiffusion(release, files, args, config, model, text, entry)
