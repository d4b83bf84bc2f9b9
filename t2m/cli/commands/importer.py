"""`t2m import t2m-gpt`: the released T2M-GPT checkpoints -> a verified model bundle.

    t2m import t2m-gpt --vq net_last.pth --gpt net_best_fid.pth --mean mean.npy --std std.npy \
        --clip ViT-B-32.pt -o models/t2m-gpt

Sizes are read from tensor shapes; attention heads are assumed to be embed / 64 (16 for the release) unless
--heads is given. The text encoder is OpenAI's CLIP ViT-B/32 from --clip ViT-B-32.pt (the TorchScript file that
OpenAI's clip.load downloads, or a state dict in its key layout); --text-encoder-bundle DIR reuses the 512-d text
graph and tokenizer of an existing bundle instead (e.g. an earlier import).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path


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
    t2m.add_argument("--clip", type=Path, default=None, metavar="ViT-B-32.pt",
                     help="OpenAI's CLIP ViT-B/32 weights (local file)")
    t2m.add_argument("--text-encoder-bundle", type=Path, default=None, metavar="DIR",
                     help="reuse text_encoder.onnx + tokenizer.json of this bundle instead of --clip")
    t2m.add_argument("--heads", type=int, default=None, help="attention heads (default embed / 64)")
    t2m.add_argument("--int8", choices=("none", "text", "gpt", "all"), default="none")
    t2m.add_argument("--name", default="t2m-gpt-humanml3d")
    t2m.add_argument("--version", default="1.0.0")
    t2m.add_argument("--allow-pickle", action="store_true",
                     help="load checkpoints that hold more than tensors with the full unpickler (trusted files only)")
    t2m.add_argument("--skip-parity", action="store_true", help="do not compare onnxruntime with PyTorch")
    t2m.add_argument("-o", "--output", type=Path, required=True, metavar="DIR", help="bundle directory to write")
    t2m.set_defaults(func=run_t2m_gpt)


def run_t2m_gpt(args: argparse.Namespace) -> int:
    import logging

    from t2m.export.t2m_gpt_import import import_t2m_gpt

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    manifest, checks = import_t2m_gpt(
        args.vq, args.gpt, args.mean, args.std, args.output, clip_weights=args.clip,
        text_encoder_bundle=args.text_encoder_bundle, heads=args.heads, name=args.name, version=args.version,
        int8=args.int8, check_parity=not args.skip_parity, allow_pickle=args.allow_pickle,
    )
    print(json.dumps({"parity": checks.parity, "int8": checks.int8}, indent=2))
    gpt = manifest["gpt"]
    print(f"imported T2M-GPT ({gpt['n_layer']} layers, {gpt['n_head']} heads x {gpt['head_dim']}) into {args.output}"
          " (verified)")
    return 0
