"""What the decoding loops cost on the host alone: the default model's T2M-HiFiGPT loop and MoMask's masked loop at
its release sizes (t2m/decoding), with steps that answer instantly (fixed outputs of the real sizes), so everything
timed is sampling, guidance, bookkeeping and Python. Why: on a GPU the network calls of a large batch are cheap, and
a loop that spends longer on the host than the GPU spends on its calls caps motions per second whatever the GPU does
(the GPU goals: the default model at 1,000 10-s motions/s, MoMask's 10 s motion in 20 ms).
benchmarks/gpu_suite.py adds the default loop over instant steps as a "host loop alone" row, so the cap is measured
on the device's own CPU beside its GPU rows.

    t2m bench host-loop [--batches 1,64,256,1024] [--repeats 3] [--draw-groups 128,0]
        [--loops default,momask,t2m-gpt] [--gc frozen,as-is] [--threads 1,2,4]

--draw-groups: the sizes of t2m.decoding.lockstep.DRAW_GROUP to compare side by side (0: one draw for all rows),
alternating within each repeat. --gc: the garbage collector as the service leaves it after loading (frozen: every
object alive then moved out of its generations, T2M_GC_FREEZE) and/or as-is, also alternating. To compare
checkouts, copy this file into the other checkout's benchmarks/ and run both copies by turns: each times the loop
of the checkout it lies in.
"""
from __future__ import annotations

import argparse
import contextlib
import gc
import json
import statistics
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np


class _Instant:
    """Fixed outputs for up to `rows` rows (random, so that sampling does real work), no cache."""

    def __init__(self, rows: int, width: int, seed: int) -> None:
        self.values = np.random.default_rng(seed).normal(size=(rows, width)).astype(np.float32)

    def empty_cache(self, batch: int) -> np.ndarray:
        return np.zeros(0, np.float32)

    def keep_rows(self, past: Any, keep: np.ndarray) -> Any:
        return past


class InstantGptStep(_Instant):
    """t2m.families.gpt.loop.GptStep answering logits [B, K+1] at once."""

    def __call__(self, cond, token, position, length, past):
        return self.values[: len(cond)], past


class InstantTemporalStep(_Instant):
    """t2m.families.hifigpt.loop.TemporalStep answering (context, a low stop logit) at once."""

    def __init__(self, rows: int, width: int, depth: int) -> None:
        super().__init__(rows, width, 1)
        self.depth = depth

    def __call__(self, cond, codes, position, length, past):
        return self.values[: len(cond)], np.full(len(cond), -8.0, np.float32), past


class InstantResidualStep(_Instant):
    """t2m.families.hifigpt.loop.ResidualGptStep answering logits [B, K] at once."""

    def __call__(self, context, code, depth, past):
        return self.values[: len(context)], past


def default_loop(max_batch: int) -> tuple[Callable[[int], np.ndarray], int]:
    """The embedded default model's loop (its sizes from the manifest) over instant steps; its steps per motion."""
    from t2m.bench.loops import hifigpt_generate
    from t2m.bundles import DEFAULT_BUNDLE

    manifest = json.loads((DEFAULT_BUNDLE / "manifest.json").read_text())
    h, steps = manifest["hifigpt"], 25
    rows = 2 * max_batch
    temporal = InstantTemporalStep(rows, h["n_head"] * h["head_dim"], manifest["residual_layers"])
    residual = InstantResidualStep(rows, manifest["codebook_size"], 2)
    return hifigpt_generate(temporal, residual, manifest["text_encoder"]["dim"], steps, manifest["max_tokens"]), steps


def _map_logits(rows: int, tokens: int, classes: int) -> np.ndarray:
    return np.random.default_rng(2).normal(size=(rows, tokens, 1, classes)).astype(np.float32)


class InstantMaskedStep(_Instant):
    """t2m.families.masked.loop.MaskedStep answering logits [B, T, C, K] at once."""

    def __init__(self, rows: int, tokens: int, classes: int, mask_id: int) -> None:
        self.values, self.columns, self.mask_id = _map_logits(rows, tokens, classes), 1, mask_id

    def __call__(self, tokens, cond, length):
        return self.values[: len(cond), : tokens.shape[1]]


class InstantMaskedResidual(_Instant):
    """t2m.families.masked.loop.ResidualStep answering logits for a layer at once."""

    mask_id = None

    def __init__(self, rows: int, tokens: int, classes: int, layers: int) -> None:
        self.values, self.layers, self.pad_id = _map_logits(rows, tokens, classes), layers, classes - 1

    def __call__(self, codes, layer, cond, length):
        return self.values[: len(cond), : codes.shape[1]]


def momask_loop(max_batch: int) -> tuple[Callable[[int], np.ndarray], int]:
    """MoMask's release loop (49 token rows, 10 mask passes, 5 residual passes, 512 codes, its release decoding:
    guidance 4 and 5, top-k 52) over instant steps."""
    from t2m.bench.loops import masked_generate, momask_release_decoding

    rows, passes, layers, codes = 49, 10, 6, 512
    masked = InstantMaskedStep(2 * max_batch, rows, codes + 1, codes)       # K codes + the mask class
    residual = InstantMaskedResidual(2 * max_batch, rows, codes + 1, layers)  # K codes + the pad class
    generate = masked_generate(masked, residual, 512, rows, passes, momask_release_decoding(codes))
    return generate, passes + layers - 1


def t2m_gpt_loop(max_batch: int) -> tuple[Callable[[int], np.ndarray], int]:
    """T2M-GPT's release loop (50 tokens of 512 codes + End, guidance 3 as gpu_suite runs it) over instant steps."""
    from t2m.bench.loops import gpt_generate

    codes, tokens = 512, 50
    step = InstantGptStep(2 * max_batch, codes + 1, 3)
    return gpt_generate(step, 512, tokens, tokens, codes), tokens


@contextlib.contextmanager
def collector(mode: str) -> Iterator[None]:
    """The garbage collector for one timed run: 'frozen' as the service leaves it after loading
    (t2m.service.app.freeze_loaded_objects), 'as-is' untouched; unfrozen afterwards either way."""
    if mode == "frozen":
        gc.collect()
        gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


LOOPS = {"default": ("default (T2M-HiFiGPT)", default_loop), "momask": ("MoMask release", momask_loop),
         "t2m-gpt": ("T2M-GPT release", t2m_gpt_loop)}


def threaded(label: str, make: Callable[[int], tuple[Callable[[int], np.ndarray], int]], batches: list[int],
             threads: list[int], repeats: int) -> None:
    """--threads: each batch split over N threads, each stepping its own loop (as T2M_ENGINE_WORKERS threads step
    their cohorts side by side), the collector frozen: whether Python threads overlap host loops. They share one
    interpreter lock; numpy lets go of it only inside its array loops."""
    loops = [make(max(batches))[0] for _ in range(max(threads))]
    print("| loop | threads | batch (split evenly) | ms per batch of 10 s motions | host cap, motions / s |\n"
          "| --- | ---: | ---: | ---: | ---: |")
    for batch in batches:
        for count in threads:
            runs = []
            for _ in range(repeats + 1):                     # the first is a warm-up
                workers = [threading.Thread(target=loops[i], args=(batch // count,)) for i in range(count)]
                with collector("frozen"):
                    started = time.perf_counter()
                    for worker in workers:
                        worker.start()
                    for worker in workers:
                        worker.join()
                    runs.append(time.perf_counter() - started)
            ms = 1000 * statistics.median(runs[1:])
            print(f"| {label} | {count} | {batch} | {ms:.1f} | {1000 * batch / ms:.0f} |", flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").strip().splitlines()[0])
    parser.add_argument("--batches", default="1,64,256,1024")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--draw-groups", default=None, help="DRAW_GROUP sizes to compare (0 = all rows at once)")
    parser.add_argument("--loops", default="default", help=f"comma-separated, of {', '.join(LOOPS)}")
    parser.add_argument("--gc", default="frozen", help="comma-separated, of frozen (as the service runs) and as-is")
    parser.add_argument("--threads", default=None, help="thread counts to split each batch over (a table of its own)")
    args = parser.parse_args(argv)
    modes = args.gc.split(",")
    if not modes or set(modes) - {"frozen", "as-is"}:
        parser.error(f"--gc takes frozen and/or as-is, got {args.gc!r}")
    from t2m.decoding import lockstep

    batches = [int(b) for b in args.batches.split(",")]
    default = getattr(lockstep, "DRAW_GROUP", 0)      # 0 in a checkout from before DRAW_GROUP
    groups = [int(g) for g in args.draw_groups.split(",")] if args.draw_groups else [default]
    print("| loop | draw group | batch | ms per batch of 10 s motions | host cap, motions / s | gc |\n"
          "| --- | ---: | ---: | ---: | ---: | --- |")
    for name in args.loops.split(","):
        label, make = LOOPS[name]
        generate, steps = make(max(batches))
        for batch in batches:
            generate(batch)
            times: dict[tuple[int, str], list[float]] = {(group, mode): [] for group in groups for mode in modes}
            for _ in range(args.repeats):
                for group, mode in times:
                    lockstep.DRAW_GROUP = group or 10**9
                    with collector(mode):
                        if len(modes) > 1:
                            generate(batch)     # untimed: the collection before a frozen run leaves caches cold
                        started = time.perf_counter()
                        generate(batch)
                        times[group, mode].append(time.perf_counter() - started)
            for (group, mode), runs in times.items():
                ms = 1000 * statistics.median(runs)
                print(f"| {label}, {steps} steps | {group or 'all'} | {batch} | {ms:.1f} | {1000 * batch / ms:.0f} | "
                      f"{mode} |", flush=True)
    print(f"- median of {args.repeats}; instant network calls; guidance (a cond and a null row per motion)")
    if args.threads:
        for name in args.loops.split(","):
            label, make = LOOPS[name]
            threaded(label, make, batches, [int(n) for n in args.threads.split(",")], args.repeats)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
