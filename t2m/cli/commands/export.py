"""`t2m export`: a VQ run + a GPT run -> a verified model bundle (ONNX graphs, tokenizer, manifest, model card).

    t2m export --vq runs/vq --gpt runs/gpt --int8 text -o t2m/bundles/default

The GPT run's config.json tells the text encoder, the condition dropout (-> unconditional_branch) and the
data directory, whose summary.json gives the training data and its licence (or pass --data-summary).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("export", help="training runs -> ONNX model bundle for the service",
                                   description=(__doc__ or "").strip().splitlines()[0])
    parser.add_argument("--vq", type=Path, required=True, metavar="RUN", help="VQ-VAE run directory")
    parser.add_argument("--gpt", type=Path, required=True, metavar="RUN", help="GPT run directory")
    parser.add_argument("--text-encoder", choices=("minilm", "clip"), default=None,
                        help="text encoder (default: the one the GPT run was trained with)")
    parser.add_argument("--clip-weights", type=Path, default=None, metavar="PATH", help="local CLIP ViT-B/32 weights")
    parser.add_argument("--int8", choices=("none", "text", "gpt", "all"), default="none",
                        help="int8 dynamic quantisation of the text encoder and/or GPT step graph (default none)")
    parser.add_argument("--name", default=None, help="bundle name (default t2m-<data>-<text encoder>)")
    parser.add_argument("--version", default="0.1.0", help="bundle version (default 0.1.0)")
    parser.add_argument("--model-card", type=Path, default=None, metavar="FILE",
                        help="markdown appended to the generated MODEL_CARD.md")
    parser.add_argument("--data-summary", type=Path, default=None, metavar="FILE",
                        help="the training data's summary.json (default: DATA_DIR/summary.json of the GPT run)")
    parser.add_argument("--guidance", type=float, default=None,
                        help="default guidance scale (default 3.0 with a trained unconditional branch, else 1.0)")
    parser.add_argument("--skip-parity", action="store_true", help="do not compare onnxruntime with PyTorch")
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="DIR", help="bundle directory to write")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import logging

    from t2m.export.exporter import export_from_runs

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    manifest, checks = export_from_runs(
        args.vq, args.gpt, args.output, text_encoder=args.text_encoder, clip_weights=args.clip_weights,
        int8=args.int8, name=args.name, version=args.version, model_card=args.model_card,
        data_summary=args.data_summary, default_guidance=args.guidance, check_parity=not args.skip_parity,
    )
    print(json.dumps({"parity": checks.parity, "int8": checks.int8}, indent=2))
    total = sum(entry["bytes"] for entry in manifest["files"].values())
    print(f"bundle {manifest['name']} {manifest['version']} written to {args.output} ({total / 1e6:.1f} MB, verified)")
    return 0
