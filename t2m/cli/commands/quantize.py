"""`t2m quantize`: a copy of a GPT-family bundle with its step graph quantised (int8, or opt-in int4 weights).

    t2m quantize bundles/t2m-gpt -o bundles/t2m-gpt-int4 --scheme int4

Why a separate step: a bundle, exported here or imported from a release, is quantised after the fact and measured
as served (`t2m eval --bundle`, benchmarks/probes.py) against its float32 original before anyone ships it.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from t2m.cli.main import CliError


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("quantize", help="quantise a GPT bundle's step graph (int8 or int4 weights)",
                                   description=(__doc__ or "").strip().splitlines()[0])
    parser.add_argument("bundle", type=Path, help="a GPT-family bundle directory (read, never changed)")
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="DIR", help="bundle directory to write")
    parser.add_argument("--scheme", choices=("int8", "int4"), default="int8",
                        help="int8: dynamic, 7-bit weights (the shipped rule); int4: MatMulNBits weights in blocks "
                             "of 128 with int8 compute, for release-size steps bound by memory bandwidth")
    parser.add_argument("--version", default=None, help="the copy's version (default: the original's)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from t2m.export.writing.int8 import quantize_bundle_gpt

    if args.output.resolve() == args.bundle.resolve():
        raise CliError("-o must differ from the bundle: the float32 original is what the copy is measured against")
    manifest = quantize_bundle_gpt(args.bundle, args.output, version=args.version, scheme=args.scheme)
    size = (args.output / "gpt_step.onnx").stat().st_size / 1e6
    print(f"{manifest['name']} {manifest['version']}: gpt_step.onnx {manifest['quantization']['gpt_step']} "
          f"({size:.1f} MB); written to {args.output} and verified")
    return 0
