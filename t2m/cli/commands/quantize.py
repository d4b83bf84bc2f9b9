"""`t2m quantize`: a copy of a bundle with its token graphs quantised (int8, int4 or fp16), for any family that
declares such graphs (the T2M-GPT step graph; the masked family's masked/residual graphs, MoGenTS's branch too; the
HiFiGPT steps).

    t2m quantize bundles/t2m-gpt -o bundles/t2m-gpt-int4 --scheme int4
    t2m quantize models/mogents -o models/mogents-int8
    t2m quantize t2m/bundles/default -o bundles/default-gpu --scheme fp16     # the int8 default, for a GPU

Why a separate step: a bundle, exported here or imported from a release, is quantised after the fact and measured
as served against its float32 original (the same seeded requests on both: token agreement and the largest logit
difference, written in the copy's model card) before anyone ships it.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from t2m.cli.main import CliError

SCHEME_HELP = ("int8: dynamic, 7-bit weights (MatMulInteger; the shipped rule, fastest on CPUs); int4: MatMulNBits "
               "weights in blocks of 128 with int8 compute, for release-size graphs bound by memory bandwidth; "
               "fp16: float16 weights and compute with float32 inputs and outputs, for GPUs (runs, slowly, on CPU); "
               "float32: an int8 bundle's graphs dequantised, for GPUs (fp16 takes int8 bundles too)")


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("quantize", help="quantise a bundle's token graphs (int8, int4 or fp16)",
                                   description=(__doc__ or "").strip().splitlines()[0])
    parser.add_argument("bundle", type=Path, help="a bundle directory (read, never changed)")
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="DIR", help="bundle directory to write")
    parser.add_argument("--scheme", choices=("int8", "int4", "fp16", "float32"), default="int8", help=SCHEME_HELP)
    parser.add_argument("--version", default=None, help="the copy's version (default: the original's)")
    parser.add_argument("--parity-runs", type=int, default=None, metavar="N",
                        help="seeded requests served on both bundles to measure parity (default 8 of 10 s; a "
                             "diffusion bundle 2 of 2 s; 0 skips it)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from t2m.export.writing.int8 import quantize_bundle

    if args.output.resolve() == args.bundle.resolve():
        raise CliError("-o must differ from the bundle: the float32 original is what the copy is measured against")
    if args.parity_runs is not None and args.parity_runs < 0:
        raise CliError(f"--parity-runs must be >= 0, got {args.parity_runs}")
    manifest, report = quantize_bundle(args.bundle, args.output, version=args.version, scheme=args.scheme,
                                       parity=args.parity_runs != 0, runs=args.parity_runs)
    if report is not None:
        print(json.dumps({"quantization": report}, indent=2))
    print(summary(manifest, args.output, report))
    return 0


def summary(manifest: dict, output: Path, report: dict | None) -> str:
    """One line: which graphs became what, their sizes, the measured agreement, where."""
    from t2m.export.writing.int8 import captured_graphs_to_convert, quantized_graphs

    done = manifest["quantization"]
    converted = [*quantized_graphs(manifest), *(name for name in captured_graphs_to_convert(manifest, "fp16")
                                                if done.get(Path(name).stem))]
    graphs = ", ".join(f"{name} {done[Path(name).stem]} ({(output / name).stat().st_size / 1e6:.1f} MB)"
                       for name in converted)
    parity = "" if report is None else (f"; {parity_words(report)} over {report['runs']} seeded requests, "
                                        f"max |{_output(report)} diff| {report['max_abs_logit_diff']:.3g}")
    return f"{manifest['name']} {manifest['version']}: {graphs}{parity}; written to {output} and verified"


def parity_words(report: dict) -> str:
    """Token agreement, or for a family without tokens (diffusion) how far the served joints moved."""
    if report["tokens"]:
        return f"{100 * report['agreement']:.1f}% of tokens as the original's"
    return f"joints within {report['max_joint_diff_m']:.3g} m of the original's"


def _output(report: dict) -> str:
    return next((graph["output"] for graph in report["graphs"].values()), "logit")
