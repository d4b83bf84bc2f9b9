"""Issue 29's CPU goals against one run's figures (benchmarks/issue29_report.sh writes both inputs): the scheduling
goals from benchmarks/step_order.py's --json-out, MoGenTS's 1 s and the quantised imports' speed-ups from
benchmarks/released_models_speed.py's --json-out. Why a script: the report's tables are long, and whether a goal
is met should be read off the same numbers, not retyped. The GPU goals need a device (benchmarks/gpu_pending.sh).

    python benchmarks/issue29_goals.py --scheduling S.json --released R.json
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

ONE_SENTENCE = "10 s, 1 sentence"
IMPORTERS = {"t2m-gpt": "T2M-GPT", "momask": "MoMask", "mogents": "MoGenTS"}


def _phase(results: list[dict[str, Any]], server: str, phase: str, kind: str) -> dict[str, Any]:
    for row in results:
        if (row["server"], row["phase"], row["kind"]) == (server, phase, kind):
            return row
    raise SystemExit(f"step_order figures: no {phase!r} {kind!r} phase for the {server!r} server")


def _met(ok: bool) -> str:
    return "met" if ok else "not met"


def scheduling_rows(results: list[dict[str, Any]]) -> list[str]:
    """The short-request ratio, the long requests' throughput and the 16 clients, before and after."""
    def ratio(server: str) -> float:
        return _phase(results, server, "mixed", "short")["p90_ms"] / _phase(results, server, "short alone",
                                                                             "short")["p90_ms"]

    ratios = {server: ratio(server) for server in ("before", "after")}
    long_before = _phase(results, "before", "mixed", "long")["ok_per_s"]
    long_after = _phase(results, "after", "mixed", "long")["ok_per_s"]
    sixteen = {server: _phase(results, server, "sixteen", "ten") for server in ("before", "after")}
    change = long_after / long_before - 1 if long_before else float("nan")
    fast_enough = sixteen["after"]["ok_per_s"] >= 60 and sixteen["after"]["p99_ms"] < 500
    return [
        f"| 2 s requests' p90 under the 30 s load / alone | 2x or less | {ratios['after']:.2f} | {ratios['before']:.2f}"
        f" | {_met(ratios['after'] <= 2)} |",
        f"| 30 s requests' answers/s beside the probe | at most 20% lost | {long_after:.2f} ({change:+.0%}) | "
        f"{long_before:.2f} | {_met(change >= -0.2)} |",
        f"| 16 clients x 10 s: answers/s, p99 | 60/s or more, p99 under 500 ms | {sixteen['after']['ok_per_s']:.1f}, "
        f"{sixteen['after']['p99_ms']:.0f} ms | {sixteen['before']['ok_per_s']:.1f}, {sixteen['before']['p99_ms']:.0f}"
        f" ms | {_met(fast_enough)} |",
    ]


def released_rows(figures: dict[str, dict[str, dict[str, dict[str, float]]]]) -> list[str]:
    """MoGenTS's 10 s motion at its fastest (any scheme, any thread count: the goal is 2 cores, however used), and
    each importer's quantised speed-up per thread count."""
    rows = []
    mogents = {(threads, model.split(" ")[1]): cases[ONE_SENTENCE]["total"]
               for threads, table in figures.items() for model, cases in table.items() if model.startswith("mogents ")}
    if mogents:
        (threads, scheme), best = min(mogents.items(), key=lambda item: item[1])
        rows.append(f"| MoGenTS's 10 s motion, the fastest measured | 1 s or less | {best:.0f} ms ({scheme}, "
                    f"{threads} thread(s)) | - | {_met(best <= 1000)} |")
    for name, label in IMPORTERS.items():
        for threads, table in sorted(figures.items(), key=lambda item: int(item[0])):
            plain = table.get(f"{name} float32", {}).get(ONE_SENTENCE)
            if plain is None:
                continue
            faster = [f"{scheme} {plain['total'] / table[f'{name} {scheme}'][ONE_SENTENCE]['total']:.1f}x"
                      for scheme in ("int8", "int4", "fp16") if f"{name} {scheme}" in table]
            rows.append(f"| {label} import, --quantize vs float32 ({threads} thread(s), 10 s motion) | a quantised "
                        f"import | {', '.join(faster) or '-'} | {plain['total']:.0f} ms float32 | - |")
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").strip().splitlines()[0])
    parser.add_argument("--scheduling", type=Path, required=True, help="benchmarks/step_order.py --json-out")
    parser.add_argument("--released", type=Path, required=True, help="benchmarks/released_models_speed.py --json-out")
    args = parser.parse_args(argv)
    try:
        scheduling = json.loads(args.scheduling.read_text())["results"]
        released = json.loads(args.released.read_text())
    except (OSError, ValueError, KeyError) as error:
        parser.error(f"cannot read the figures: {error}")
    print("| goal (issue 29, CPU) | target | this checkout | before issue 29 | |")
    print("| --- | --- | ---: | ---: | --- |")
    for row in scheduling_rows(scheduling) + released_rows(released):
        print(row)
    print()
    print("- the GPU goals (T2M-GPT 1.5 ms per token, MoMask 20 ms, the default model 1,000 motions/s) need a device:"
          " benchmarks/gpu_pending.sh")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
