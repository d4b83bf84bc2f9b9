"""The model card text of a MoGenTS import: the source files, the sizes read from them, the release's settings,
which of the release's quirks are kept and why, what cannot be exact, and the release's terms.

Kept apart from the importer so the statement of exactness is one readable text (t2m/families/masked/README.md repeats
it).
"""
from __future__ import annotations

from t2m.families.masked.export import MaskedDecoding
from t2m.families.masked.import_momask import release_top_k
from t2m.families.masked.mogents_files import DEMO_STEPS, ImportedMogents
from t2m.families.masked.momask_card import release_file, trained_parameters
from t2m.families.masked.momask_files import kit_fps_note

RELEASE_LICENSE = ("MoGenTS's release terms: its code is distributed under the MIT licence and the weights come "
                   "with it without separate terms; its README adds that the datasets it uses have their own "
                   "licences, which must be followed (HumanML3D / AMASS: non-commercial research use)")
TRAINING_DATA = {
    "HumanML3D": {"name": "HumanML3D", "license": "HumanML3D / AMASS terms (non-commercial research use)",
                  "attribution": ("Yuan et al., MoGenTS (NeurIPS 2024), released weights; trained on HumanML3D "
                                  "(Guo et al., CVPR 2022), built on AMASS and HumanAct12.")},
    "KIT-ML": {"name": "KIT-ML", "license": "KIT Motion-Language dataset terms (research use)",
               "attribution": ("Yuan et al., MoGenTS (NeurIPS 2024), released weights; trained on KIT-ML (Plappert "
                               "et al., 2016) in HumanML3D's feature layout.")},
}
# Measured by tests/families/masked/test_mogents_import.py::test_full_release_sizes_match_the_reference (slow suite) at
# the
# released sizes with random weights, against tests/families/masked/mogents_reference.py (an independent
# re-implementation
# of MoGenTS's forward passes, quirks included, and its generate loops): see t2m/families/masked/README.md.
VERIFIED = ("at the released sizes with random weights, logits of the imported modules vs the reference max |diff| "
            "3.0e-6 (ts mask, logits up to 2.9), 9.2e-6 (ts residual, up to 8.5), 2.3e-6 (aux mask), 6.8e-6 (aux "
            "residual), of the ONNX graphs 4.0e-6, 8.6e-6, 3.1e-6, 9.1e-6; the service's token maps over the graphs "
            "vs the reference `generate` loops at top-k 1: lengths 49 and 1 identical, length 37 one token of 1554 "
            "in the last residual layer (a float-rounding tie), at small sizes every map identical (also a "
            "residual stage that draws the mask id); decoded features vs the reference fused decode 1.9e-5")




def release_notes(models: ImportedMogents, decoding: MaskedDecoding, heads: int) -> tuple[str, dict[str, str], str]:
    """(card notes, training_data entry, licence) for an import."""
    f, v, k = models.files, models.vq.config, models.keys
    rows = [("fused VQ-VAE", f.vq, k["vq"], models.vq),
            ("ts mask transformer (2D)", f.masked, k["masked"], models.masked),
            ("aux mask transformer (1D)", f.masked, k["masked_aux"], models.masked_aux),
            ("ts residual transformer (2D)", f.residual, k["residual"], models.residual),
            ("aux residual transformer (1D)", f.residual, k["residual_aux"], models.residual_aux)]
    if models.length is not None and f.length is not None:
        rows.append(("length estimator", f.length, k["length"], models.length))
    m = models.masked.config
    length_line = (f.missing_length_note() or "") if models.length is None else (
        "- free length: the length estimator, sampled over 1..49 rows (see below)")
    lines = [
        "## Imported weights", "",
        f"Imported from MoGenTS's released checkpoints ({f.dataset}) with `t2m import mogents`; every tensor's "
        "name and shape checked, strict loads.", "",
        "| network | file | key | parameters |", "| --- | --- | --- | --- |",
        *[f"| {role} | `{release_file(path)}` | `{key}` | {trained_parameters(module):,} |"
          for role, path, key, module in rows],
        f"| de-normalisation | `{f.mean.parent.parent.name}/meta/{f.mean.name}`, `{f.std.name}` | | |", "",
        f"- fused VQ-VAE: width {v.width}; 2D branch {v.residual_layers} codebooks of {v.nb_code} x {v.code_dim}"
        f" over {v.columns} joint columns, `linear_merge` per time step; 1D branch {v.residual_layers} codebooks"
        f" of {v.nb_code1d} x {v.code_dim1d}; `linear_out` fuses both decoders' features; time / "
        f"{v.frames_per_token}; dilation growth {v.dilation_growth} (release value, not stored)",
        f"- transformers: {m.n_layer} layers per stack (2D: joint-time, spatial, temporal stacks), width {m.latent},"
        f" feed-forward {m.ff_size}, {heads} attention heads ("
        f"{'the release value: not stored in the weights' if heads == 6 else 'given with --heads'})",
        f"- at most {m.max_tokens} token rows (196 frames); positional tables read from each checkpoint "
        "(`position2d_enc.pe` cut to the rows and columns a map has; the aux models' LEARNED `position_enc.pe`)",
        "- de-normalisation with the VQ's meta mean/std", length_line,
        *([f"- {kit}"] if (kit := kit_fps_note(f.dataset)) else []), "",
        "## Decoding: the release's settings", "",
        f"Two generators per segment on the same rows: the 2D map (ts) and the 1D tokens (aux), then one fused"
        f" decode. {decoding.steps} re-masking steps (MoGenTS's evaluation; its demo runs the option default"
        f" {DEMO_STEPS}), guidance {decoding.guidance:g} on both mask stages (a request's default) and"
        f" {decoding.residual_guidance:g} on both residual stages, top-k ceil((1 - 0.9) V): {decoding.top_k} of"
        f" {v.nb_code} and {decoding.residual_top_k} of {v.nb_code + 2} (ts), {release_top_k(v.nb_code1d)} of"
        f" {v.nb_code1d} and {release_top_k(v.nb_code1d + 1)} of {v.nb_code1d + 1} (aux); temperature 1 in every"
        " stage whatever a request asks"
        " (MoGenTS's mask sampler divides normalised probabilities by it, which has no effect; its residual"
        " stages sample at 1).", "",
        "## The release's quirks: kept, and why", "",
        "The served model computes what the released one computes, so the quirks that change its outputs are"
        " reproduced (the weights were trained with them):",
        "- the 2D mask transformer's temporal stack cannot attend to the text row (an in-place write into a view"
        " of the padding mask marks it as padding); the residual model's can;",
        "- the 2D residual transformer's spatial stack adds positions from row 0 (not after its two prefix rows)"
        " and lays its output out without the transpose back, so each output lands on another (time, column)"
        " slot. In MoGenTS that layout depends on the batch; it is reproduced as the demo runs it, one motion per"
        " call (B = 1, no padding): slot t' 6 + j' receives the output of (t, j) = (n mod L, n div L), n = t' 6 +"
        " j', L the motion's rows. Every segment is computed so, whatever shares its batch here; MoGenTS's"
        " evaluation batches (B = 32, padded) mix motions and cannot be served per request;",
        "- the spatial stacks run only on real rows (MoGenTS selects them with nonzero): here every row runs and"
        " padded rows keep their input (mask model) or add zero (residual model), the same values with static"
        " shapes;",
        "- the 2D residual model scores 258 classes: a drawn pad (257) is an unused layer (-1, a zero vector at"
        " decode); a drawn mask id (256) stays in the map and its embedding enters the next layer, and a motion"
        " whose map holds one is clipped to [0, 255] at the end (-1 becomes 0 too), per segment as MoGenTS clips"
        " the one motion of its call.", "",
        "## Exactness", "",
        "Also MoGenTS's computation: classifier-free guidance as uncond + s (cond - uncond) with the null text ="
        " zeros; the float32 cosine schedule over the flattened map (rows x 6 tokens; the aux branch rows x 1);"
        " confidence = softmax of the unfiltered guided logits at the drawn code; tokens not re-masked in a step"
        " frozen; the fused decode (1D RVQ decode, 2D codes summed per column, `linear_merge`, the 2D decoder, the"
        " joint crop and jmotion assembly, `linear_out`) and the de-normalisation.", "",
        f"Verified against an independent re-implementation of MoGenTS's modules (quirks included) and generate"
        f" loops: {VERIFIED}.", "",
        "Not reproducible, and why:",
        "- random draws: MoGenTS samples with torch's Categorical and Gumbel noise from torch's generator, the"
        " service with one numpy uniform per token from each request's own generator (both branches draw from"
        " it, the ts branch first): the same distributions, other draws (at top-k 1 both are deterministic and"
        " agree);",
        "- batches of several motions in MoGenTS (its evaluation, a demo prompt file): the 2D residual layout"
        " mixes them (see above); here every segment is computed as a motion generated alone;",
        "- free length: the estimator can draw 0 rows in MoGenTS; here 1..49 are drawn in proportion to its"
        " probabilities;",
        "- text features: MoGenTS casts CLIP to float16 on every device; here float32;",
        "- ties: equal confidences are ordered by torch's unstable sort in MoGenTS, by position here; values closer"
        " than float rounding (about 1e-6 between PyTorch and onnxruntime) may go either way;",
        "- streams of several segments are the service's: each segment is generated as one MoGenTS motion, the"
        " maps concatenated and decoded once.",
    ]
    return "\n".join(lines) + "\n", dict(TRAINING_DATA.get(f.dataset, TRAINING_DATA["HumanML3D"])), RELEASE_LICENSE
