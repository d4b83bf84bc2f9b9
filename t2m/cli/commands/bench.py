"""`t2m bench`: ms per generated token and ms for a 10 s motion, onnxruntime + KV cache vs PyTorch eager.

Prints a markdown table (default model size and the T2M-GPT release size) with the machine's CPU, cores,
library versions and thread counts; the last line is `speedup_vs_eager_recompute=<N>x` for the default size.
"""
from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("bench", help="generation speed: onnxruntime + KV cache vs PyTorch eager",
                                   description=(__doc__ or "").strip().splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="one repeat, and only 10 tokens at the T2M-GPT release size "
                             "(under ~40 s once the graphs are cached)")
    parser.add_argument("--threads", type=int, default=None,
                        help="threads for torch and onnxruntime (default: all cores)")
    parser.add_argument("--cache-dir", type=Path, default=None, metavar="DIR",
                        help="where exported benchmark graphs are kept between runs (default ~/.cache/t2m/bench)")
    parser.add_argument("--no-cache", action="store_true", help="export the graphs afresh into a temporary directory")
    parser.add_argument("--no-release", action="store_true", help="skip the 228M-parameter T2M-GPT release size")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from t2m.cli.main import CliError

    if args.threads is not None and args.threads < 1:
        raise CliError("--threads must be >= 1")
    from t2m.export.bench import default_cache_dir, run_bench

    cache_dir = None if args.no_cache else (args.cache_dir or default_cache_dir())
    run_bench(quick=args.quick, threads=args.threads, include_release=not args.no_release, cache_dir=cache_dir)
    return 0
