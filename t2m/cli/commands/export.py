"""`t2m export`: a VQ run + a token model's runs -> a verified model bundle (ONNX graphs, tokenizer, manifest, card).

    t2m export --vq runs/vq --gpt runs/gpt --int8 text -o t2m/bundles/default
    t2m export --family masked --vq runs/joint_vq --masked runs/masked --residual runs/residual \
        [--length runs/length] -o DIR
    t2m export --family hifigpt --vq runs/rvq --hifigpt runs/hifigpt [--guidance 3] -o DIR

Each family (t2m.bundle.family) adds its own options and does its own export; the token run's config.json tells the
text encoder, the condition dropout (-> unconditional_branch) and the data directory, whose summary.json gives the
training data and its licence (or pass --data-summary).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from t2m.bundle import ModelFamily


def register(subparsers: argparse._SubParsersAction) -> None:
    from t2m.bundle import iter_families

    parser = subparsers.add_parser("export", help="training runs -> ONNX model bundle for the service",
                                   description=(__doc__ or "").strip().splitlines()[0])
    families = list(iter_families())
    parser.add_argument("--vq", type=Path, default=None, metavar="RUN",
                        help="VQ-VAE run directory (the families that decode with a trained VQ)")
    parser.add_argument("--family", choices=[family.name for family in families], default="gpt",
                        help="model family (default gpt): " + "; ".join(f"{family.name}: {family.title}"
                                                                       for family in families))
    parser.add_argument("--int8", default="none", metavar="GRAPHS",
                        help="int8 dynamic quantisation: none (default), all, or the graphs comma-separated: "
                             + "; ".join(f"family {family.name}: {', '.join(sorted(family.int8_graphs))}"
                                         for family in families if family.int8_graphs))
    parser.add_argument("--name", default=None, help="bundle name (default t2m-<data>-<text encoder>)")
    parser.add_argument("--version", default="0.1.0", help="bundle version (default 0.1.0)")
    parser.add_argument("--model-card", type=Path, default=None, metavar="FILE",
                        help="markdown appended to the generated MODEL_CARD.md")
    parser.add_argument("--data-summary", type=Path, default=None, metavar="FILE",
                        help="the training data's summary.json (default: DATA_DIR/summary.json of the token run)")
    parser.add_argument("--guidance", type=float, default=None,
                        help="default guidance scale (default 3.0 with a trained unconditional branch, else 1.0; "
                             "family masked: the mask stage's, default 4.0)")
    parser.add_argument("--skip-parity", action="store_true", help="do not compare onnxruntime with PyTorch")
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="DIR", help="bundle directory to write")
    # each family's own options, remembered by family so that another family's export refuses them
    owners: dict[str, list[argparse.Action]] = {}
    for family in families:
        group = parser.add_argument_group(f"family {family.name}")
        before = len(parser._actions)
        family.add_export_arguments(group)
        owners[family.name] = parser._actions[before:]
    parser.set_defaults(func=run, family_options=owners)


def _check_family_arguments(args: argparse.Namespace, family: ModelFamily) -> frozenset[str]:
    """Options of other families refused, the family's own checks, and --int8 as the set of graphs to quantise."""
    from t2m.cli.main import CliError

    for name, actions in args.family_options.items():
        given = [action.option_strings[0] for action in actions
                 if name != family.name and getattr(args, action.dest) != action.default]
        if given:
            raise CliError(f"{', '.join(given)}: only with --family {name}")
    allowed = family.int8_graphs
    if not allowed and args.int8 != "none":
        raise CliError(f"--int8 is not available for --family {family.name}")
    graphs = set(args.int8.split(",")) - {"none", "all"}
    if args.int8 not in ("none", "all") and (not graphs or not graphs <= allowed):
        raise CliError(f"--int8 {args.int8}: give none, all, or some of {', '.join(sorted(allowed))} "
                       f"(comma-separated) for --family {family.name}")
    if family.export_needs_vq and args.vq is None:
        raise CliError("--vq RUN is required")
    if args.guidance is not None and args.guidance < 0:
        raise CliError(f"--guidance must be >= 0, got {args.guidance}")
    try:
        family.check_export_arguments(args)
    except ValueError as error:
        raise CliError(str(error)) from None
    return frozenset() if args.int8 == "none" else frozenset(allowed) if args.int8 == "all" else frozenset(graphs)


def run(args: argparse.Namespace) -> int:
    import logging

    from t2m.bundle import get_family

    family = get_family(args.family)
    int8 = _check_family_arguments(args, family)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    manifest, checks = family.export(args, int8)
    print(json.dumps(checks, indent=2))
    total = sum(entry["bytes"] for entry in manifest["files"].values())
    print(f"bundle {manifest['name']} {manifest['version']} written to {args.output} ({total / 1e6:.1f} MB, verified)")
    return 0
