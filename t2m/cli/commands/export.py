"""`t2m export`: a VQ run + a GPT run -> a verified model bundle (ONNX graphs, tokenizer, manifest, model card).

    t2m export --vq runs/vq --gpt runs/gpt --int8 text -o t2m/bundles/default
    t2m export --family masked --vq runs/joint_vq --masked runs/masked --residual runs/residual \
        [--length runs/length] -o DIR
    t2m export --family hifigpt --vq runs/rvq --hifigpt runs/hifigpt [--guidance 3] -o DIR

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
    parser.add_argument("--family", choices=("gpt", "masked", "hifigpt"), default="gpt",
                        help="model family (default gpt; masked: MoMask / MoGenTS token maps; hifigpt: T2M-HiFiGPT's "
                             "double-tier GPT over residual codes)")
    parser.add_argument("--hifigpt", type=Path, default=None, metavar="RUN",
                        help="HiFiGPT run directory (family hifigpt; --vq is its residual VQ)")
    parser.add_argument("--gpt", type=Path, default=None, metavar="RUN", help="GPT run directory (family gpt)")
    parser.add_argument("--masked", type=Path, default=None, metavar="RUN", help="masked run directory (family masked)")
    parser.add_argument("--residual", type=Path, default=None, metavar="RUN",
                        help="residual run directory (family masked, a VQ with more than one layer)")
    parser.add_argument("--length", type=Path, default=None, metavar="RUN",
                        help="length estimator run directory (family masked, optional: null durations)")
    parser.add_argument("--steps", type=int, default=10, help="family masked: re-masking steps (default 10)")
    parser.add_argument("--residual-guidance", type=float, default=5.0,
                        help="family masked: the residual stage's guidance scale (default 5.0)")
    parser.add_argument("--top-k", type=int, default=None, metavar="K",
                        help="family masked: sample the mask stage from the K likeliest codes (MoMask's and MoGenTS's "
                             "eval: 10%% of the codebook; default: all codes)")
    parser.add_argument("--residual-top-k", type=int, default=None, metavar="K",
                        help="family masked: the residual stage's top-k (default: all codes)")
    parser.add_argument("--text-encoder", choices=("minilm", "clip"), default=None,
                        help="text encoder (default: the one the GPT run was trained with)")
    parser.add_argument("--clip-weights", type=Path, default=None, metavar="PATH", help="local CLIP ViT-B/32 weights")
    parser.add_argument("--int8", default="none", metavar="GRAPHS",
                        help="int8 dynamic quantisation: none (default), all, or the graphs comma-separated; family "
                             "gpt: text or gpt; family masked: text, masked, residual; family hifigpt: text, "
                             "temporal, residual")
    parser.add_argument("--name", default=None, help="bundle name (default t2m-<data>-<text encoder>)")
    parser.add_argument("--version", default="0.1.0", help="bundle version (default 0.1.0)")
    parser.add_argument("--model-card", type=Path, default=None, metavar="FILE",
                        help="markdown appended to the generated MODEL_CARD.md")
    parser.add_argument("--data-summary", type=Path, default=None, metavar="FILE",
                        help="the training data's summary.json (default: DATA_DIR/summary.json of the GPT run)")
    parser.add_argument("--guidance", type=float, default=None,
                        help="default guidance scale (default 3.0 with a trained unconditional branch, else 1.0; "
                             "family masked: the mask stage's, default 4.0)")
    parser.add_argument("--skip-parity", action="store_true", help="do not compare onnxruntime with PyTorch")
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="DIR", help="bundle directory to write")
    parser.set_defaults(func=run)


_RUNS = {"gpt": ("gpt",), "masked": ("masked", "residual", "length"), "hifigpt": ("hifigpt",)}
# the graphs --int8 may name per family (none: no int8 export)
_INT8: dict[str, set[str]] = {"gpt": {"text", "gpt"}, "masked": {"text", "masked", "residual"},
                              "hifigpt": {"text", "temporal", "residual"}}


def _check_family_arguments(args: argparse.Namespace) -> None:
    from t2m.cli.main import CliError

    for family, runs in _RUNS.items():
        given = [f"--{name}" for name in runs if family != args.family and getattr(args, name) is not None]
        if given:
            raise CliError(f"{', '.join(given)}: only with --family {family}")
    allowed = _INT8[args.family]
    if not allowed and args.int8 != "none":
        raise CliError(f"--int8 is not available for --family {args.family}")
    graphs = set(args.int8.split(",")) - {"none", "all"}
    if args.int8 not in ("none", "all") and (not graphs or not graphs <= allowed):
        raise CliError(f"--int8 {args.int8}: give none, all, or some of {', '.join(sorted(allowed))} "
                       f"(comma-separated) for --family {args.family}")
    if args.family == "gpt":
        if len(graphs) > 1:
            args.int8 = "all"
        if args.gpt is None:
            raise CliError("--gpt RUN is required (or --family masked with --masked RUN, --family hifigpt with "
                           "--hifigpt RUN)")
        return
    if args.guidance is not None and args.guidance < 0:
        raise CliError(f"--guidance must be >= 0, got {args.guidance}")
    if args.family == "hifigpt":
        if args.hifigpt is None:
            raise CliError("--family hifigpt needs --hifigpt RUN")
        return
    if args.masked is None:
        raise CliError("--family masked needs --masked RUN")
    if args.steps < 1:
        raise CliError(f"--steps must be >= 1, got {args.steps}")
    if args.residual_guidance < 0:
        raise CliError(f"--residual-guidance must be >= 0, got {args.residual_guidance}")
    for option, value in (("--top-k", args.top_k), ("--residual-top-k", args.residual_top_k)):
        if value is not None and value < 1:
            raise CliError(f"{option} must be >= 1, got {value}")


def _int8_graphs(value: str, family: str) -> frozenset[str]:
    """--int8's graph names for a masked or hifigpt export ("all": every graph the family may quantise)."""
    if value == "none":
        return frozenset()
    return frozenset(_INT8[family]) if value == "all" else frozenset(value.split(","))


def _run_masked(args: argparse.Namespace) -> int:
    from t2m.export.masked_exporter import MaskedDecoding, export_masked_from_runs

    decoding = MaskedDecoding(steps=args.steps, guidance=4.0 if args.guidance is None else args.guidance,
                              residual_guidance=args.residual_guidance, top_k=args.top_k,
                              residual_top_k=args.residual_top_k)
    manifest, checks = export_masked_from_runs(
        args.vq, args.masked, args.output, residual_run=args.residual, length_run=args.length, name=args.name,
        version=args.version, model_card=args.model_card, data_summary=args.data_summary, decoding=decoding,
        check_parity=not args.skip_parity, int8=_int8_graphs(args.int8, "masked"))
    return _report(args, manifest, {"parity": checks.parity, "int8": checks.int8})


def _run_hifigpt(args: argparse.Namespace) -> int:
    from t2m.export.hifigpt_exporter import export_hifigpt_from_runs

    manifest, checks = export_hifigpt_from_runs(
        args.vq, args.hifigpt, args.output, name=args.name, version=args.version, model_card=args.model_card,
        data_summary=args.data_summary, default_guidance=args.guidance, check_parity=not args.skip_parity,
        int8=_int8_graphs(args.int8, "hifigpt"))
    return _report(args, manifest, {"parity": checks.parity, "int8": checks.int8})


def _report(args: argparse.Namespace, manifest: dict, checks: dict) -> int:
    print(json.dumps(checks, indent=2))
    total = sum(entry["bytes"] for entry in manifest["files"].values())
    print(f"bundle {manifest['name']} {manifest['version']} written to {args.output} ({total / 1e6:.1f} MB, verified)")
    return 0


def run(args: argparse.Namespace) -> int:
    import logging

    from t2m.export.exporter import export_from_runs

    _check_family_arguments(args)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    if args.family == "masked":
        return _run_masked(args)
    if args.family == "hifigpt":
        return _run_hifigpt(args)
    manifest, checks = export_from_runs(
        args.vq, args.gpt, args.output, text_encoder=args.text_encoder, clip_weights=args.clip_weights,
        int8=args.int8, name=args.name, version=args.version, model_card=args.model_card,
        data_summary=args.data_summary, default_guidance=args.guidance, check_parity=not args.skip_parity,
    )
    return _report(args, manifest, {"parity": checks.parity, "int8": checks.int8})
