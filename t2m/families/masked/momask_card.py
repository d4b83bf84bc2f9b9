"""The model card text of a MoMask import: the source files, the sizes read from them, the release's settings, what is
exactly MoMask's computation and what cannot be, and the release's terms.

Kept apart from the importer so the statement of exactness is one readable text (t2m/families/masked/README.md repeats
it).
"""
from __future__ import annotations

from pathlib import Path

from torch import nn

from t2m.families.masked.export import MaskedDecoding
from t2m.families.masked.momask_files import ImportedMomask, kit_fps_note

RELEASE_LICENSE = ("MoMask's release terms: its code is MIT-licensed (Chuan Guo, 2023) and the weights come with it "
                   "without separate terms; its README adds that the datasets have their own licences, which must "
                   "be followed (HumanML3D / AMASS: non-commercial research use)")
TRAINING_DATA = {
    "HumanML3D": {"name": "HumanML3D", "license": "HumanML3D / AMASS terms (non-commercial research use)",
                  "attribution": ("Guo et al., MoMask (CVPR 2024), released weights; trained on HumanML3D (Guo et al., "
                                  "CVPR 2022), built on AMASS and HumanAct12.")},
    "KIT-ML": {"name": "KIT-ML", "license": "KIT Motion-Language dataset terms (research use)",
               "attribution": ("Guo et al., MoMask (CVPR 2024), released weights; trained on KIT-ML (Plappert et al., "
                               "2016) in HumanML3D's feature layout.")},
}
# Measured by tests/families/masked/test_momask_import.py::test_full_release_sizes_match_the_reference (slow suite) at
# the
# released sizes with random weights, against tests/families/masked/momask_reference.py (an independent
# re-implementation
# of MoMask's modules and generate loops): see t2m/families/masked/README.md "Importing MoMask".
VERIFIED = ("at the released sizes with random weights, logits of the imported modules vs the reference max |diff| "
            "2.7e-6 (masked, logits up to 3.5) and 9.7e-6 (residual, up to 9.1), of the ONNX graphs 3.0e-6 and 1.0e-5; "
            "the service's token maps over the graphs identical to the reference `generate` at top-k 1 (lengths 49, "
            "37, 1; at small sizes also 12, 7, 2 and a residual stage that draws pad); decoded features vs the "
            "reference RVQ decode 7.4e-6")


def trained_parameters(module: nn.Module) -> int:
    """Trained parameters (as the facts count them): codebooks and sinusoidal positional tables are buffers."""
    return sum(parameter.numel() for parameter in module.parameters())


def release_file(path: Path) -> str:
    """A release file as the card names it: run folder / subfolder / file."""
    return f"{path.parent.parent.name}/{path.parent.name}/{path.name}"


def release_notes(models: ImportedMomask, decoding: MaskedDecoding, heads: int) -> tuple[str, dict[str, str], str]:
    """(card notes, training_data entry, licence) for an import."""
    f, m, r = models.files, models.masked.config, models.residual.config
    rows = [("RVQ-VAE", f.vq, models.keys["vq"], models.vq), ("masked transformer", f.masked, models.keys["masked"],
            models.masked), ("residual transformer", f.residual, models.keys["residual"], models.residual)]
    if models.length is not None and f.length is not None:
        rows.append(("length estimator", f.length, models.keys["length"], models.length))
    v = models.vq.config
    length_line = (f.missing_length_note() or "") if models.length is None else (
        "- free length: MoMask's length estimator, sampled over 1..49 rows (see below)")
    lines = [
        "## Imported weights", "",
        f"Imported from MoMask's released checkpoints ({f.dataset}) with `t2m import momask`; every tensor's name and "
        "shape checked, strict loads.", "",
        "| network | file | key | parameters |", "| --- | --- | --- | --- |",
        *[f"| {role} | `{release_file(path)}` | `{key}` | {trained_parameters(module):,} |"
          for role, path, key, module in rows],
        f"| de-normalisation | `{f.mean.parent.parent.name}/meta/{f.mean.name}`, `{f.std.name}` | | |", "",
        f"- RVQ-VAE: width {v.width}, code dim {v.code_dim}, {v.residual_layers} codebooks of {v.nb_code} codes"
        f" (buffers, besides the parameters above), time / {v.frames_per_token}; residual-block dilation growth"
        f" {v.dilation_growth} (release value, not stored)",
        f"- transformers: {m.n_layer} layers, width {m.latent}, feed-forward {m.ff_size}, {heads} attention heads"
        f" ({'the release value: not stored in the weights' if heads == 6 else 'given with --heads'}); residual: "
        f"{r.n_layer} layers, share-weight tables",
        f"- at most {m.max_tokens} token rows (196 frames, the release's max_motion_length); positional table read"
        " from each checkpoint's `position_enc.pe` (its first rows), not regenerated",
        "- de-normalisation with the VQ's meta mean/std (std divided by 5 on the root and foot-contact dims, as"
        " MoMask de-normalises its output)",
        length_line, *([f"- {kit}"] if (kit := kit_fps_note(f.dataset)) else []), "",
        "## Decoding: the release's settings", "",
        f"{decoding.steps} re-masking steps, guidance {decoding.guidance:g} on the mask stage (a request's default) and"
        f" {decoding.residual_guidance:g} on the residual stage, top-k {decoding.top_k} of {v.nb_code} and"
        f" {decoding.residual_top_k} of {v.nb_code + 1} (ceil((1 - 0.9) V)), temperature 1 (the residual stage stays"
        " at 1 whatever a request asks, as in MoMask).", "",
        "## Exactness", "",
        "Computed as MoMask computes it: the modules' forward passes (post-LN encoder, the text row without"
        " positions, the checkpoint's positional table, the share-weight tables); classifier-free guidance as"
        " uncond + s (cond - uncond) with the null text = zeros; the float32 cosine schedule of re-masked counts (as"
        " torch rounds it); confidence = softmax of the unfiltered guided logits at the drawn code; tokens not"
        " re-masked in a step frozen; a drawn pad in the residual stage = an unused layer (-1, a zero vector at"
        " decode) whose pad embedding enters the next layer's input; the RVQ decode and de-normalisation.",
        "",
        f"Verified against an independent re-implementation of MoMask's modules and generate loops: {VERIFIED}.",
        "",
        "Not reproducible, and why:",
        "- random draws: MoMask samples with torch's Categorical and Gumbel noise from torch's generator, the service"
        " with one numpy uniform per token from each request's own generator: the same distributions, other draws,"
        " so a seed here does not give a seeded MoMask run's motion (at top-k 1 both are deterministic and agree);",
        "- free length: MoMask's estimator can draw 0 rows (and then attends over nothing); here 0 is excluded and"
        " 1..49 are drawn in proportion to MoMask's probabilities;",
        "- text features: MoMask runs CLIP in float16 on a GPU (float32 on a CPU); here float32, i.e. MoMask's CPU"
        " features;",
        "- a request temperature other than 1: MoMask's categorical sampler ignores its temperature (it divides"
        " already normalised probabilities); the service applies it to the mask stage's logits;",
        "- ties: MoMask orders equal confidences by torch's unstable sort (an order that differs between CPU and"
        " GPU), the service by position; and two confidences or logits closer than float rounding (about 1e-6"
        " between PyTorch and onnxruntime) may be ordered either way; torch's top-k keeps exactly k classes, the"
        " service every class equal to the k-th largest;",
        "- streams of several segments are the service's: each segment is generated as MoMask generates one motion,"
        " the maps are concatenated and decoded once (MoMask decodes each motion alone).",
    ]
    return "\n".join(lines) + "\n", dict(TRAINING_DATA.get(f.dataset, TRAINING_DATA["HumanML3D"])), RELEASE_LICENSE
