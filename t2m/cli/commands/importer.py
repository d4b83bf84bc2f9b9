"""`t2m import t2m-gpt` / `momask` / `mogents`: released checkpoints -> a verified model bundle.

    t2m import t2m-gpt --vq net_last.pth --gpt net_best_fid.pth --mean mean.npy --std std.npy \
        --clip ViT-B-32.pt -o models/t2m-gpt

Sizes are read from tensor shapes; attention heads are assumed to be embed / 64 (16 for the release) unless
--heads is given. The text encoder is OpenAI's CLIP ViT-B/32 from --clip ViT-B-32.pt (the TorchScript file that
OpenAI's clip.load downloads, or a state dict in its key layout); --text-encoder-bundle DIR reuses the 512-d text
graph and tokenizer of an existing bundle instead (e.g. an earlier import).

    t2m import momask checkpoints/t2m --clip ViT-B-32.pt -o models/momask

reads MoMask's release as it unpacks (t2m/families/masked/README.md "Importing MoMask"); --vq/--mean/--std/--masked/
--residual/--length name single files instead.

    t2m import mogents logs/humanml3d --clip ViT-B-32.pt -o models/mogents

reads MoGenTS's release likewise (t2m/families/masked/README.md "Importing MoGenTS"), with the same file options.

    t2m import mdm save/humanml_trans_enc_512 --clip ViT-B-32.pt --humanml3d dataset/HumanML3D -o models/mdm
    t2m import dip save/DiP_no-target_10steps_context20_predict40 --bert distilbert-base-uncased \
        --humanml3d dataset/HumanML3D -o models/dip

read MDM's and DiP's release folders (args.json + model<step>.pt; t2m/families/diffusion/README.md "Importing MDM and
DiP"): the CLIP file for MDM's CLIP releases, a Hugging Face distilbert-base-uncased folder for the DistilBERT ones
and DiP, and HumanML3D's Mean.npy / Std.npy (not in the release folder).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("import", help="import released checkpoints of other projects as a bundle")
    sources = parser.add_subparsers(dest="import_source", metavar="SOURCE")
    parser.set_defaults(func=lambda args: parser.print_help() or 2)
    t2m = sources.add_parser("t2m-gpt", help="T2M-GPT (net_last.pth + net_best_fid.pth)",
                             description=(__doc__ or "").strip().splitlines()[0])
    t2m.add_argument("--vq", type=Path, required=True, metavar="net_last.pth", help="VQ-VAE checkpoint {'net': ...}")
    t2m.add_argument("--gpt", type=Path, required=True, metavar="net_best_fid.pth",
                     help="GPT checkpoint {'trans': ...}")
    t2m.add_argument("--mean", type=Path, required=True, help="mean.npy used to de-normalise (evaluator meta)")
    t2m.add_argument("--std", type=Path, required=True, help="std.npy used to de-normalise (evaluator meta)")
    t2m.add_argument("--text-encoder-bundle", type=Path, default=None, metavar="DIR",
                     help="reuse text_encoder.onnx + tokenizer.json of this bundle instead of --clip")
    t2m.add_argument("--heads", type=int, default=None, help="attention heads (default embed / 64)")
    t2m.add_argument("--int8", choices=("none", "text", "gpt", "all"), default="none")
    t2m.add_argument("--name", default="t2m-gpt-humanml3d")
    t2m.add_argument("--cuda-graph-step", action="store_true",
                     help="also write gpt_step_fixed.onnx, the step over a fixed-capacity cache that "
                          "T2M_CUDA_GRAPHS=true replays on a GPU (float32; a second copy of the GPT's weights)")
    add_common_options(t2m)
    t2m.set_defaults(func=run_t2m_gpt)
    register_momask(sources)
    register_diffusion(sources)


def add_common_options(parser: argparse.ArgumentParser, clip: bool = True) -> None:
    """The options every importer has: the CLIP file (``clip``), the bundle's version, pickles, parity, the output
    folder."""
    if clip:
        parser.add_argument("--clip", type=Path, default=None, metavar="ViT-B-32.pt",
                            help="OpenAI's CLIP ViT-B/32 weights (local file)")
    parser.add_argument("--version", default="1.0.0")
    parser.add_argument("--allow-pickle", action="store_true",
                        help="load checkpoints holding more than tensors with the full unpickler (trusted files only)")
    parser.add_argument("--skip-parity", action="store_true", help="do not compare onnxruntime with PyTorch")
    parser.add_argument("--quantize", choices=("int8", "int4", "fp16"), default=None,
                        help="quantise the token graphs after the float32 import and measure them against it as "
                             "served (the card says what and how close): int8 (dynamic, 7-bit weights: fastest on "
                             "CPUs), int4 (MatMulNBits weights), fp16 (for GPUs); as `t2m quantize --scheme`")
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="DIR", help="bundle directory to write")


FILE_ROLES = ("vq", "mean", "std", "masked", "residual", "length")
RELEASES = {
    "momask": ("MoMask (checkpoints/t2m: RVQ-VAE, masked + residual transformers, length estimator)",
               "Import MoMask's released checkpoints as a masked-family bundle with the release's decoding settings "
               "(10 steps, guidance 4 and 5, top-k 10%).",
               "CHECKPOINTS_DIR", "MoMask's checkpoints/t2m (or checkpoints/kit) folder as the release unpacks it",
               ("rvq_*/model/net_best_fid.tar", "rvq_*/meta/mean.npy", "rvq_*/meta/std.npy",
                "t2m_nlayer8_*/model/latest.tar", "tres_nlayer8_*/model/net_best_fid.tar",
                "length_estimator/model/finest.tar")),
    "mogents": ("MoGenTS (logs/humanml3d: fused VQ-VAE, 2D + 1D mask and residual transformers, length estimator)",
                "Import MoGenTS's released checkpoints (both branches and the fusion) as a masked-family bundle "
                "with the release's decoding settings (10 steps, guidance 4 and 5, top-k 10%) and its quirks.",
                "LOGS_DIR", "MoGenTS's logs/humanml3d (or logs/kit) folder as the release unpacks it",
                ("pretrain_vq/model/net_best_fid.tar", "pretrain_vq/meta/mean.npy", "pretrain_vq/meta/std.npy",
                 "pretrain_mtrans/model/net_best_fid.tar (else latest.tar)",
                 "pretrain_rtrans/model/net_best_fid.tar (else latest.tar)",
                 "../../checkpoints/<LOGS_DIR name>/length_estimator/model/finest.tar")),
}


def register_momask(sources: argparse._SubParsersAction) -> None:
    """`t2m import momask` and `t2m import mogents`: a release folder, one option per file."""
    for release, (summary, description, folder, folder_help, defaults) in RELEASES.items():
        parser = sources.add_parser(release, help=summary, description=description)
        parser.add_argument("checkpoints", type=Path, nargs="?", default=None, metavar=folder, help=folder_help)
        files = parser.add_argument_group("files (each overrides the folder lookup)")
        for flag, default in zip(FILE_ROLES, defaults):
            files.add_argument(f"--{flag}", type=Path, default=None, metavar="FILE", help=f"default: {default}")
        parser.add_argument("--heads", type=int, default=6,
                            help="attention heads (not stored in the weights; release: 6)")
        parser.add_argument("--name", default=None, help=f"bundle name (default {release}-humanml3d / {release}-kit)")
        add_common_options(parser)
        parser.set_defaults(func=run_momask if release == "momask" else run_mogents)


def run_momask(args: argparse.Namespace) -> int:
    from t2m.families.masked.import_momask import import_momask

    return _run_release("MoMask", import_momask, args)


def run_mogents(args: argparse.Namespace) -> int:
    from t2m.families.masked.import_mogents import import_mogents

    return _run_release("MoGenTS", import_mogents, args)


def _run_release(release: str, importer, args: argparse.Namespace) -> int:
    import logging

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    files = {role: getattr(args, role) for role in FILE_ROLES}
    manifest, checks = importer(args.checkpoints, args.output, clip_weights=args.clip, files=files,
                                heads=args.heads, name=args.name, version=args.version,
                                check_parity=not args.skip_parity, allow_pickle=args.allow_pickle,
                                quantize=args.quantize)
    print(json.dumps({"parity": checks.parity, **_quantization(checks)}, indent=2))
    _report(release, manifest, args.output, args)
    return 0


def _quantization(checks: Any) -> dict[str, Any]:
    return {} if checks.quantization is None else {"quantization": checks.quantization}


RECOMMENDATION = ("recommended: import with `--quantize int8` (or run `t2m quantize {output} -o DIR`): int8 weights "
                  "make the token graphs about 4x smaller and faster on CPUs, and the copy's card records its token "
                  "agreement and logit difference against the float32 import")


def _report(release: str, manifest: dict, output: Path, args: argparse.Namespace) -> None:
    """One line: what was imported, in its family's words, and where; after a float32 import, one more line
    recommending int8."""
    from t2m.bundle import get_family, parse_manifest

    typed = parse_manifest(manifest)
    family = get_family(typed.family)
    line = family.describe(typed, typed.default_guidance)
    quantised = ", ".join(f"{name} {manifest['quantization'][Path(name).stem]}"
                          for name in family.quantizable_graphs(manifest)
                          if (manifest.get("quantization") or {}).get(Path(name).stem))
    print(f"imported {release} ({line}; {typed.residual_layers} quantiser layer(s), at most {typed.max_tokens} "
          f"token rows) into {output} (verified{'; ' + quantised if quantised else ''})")
    if args.quantize is None:
        print(RECOMMENDATION.format(output=output))


def run_t2m_gpt(args: argparse.Namespace) -> int:
    import logging

    from t2m.families.gpt.import_t2m_gpt import import_t2m_gpt

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    manifest, checks = import_t2m_gpt(
        args.vq, args.gpt, args.mean, args.std, args.output, clip_weights=args.clip,
        text_encoder_bundle=args.text_encoder_bundle, heads=args.heads, name=args.name, version=args.version,
        int8=args.int8, check_parity=not args.skip_parity, allow_pickle=args.allow_pickle, quantize=args.quantize,
        fixed_step=args.cuda_graph_step,
    )
    print(json.dumps({"parity": checks.parity, "int8": checks.int8, **_quantization(checks)}, indent=2))
    _report("T2M-GPT", manifest, args.output, args)
    return 0


DIFFUSION = {
    "mdm": ("MDM (save/<name>: args.json + model<step>.pt; the paper model, the 50-step and DistilBERT variants)",
            "Import an MDM release folder as a diffusion-family bundle: the trained number of DDPM steps, guidance "
            "2.5; CLIP releases need --clip, the DistilBERT variant --bert."),
    "dip": ("DiP (DiP_no-target_10steps_context20_predict40: args.json + model<step>.pt, DistilBERT)",
            "Import DiP's release folder as a diffusion-family bundle: 40-frame calls after 20 frames in 10 steps, "
            "guidance 7.5, starting from a standing pose (prefix.npy)."),
}


def register_diffusion(sources: argparse._SubParsersAction) -> None:
    """`t2m import mdm` and `t2m import dip`: a release folder, its text encoder, HumanML3D's statistics."""
    for release, (summary, description) in DIFFUSION.items():
        parser = sources.add_parser(release, help=summary, description=description)
        parser.add_argument("release", type=Path, nargs="?", default=None, metavar="FOLDER",
                            help="the release folder (the official save/<name>/: args.json, model<step>.pt)")
        parser.add_argument("--model", type=Path, default=None, metavar="FILE",
                            help="the weights file, when the folder holds several model<step>.pt")
        if release == "mdm":
            parser.add_argument("--clip", type=Path, default=None, metavar="ViT-B-32.pt",
                                help="OpenAI's CLIP ViT-B/32 weights (CLIP releases)")
        parser.add_argument("--bert", type=Path, default=None, metavar="DIR",
                            help="a Hugging Face distilbert-base-uncased folder (DistilBERT releases"
                                 + (")" if release == "mdm" else "; required)"))
        stats = parser.add_argument_group("HumanML3D's generation statistics (not in the release folder)")
        stats.add_argument("--humanml3d", type=Path, default=None, metavar="DIR",
                           help="HumanML3D's folder with Mean.npy and Std.npy (MDM's dataset/HumanML3D)")
        stats.add_argument("--mean", type=Path, default=None, metavar="Mean.npy", help="overrides the folder's")
        stats.add_argument("--std", type=Path, default=None, metavar="Std.npy", help="overrides the folder's")
        parser.add_argument("--name", default=None,
                            help="bundle name (default mdm-humanml3d-<steps>steps[-distilbert] / dip-humanml3d)")
        add_common_options(parser, clip=False)
        parser.set_defaults(func=run_diffusion, import_release=release)


def run_diffusion(args: argparse.Namespace) -> int:
    import logging

    from t2m.families.diffusion.importer import import_dip, import_mdm

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    common = {"bert_dir": args.bert, "model_file": args.model, "humanml3d": args.humanml3d, "mean": args.mean,
              "std": args.std, "name": args.name, "version": args.version, "check_parity": not args.skip_parity,
              "allow_pickle": args.allow_pickle}
    from t2m.export.importers.kit import import_quantized

    def write(out: Path) -> tuple[dict, Any]:
        if args.import_release == "mdm":
            return import_mdm(args.release, out, clip_file=args.clip, **common)
        return import_dip(args.release, out, **common)

    manifest, checks = import_quantized(args.output, args.quantize, write)
    print(json.dumps({"parity": checks.parity, **_quantization(checks)}, indent=2))
    from t2m.bundle import get_family, parse_manifest

    typed = parse_manifest(manifest)
    line = get_family(typed.family).describe(typed, typed.default_guidance)
    quantised = (manifest.get("quantization") or {}).get("denoiser")
    print(f"imported {manifest['name']} ({line}; at most {typed.max_tokens} frames a sentence) into {args.output} "
          f"(verified{'; denoiser.onnx ' + quantised if quantised else ''})")
    if args.quantize is None:
        print(DIFFUSION_NOTE.format(output=args.output))
    return 0


DIFFUSION_NOTE = ("int8 (`--quantize int8`, or `t2m quantize {output} -o DIR`) made a released-size denoiser call "
                  "1.5-3.7x faster on a 2-core CPU (docs/serving-released-models.md); it moves the motion, and its "
                  "effect on a real release's quality is not measured: the copy's card records how far its joints "
                  "moved from this import's")
