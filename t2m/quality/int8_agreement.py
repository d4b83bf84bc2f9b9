"""An int8-GPT copy of a GPT bundle and its greedy code agreement with the float32 step graph.

Writes OUT (the bundle with gpt_step.onnx quantised by `quantize_graph`, 7-bit weights; manifest
quantization.gpt_step = "int8-dynamic") and prints, over `--conditions` seeded random text conditions at the
bundle's default guidance, 50-step greedy rollouts of both graphs
(t2m.families.gpt.parity.gpt_int8_report): how many
code sequences are identical, the mean first position where they part, and the largest logit difference while they
agree. Table 1 and the probes of the copy are separate commands (`t2m eval --bundle OUT`, `t2m/quality/probes.py
--bundle OUT`; benchmarks/README.md).

    OMP_NUM_THREADS=1 t2m eval int8-agreement --bundle t2m/bundles/gpt
        --out tmp/default-int8 [--conditions 20]
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from t2m.export.writing.int8 import quantize_bundle_gpt
from t2m.families.gpt.parity import gpt_int8_report


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").strip().splitlines()[0])
    parser.add_argument("--bundle", type=Path, required=True, help="a float32-GPT bundle")
    parser.add_argument("--out", type=Path, required=True, help="where the int8 copy goes (reused when there)")
    parser.add_argument("--conditions", type=int, default=20, help="random conditions rolled out (default 20)")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    if not (args.out / "manifest.json").is_file():
        quantize_bundle_gpt(args.bundle, args.out)
    manifest = json.loads((args.bundle / "manifest.json").read_text())
    reports = [gpt_int8_report(args.bundle / "gpt_step.onnx", args.out / "gpt_step.onnx", manifest, seed=seed,
                               threads=args.threads) for seed in range(args.conditions)]
    same = sum(r.greedy_codes_match for r in reports)
    print(f"bundle {args.bundle} ({manifest['name']} {manifest['version']}) vs its int8-GPT copy {args.out}")
    print(f"- greedy rollouts, {reports[0].steps} steps, guidance {manifest['gpt']['default_guidance']:g}, "
          f"{args.conditions} random conditions: {same}/{args.conditions} code sequences identical")
    print(f"- steps agreeing before the first difference: mean {np.mean([r.agree_steps for r in reports]):.1f}, "
          f"min {min(r.agree_steps for r in reports)}")
    print(f"- max |logit diff| while the codes agree: {max(r.max_abs_logit_diff for r in reports):.4f} "
          f"(median over conditions {np.median([r.max_abs_logit_diff for r in reports]):.4f})")
    print(f"- gpt_step.onnx {reports[0].fp32_bytes / 1e6:.1f} -> {reports[0].int8_bytes / 1e6:.1f} MB; "
          f"{np.median([r.fp32_ms_per_step for r in reports]):.3f} -> "
          f"{np.median([r.int8_ms_per_step for r in reports]):.3f} ms per step (guidance pair, median)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
