"""The model-card facts of an MDM / DiP import: the release's terms (code, text encoder, data), the published
anchors, what the import read, and what is exactly the release's computation and what cannot be.

Kept apart from the importers so the card writer (the family's bundle exporter) takes one readable text:
``release_notes(imported)`` -> (notes, training_data entry, licence line), as momask_card does for MoMask.
Sources: ../shared/docs/diffusion-models.md §4 (releases), §8 (published numbers), §9 (pitfalls), §10 (licences).
"""
from __future__ import annotations

from t2m.families.diffusion.mdm_files import ImportedDiffusion
from t2m.families.diffusion.text_encoders import MDM_MAX_TEXT_TOKENS, MdmClipEncoder

__all__ = ["CLIP_FP16", "CODE_LICENSES", "HUMANML3D", "PUBLISHED", "TEXT_LICENSES", "release_license",
           "release_notes", "training_data"]

CODE_LICENSES = {
    "MDM": "motion-diffusion-model (GuyTevet/motion-diffusion-model): MIT, Copyright (c) 2022 Guy Tevet",
    "DiP": ("motion-diffusion-model (GuyTevet/motion-diffusion-model): MIT, Copyright (c) 2022 Guy Tevet; CLoSD "
            "(GuyTevet/CLoSD, DiP's other home): MIT, 2024 Guy Tevet"),
}
TEXT_LICENSES = {
    "clip": "OpenAI CLIP ViT-B/32 (openai/CLIP): MIT, 2021 OpenAI",
    "distilbert": ("DistilBERT distilbert-base-uncased (Hugging Face): Apache-2.0, as its mirrors' model cards state "
                   "(the primary hub card was not read)"),
}
HUMANML3D = "HumanML3D / AMASS terms (non-commercial research use)"
WEIGHTS_TERMS = ("the checkpoints come with no separate terms in the README or DiP.md; the README adds that the "
                 "dependencies (CLIP, SMPL, ...) and the datasets have their own licences, which must be followed")
# published by the authors (RTX 3090; HumanML3D test set), not measured here
PUBLISHED = {
    "MDM": "MDM-50: 400 ms per sample at 50 steps (RTX 3090); HumanML3D R@1 0.455, FID 0.489",
    "DiP": "DiP: 11 ms per call of 40 frames, 3,500 frames/s (RTX 3090); HumanML3D R@1 0.458, FID 0.228, measured "
           "with ground-truth prefixes",
}
# Measured by tests/families/diffusion/test_diffusion_text.py (test_float16_vs_float32_at_the_released_size, slow
# suite):
# OpenAI's ViT-B/32 text tower at its size with random weights, MDM's float16 arithmetic emulated on the CPU
# (t2m.families.diffusion.text_encoders.clip_encode_text_fp16) vs float32; the GPU's half kernels round otherwise.
CLIP_FP16 = ("MDM computes CLIP in float16 (convert_weights); the service in float32. On a ViT-B/32-sized tower with "
             "random weights the text feature moves by max |diff| 4.3e-3 (features up to 4.2), cosine >= 0.999999 "
             "(MDM's float16 arithmetic emulated on the CPU); real weights were not measured")


def training_data() -> dict[str, str]:
    return {"name": "HumanML3D", "license": HUMANML3D,
            "attribution": ("Tevet et al., Human Motion Diffusion Model (ICLR 2023) and DiP (2025), released weights; "
                            "trained on HumanML3D (Guo et al., CVPR 2022), built on AMASS and HumanAct12.")}


def release_license(imported: ImportedDiffusion) -> str:
    """One line: the code's licence, the text encoder's, the data's terms, the weights' (none stated)."""
    text = "clip" if isinstance(imported.text, MdmClipEncoder) else "distilbert"
    return (f"{CODE_LICENSES[imported.release]}; text encoder {TEXT_LICENSES[text]}; trained on {HUMANML3D}; "
            f"{WEIGHTS_TERMS}")


def release_notes(imported: ImportedDiffusion) -> tuple[str, dict[str, str], str]:
    """(card notes in Markdown, training_data entry, licence line) for an import."""
    c, f = imported.config, imported.files
    clip = isinstance(imported.text, MdmClipEncoder)
    entry = {"model_avg": "`model_avg` (EMA; args.json says use_ema)", "model": "`model` (args.json: no use_ema)",
             "state dict": "the plain state dict"}[imported.entry]
    parameters = sum(p.numel() for p in imported.model.parameters())
    text = (f"OpenAI's CLIP ViT-B/32 text tower, the caption cut to {MDM_MAX_TEXT_TOKENS} BPE tokens (start + 20 + "
            "end token, as clip.tokenize(context_length=22, truncate=True)), the end token's feature, not normalised"
            if clip else
            f"DistilBERT (distilbert-base-uncased) token states, {imported.text.dim}-d, every token (no pooling), "
            "the padding masked in cross-attention; uncased WordPiece, [CLS] ... [SEP]; no truncation in the "
            f"official code, here at {imported.text.max_length} tokens (the learned positions)")
    lines = [
        "## Imported weights", "",
        f"Imported from {imported.release}'s release `{f.folder.name}/{f.model.name}` ({entry}) with its "
        "`args.json`; every tensor's name and shape checked, strict load; the positional tables recomputed and "
        "any `clip_model.*` tensors ignored, as the official loader does.", "",
        f"- denoiser: {c.arch}, {c.layers} layers, width {c.latent_dim}, feed-forward {c.ff_size}, {c.heads} heads, "
        f"GELU ({parameters:,} parameters; ff, heads, dropout and activation are the code's constants)",
        f"- diffusion: {c.diffusion_steps} DDPM steps (the trained number, no respacing), cosine schedule, x0 "
        "prediction, guidance uncond + s (cond - uncond) with the zeroed text as the null condition",
        "- frames: " + ("padded frames masked (mask_frames)" if c.mask_frames else
                        "no mask_frames: padded frames are attended to, as in the release (one length per batch)"),
        *([f"- prefix completion: {c.context_len} clean prefix frames, {c.pred_len} new frames per call"]
          if c.context_len else []),
        f"- text: {text}", "",
        "## Exactness", "",
        "The denoiser computes the release's forward pass (checked against torch's own transformer layers); the "
        "sampler is the official DDPM ancestral loop (float64 tables, FIXED_SMALL variance, no clipping).", "",
        "Not reproducible, and why:",
        f"- {CLIP_FP16};" if clip else
        "- DistilBERT: float32 as in the official code; batch padding changes states only at float rounding;",
        "- random draws: the official code draws torch's Gaussian noise, the service numpy's from each request's own "
        "generator: the same distributions, other draws (with injected noise both agree);",
        "",
        f"Published anchors (not measured here): {PUBLISHED[imported.release]}.",
    ]
    return "\n".join(lines) + "\n", training_data(), release_license(imported)
