"""The whole ``t2m import mdm`` / ``t2m import dip``: a release folder (mdm.py / dip.py read it into our modules),
HumanML3D's generation statistics, then a verified diffusion-family bundle (t2m.families.diffusion.export) with the
release's settings, its card (diffusion_card.release_notes) and the graphs checked against the modules.

Statistics: MDM de-normalises with HumanML3D's ``Mean.npy`` / ``Std.npy`` from ``dataset/HumanML3D`` (the dataset
folder, not the release folder: ../shared/docs/diffusion-models.md §7), so the import takes that folder
(``--humanml3d DIR``) or the two files (``--mean`` / ``--std``). The repository's ``dataset/t2m_mean.npy`` /
``t2m_std.npy`` are the evaluator's statistics (std 25 times smaller on the root and foot-contact dims): refused by
name, as another de-normalisation.

Settings: guidance 2.5 (generate.py's default) for MDM, 7.5 for DiP (DiP.md); a release trained without condition
dropout (``cond_mask_prob`` 0) samples without guidance, as generate.py forces it. Segments: MDM at most 196 frames
(generate.py); a DiP sentence at most ``DIP_MAX_FRAMES`` (its code has no limit of its own). DiP's first prefix is
the standing pose of ``standing_prefix`` (t2m/families/diffusion/README.md).
"""
from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from t2m.export.importers.kit import read_stat
from t2m.export.kit.checks import GROSS_PARITY_ERROR
from t2m.export.kit.parity import PARITY_TEXTS
from t2m.export.kit.text_sources import TextSource, encoder_text_source, token_states_text_source
from t2m.families.diffusion.export import MDM_MAX_FRAMES, export_diffusion_bundle
from t2m.families.diffusion.import_card import release_notes
from t2m.families.diffusion.import_dip import load_dip_release
from t2m.families.diffusion.import_mdm import load_mdm_release
from t2m.families.diffusion.mdm_files import ImportedDiffusion
from t2m.families.diffusion.text_encoders import TokenStateEncoder

log = logging.getLogger(__name__)

__all__ = ["DIP_MAX_FRAMES", "GUIDANCE", "DiffusionImportChecks", "denoiser_parity", "import_dip", "import_mdm",
           "locate_statistics"]

GUIDANCE = {"MDM": 2.5, "DiP": 7.5}
DIP_MAX_FRAMES = 400                      # 20 s a sentence: 10 calls of 40 frames
STATISTICS = ("Mean.npy", "Std.npy")      # HumanML3D's folder (MDM's dataset/HumanML3D)
EVALUATOR_STATISTICS = ("t2m_mean.npy", "t2m_std.npy")
NO_STATISTICS = ("no generation statistics: pass --humanml3d DIR (HumanML3D's folder with Mean.npy and Std.npy, "
                 "MDM's dataset/HumanML3D) or --mean Mean.npy --std Std.npy")


def locate_statistics(humanml3d: str | Path | None, mean: str | Path | None,
                      std: str | Path | None) -> tuple[Path, Path]:
    """(Mean.npy, Std.npy): the files given, else the folder's; each missing one, or the evaluator's files, refused
    in one line naming it."""
    folder = Path(humanml3d) if humanml3d is not None else None
    if folder is not None and not folder.is_dir():
        raise ValueError(f"{folder}: no such folder (expected HumanML3D's folder with Mean.npy and Std.npy)")
    paths = []
    for given, default in zip((mean, std), STATISTICS):
        path = Path(given) if given is not None else (folder / default if folder is not None else None)
        if path is None:
            raise ValueError(NO_STATISTICS)
        if path.name in EVALUATOR_STATISTICS:
            raise ValueError(f"{path}: the evaluator's statistics (MDM's dataset/{path.name}), not the generation "
                             f"ones: MDM de-normalises with HumanML3D's {default}")
        if not path.is_file():
            raise ValueError(f"{path}: missing file: HumanML3D's {default} (the generation statistics)")
        paths.append(path)
    return paths[0], paths[1]


@dataclass
class DiffusionImportChecks:
    """What the import measured: onnxruntime vs PyTorch on the written graphs (float32)."""

    parity: dict[str, Any] = field(default_factory=dict)
    quantization: dict[str, Any] | None = None     # `--quantize`: the copy against this import (bundle_parity)

    def model_card_section(self) -> str:
        p = self.parity
        lines = ["## Export checks (onnxruntime vs PyTorch, float32)", "",
                 f"- denoiser: max |x0 diff| {p['denoiser']['max_abs_diff']:.2e} (x0 up to "
                 f"{p['denoiser']['max_abs_value']:.2f}; {p['denoiser']['rows']} rows: conditional and null texts, "
                 f"steps {p['denoiser']['steps']})",
                 f"- text encoder: max |feature diff| {p['text_encoder']['max_abs_diff']:.2e}",
                 f"- decoder: max |feature diff| {p['decoder']['max_abs_diff']:.2e}"]
        return "\n".join(lines) + "\n"


def _ort(path: Path) -> Any:
    from t2m.export.graphs.export import ort_session

    return ort_session(path)


@torch.no_grad()
def text_condition(text: Any, out_dir: Path, texts: Sequence[str]) -> tuple[np.ndarray, np.ndarray | None, float]:
    """(the module's text condition for ``texts``, its token mask or None, max |diff| of text_encoder.onnx on the
    bundle's tokenizer): pooled features [N, Dt] or token states [N, L, Dt] + mask [N, L]."""
    from t2m.export.graphs.text import tokenize

    ids, mask = tokenize(out_dir / "tokenizer.json", list(texts))
    feed = {"input_ids": ids.numpy(), "attention_mask": mask.numpy()}
    if isinstance(text, TokenStateEncoder):
        (states,) = _ort(out_dir / "text_encoder.onnx").run(["token_states"], feed)
        expected, keys = text.encode(list(texts))
        if expected.shape != states.shape:
            raise ValueError(f"text_encoder.onnx gave {list(states.shape)}, PyTorch {list(expected.shape)}")
        return expected, keys, float(np.abs((states - expected) * keys[..., None]).max())
    (features,) = _ort(out_dir / "text_encoder.onnx").run(["text_features"], feed)
    expected = text.encode(list(texts))
    return expected, None, float(np.abs(features - expected).max())


@torch.no_grad()
def denoiser_parity(imported: ImportedDiffusion, out_dir: Path, seed: int = 0) -> dict[str, Any]:
    """denoiser.onnx vs the module on one batch as the service feeds it: the parity texts' conditions and their
    null rows (zeros), random x_t, steps from the first to 0, one shorter row where the model masks frames, random
    prefixes for DiP; the text graph and the decoder too. Refused beyond GROSS_PARITY_ERROR (relative to |x0|)."""
    from t2m.families.diffusion.export_graphs import DenoiserGraph, denoiser_inputs

    model, c = imported.model.eval(), imported.config
    text, keys, text_diff = text_condition(imported.text, out_dir, PARITY_TEXTS[:2])
    rows = 2 * len(text)
    frames = c.pred_len or 40
    g = torch.Generator().manual_seed(seed)
    cond = torch.from_numpy(np.concatenate([text, np.zeros_like(text)]))
    steps = torch.tensor([c.diffusion_steps - 1, c.diffusion_steps // 2, 1, 0])[:rows]
    values: dict[str, torch.Tensor | None] = {
        "x_t": torch.randn(rows, frames, c.features, generator=g), "t": steps, "text": cond,
        "text_mask": None if keys is None else torch.from_numpy(np.concatenate([keys, keys])),
        "length": torch.tensor([frames] * (rows - 1) + [frames - 7]),
        "prefix": torch.randn(rows, max(c.context_len, 1), c.features, generator=g)}
    names = denoiser_inputs(model)
    inputs = [value for name in names if (value := values[name]) is not None]
    expected = DenoiserGraph(model)(*inputs).numpy()
    (x0,) = _ort(out_dir / "denoiser.onnx").run(["x0"], {n: v.numpy() for n, v in zip(names, inputs)})
    if c.mask_frames:   # a padded frame's output is not used
        expected[-1, frames - 7:] = x0[-1, frames - 7:] = 0.0
    motion = np.random.default_rng(seed).standard_normal((1, 12, c.features)).astype(np.float32)
    (features,) = _ort(out_dir / "decoder.onnx").run(["features"], {"motion": motion})
    mean, std = np.load(out_dir / "mean.npy"), np.load(out_dir / "std.npy")
    report: dict[str, dict[str, Any]] = {"denoiser": {"rows": rows, "frames": frames, "steps": steps.tolist(),
                           "max_abs_diff": float(np.abs(x0 - expected).max()),
                           "max_abs_value": float(np.abs(expected).max())},
              "text_encoder": {"max_abs_diff": text_diff},
              "decoder": {"max_abs_diff": float(np.abs(features - (motion * std + mean)).max())}}
    scale = max(1.0, report["denoiser"]["max_abs_value"])
    worst = {"denoiser": report["denoiser"]["max_abs_diff"] / scale, "text_encoder": text_diff,
             "decoder": report["decoder"]["max_abs_diff"]}
    broken = {key: diff for key, diff in worst.items() if not diff <= GROSS_PARITY_ERROR}
    if broken:
        raise ValueError(f"exported graphs differ from PyTorch by more than {GROSS_PARITY_ERROR}: {broken}")
    return report


def default_name(imported: ImportedDiffusion) -> str:
    c = imported.config
    if imported.release == "DiP":
        return "dip-humanml3d"
    return f"mdm-humanml3d-{c.diffusion_steps}steps" + ("-distilbert" if c.text_tokens else "")


def text_source_of(imported: ImportedDiffusion) -> TextSource:
    """MDM's CLIP (pooled, 22 ids) or DistilBERT's token states, as the import already loaded them."""
    if isinstance(imported.text, TokenStateEncoder):
        return token_states_text_source(imported.text)
    return encoder_text_source(imported.text)


def _export(imported: ImportedDiffusion, statistics: tuple[Path, Path], out_dir: str | Path, *, name: str | None,
            version: str, check_parity: bool) -> tuple[dict, DiffusionImportChecks]:
    """Statistics read, settings chosen, bundle written and verified, parity measured into the card."""
    c = imported.config
    mean, std = (read_stat(path, c.features, "HumanML3D's features") for path in statistics)
    if not (std > 0).all():
        raise ValueError(f"{statistics[1]}: {int((std <= 0).sum())} value(s) <= 0 (a standard deviation)")
    trained_null = float(imported.args.get("cond_mask_prob", 0.1)) > 0
    if not trained_null:
        log.warning("%s: cond_mask_prob 0: no null condition was trained; sampling without guidance (as "
                    "generate.py forces it)", imported.files.args)
    checks = DiffusionImportChecks()

    def measure(folder: Path) -> str:
        if not check_parity:
            return ""
        checks.parity = denoiser_parity(imported, folder)
        return checks.model_card_section()

    notes, training_data, license = release_notes(imported)
    notes += ("\n## Statistics and start\n\n"
              f"Frames de-normalised with `{statistics[0].name}` / `{statistics[1].name}` (HumanML3D's generation "
              "statistics, MDM's dataset/HumanML3D; not the evaluator's t2m_mean / t2m_std).")
    if c.pred_len:
        notes += (f" The first call continues `prefix.npy`: {c.context_len} frames of standing still made from the "
                  "mean frame (root and joint velocities 0, feet on the ground); the official code starts from a "
                  "random test-set clip and the published numbers from ground-truth prefixes.")
    notes += "\n"
    manifest = export_diffusion_bundle(
        out_dir, model=imported.model, mean=mean, std=std, text_source=text_source_of(imported),
        name=name or default_name(imported), version=version, training_data=training_data, license=license,
        default_guidance=GUIDANCE[imported.release] if trained_null else 1.0, unconditional_branch=trained_null,
        max_frames=DIP_MAX_FRAMES if c.pred_len else MDM_MAX_FRAMES,
        description=(f"{imported.release} (GuyTevet/motion-diffusion-model) imported from its released weights: "
                     "denoiser.onnx stepped by DDPM ancestral sampling, decoder.onnx de-normalises the frames."),
        notes=notes, checks=measure)
    return manifest, checks


def import_mdm(folder: str | Path | None, out_dir: str | Path, *, clip_file: str | Path | None = None,
               bert_dir: str | Path | None = None, model_file: str | Path | None = None,
               humanml3d: str | Path | None = None, mean: str | Path | None = None, std: str | Path | None = None,
               name: str | None = None, version: str = "1.0.0", check_parity: bool = True,
               allow_pickle: bool = False) -> tuple[dict, DiffusionImportChecks]:
    """An MDM release folder (+ ViT-B-32.pt or a DistilBERT folder, + HumanML3D's statistics) -> a bundle."""
    statistics = locate_statistics(humanml3d, mean, std)
    imported = load_mdm_release(folder, clip_file, bert_dir, model_file=model_file, allow_pickle=allow_pickle)
    return _export(imported, statistics, out_dir, name=name, version=version, check_parity=check_parity)


def import_dip(folder: str | Path | None, out_dir: str | Path, *, bert_dir: str | Path | None = None,
               model_file: str | Path | None = None, humanml3d: str | Path | None = None,
               mean: str | Path | None = None, std: str | Path | None = None, name: str | None = None,
               version: str = "1.0.0", check_parity: bool = True,
               allow_pickle: bool = False) -> tuple[dict, DiffusionImportChecks]:
    """A DiP release folder + a DistilBERT folder (+ HumanML3D's statistics) -> a bundle (standing first prefix)."""
    statistics = locate_statistics(humanml3d, mean, std)
    imported = load_dip_release(folder, bert_dir, model_file=model_file, allow_pickle=allow_pickle)
    return _export(imported, statistics, out_dir, name=name, version=version, check_parity=check_parity)
