"""`t2m index-captions`: add the training captions' text features and a calibrated unknown-text threshold to a bundle.

    t2m index-captions t2m/bundles/default --data data/bandai
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from t2m.cli.main import CliError


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("index-captions", help="index a bundle's training captions (unknown-text warnings)",
                                   description=(__doc__ or "").strip().splitlines()[0])
    parser.add_argument("bundle", type=Path, help="bundle directory (rewritten in place, then verified)")
    parser.add_argument("--data", type=Path, required=True, metavar="DIR",
                        help="the training set in HumanML3D's layout (its captions are indexed)")
    parser.add_argument("--split", default="train", help="which split's captions (default train)")
    parser.add_argument("--phrasings", type=Path, default=None, metavar="FILE",
                        help="JSON of known/unknown sentences for calibration and evaluation "
                             "(default: the Bandai-Namco set shipped in t2m/export/phrasings)")
    parser.add_argument("--report", type=Path, default=None, metavar="FILE", help="write the full report as JSON")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from t2m.export.writing.index_captions import DEFAULT_PHRASINGS, add_caption_index

    if not (args.data / "texts").is_dir():
        raise CliError(f"--data {args.data}: no texts/ directory (expected a dataset in HumanML3D's layout)")
    report = add_caption_index(args.bundle, args.data, args.phrasings or DEFAULT_PHRASINGS, split=args.split)
    if args.report:
        args.report.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    for name in ("calibration", "evaluation"):
        r = report[name]
        print(f"{name}: false warnings {r['false_warnings']}/{r['known']} ({r['false_warning_rate']:.2f}), "
              f"missed {r['missed_warnings']}/{r['unknown']} ({r['missed_warning_rate']:.2f})")
    print(f"threshold {report['threshold']:.4f}; bundle {args.bundle} rewritten and verified")
    return 0
