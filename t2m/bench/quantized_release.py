"""T2M-GPT's GPT at its released size: ms per token of the float32 step graph vs int8 step graphs vs the reference
sampler (PyTorch eager, prefix recomputed), batch 1, guidance off (1 row) and on (cond + null rows), in one run.

The release is written with random weights in its exact file layout and imported with `t2m import t2m-gpt`'s code
(t2m/bench/released_models.py's writers: the 228M-parameter GPT, OpenAI's CLIP ViT-B/32 text tower); speed
depends on sizes, not values. Step graphs timed (all the imported graph, quantised here):

- float32: the imported gpt_step.onnx (what `t2m import t2m-gpt` writes without --int8);
- int8 7-bit: `quantize_graph` (dynamic MatMulInteger, per-channel, 7-bit weights: what `--int8 gpt` ships; the same
  integers on CPUs with and without VNNI);
- int8 8-bit: the same with full 8-bit weights (NOT shipped: non-VNNI CPUs saturate; for comparison only);
- weight-only int8 / int4: MatMulNBits (block-wise weights, dequantised in the kernel; float32 activations), where
  this onnxruntime has it;
- int4 weights, int8 compute: MatMulNBits 4-bit, block 128, accuracy level 4 (activations quantised to int8 per
  block, integer dot products). 4-bit weights cannot saturate a 16-bit pair sum (2 x 127 x 8), so no 7-bit rule is
  needed; opt-in (`t2m quantize --scheme int4`): no bundle here ships it, and its quality on a trained release is
  unmeasurable here (random weights, no release weights); on the trained GPT model, see README.

Each step graph runs the service's own loop shape: `position` 0..tokens-1 with the KV cache, greedy choice; the
reference recomputes the whole prefix with MotionGPT.forward every token (T2M-GPT's sample loop, as `t2m bench`).
Each figure is given as wall time and as this process's CPU time per token: on a machine shared with other work the
wall time measures the scheduler's share too, while one thread's CPU time stays close to what the step costs (with
2 threads, CPU time adds both threads' time and is not a latency). Figures are printed, never asserted.

    OMP_NUM_THREADS=1 t2m bench quantized-release [--workdir DIR] [--threads 1 2]
        [--tokens 50] [--repeats 3] [--variants float32,int8-7bit,...] [--no-eager]
"""
from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from t2m.bench.machine import describe_machine
from t2m.bench.released_models import import_t2m_gpt_release, write_clip

VARIANTS = ["float32", "int8-7bit", "int8-8bit", "wo-int8", "wo-int4", "int4-acc4"]
LABELS = {
    "float32": "float32 step graph (KV cache)",
    "int8-7bit": "int8 MatMulInteger, 7-bit weights (shipped rule)",
    "int8-8bit": "int8 MatMulInteger, 8-bit weights (not shippable)",
    "wo-int8": "weight-only int8 MatMulNBits (block 32)",
    "wo-int4": "weight-only int4 MatMulNBits (block 32)",
    "int4-acc4": "int4 weights, int8 compute: MatMulNBits block 128, accuracy level 4 (opt-in: t2m quantize)",
    "eager": "PyTorch eager, prefix recomputed (reference)",
}


def build_release_bundle(workdir: Path) -> Path:
    """The imported T2M-GPT bundle in workdir/bundles/t2m-gpt (reused when already there)."""
    out = workdir / "bundles" / "t2m-gpt"
    if not (out / "manifest.json").is_file():
        start = time.perf_counter()
        import_t2m_gpt_release(workdir / "releases" / "t2m-gpt", write_clip(workdir / "clip"), out)
        print(f"- imported the random-weight release in {time.perf_counter() - start:.0f} s", flush=True)
    return out


def variant_graph(bundle: Path, variant: str) -> Path:
    """The step graph of a variant, next to the bundle's float32 one (made once)."""
    from t2m.export.writing.quantize import quantize_graph, quantize_graph_int4, quantize_weights_nbits

    fp32 = bundle / "gpt_step.onnx"
    if variant == "float32":
        return fp32
    path = bundle.parent / f"gpt_step.{variant}.onnx"
    if not path.is_file():
        start = time.perf_counter()
        if variant in ("int8-7bit", "int8-8bit"):
            quantize_graph(fp32, path, reduce_range=variant == "int8-7bit")
        elif variant == "int4-acc4":
            quantize_graph_int4(fp32, path)
        else:
            quantize_weights_nbits(fp32, path, bits=8 if variant == "wo-int8" else 4)
        print(f"- {variant}: quantised in {time.perf_counter() - start:.0f} s, {path.stat().st_size / 1e6:.0f} MB",
              flush=True)
    return path


@dataclass
class Row:
    method: str
    threads: int
    guided: bool
    ms_per_token: float
    cpu_ms_per_token: float
    megabytes: float


def median_ms(fn: Callable[[], object], repeats: int) -> tuple[float, float]:
    """Median wall ms and median process CPU ms of `repeats` calls."""
    walls, cpus = [], []
    for _ in range(repeats):
        start, cpu = time.perf_counter(), time.process_time()
        fn()
        walls.append(time.perf_counter() - start)
        cpus.append(time.process_time() - cpu)
    return 1000 * statistics.median(walls), 1000 * statistics.median(cpus)


def conditions(manifest: dict, guided: bool) -> tuple[np.ndarray, np.ndarray]:
    """One text row (guidance off) or the cond + null pair (guidance on)."""
    dim = manifest["text_encoder"]["dim"]
    cond = np.random.default_rng(0).normal(size=(1, dim)).astype(np.float32)
    if guided:
        cond = np.concatenate([cond, np.zeros_like(cond)])
    return cond, np.zeros(len(cond), np.int64)


def ort_ms_per_token(path: Path, manifest: dict, guided: bool, tokens: int, repeats: int,
                     threads: int) -> tuple[float, float]:
    from t2m.export.graphs.export import ort_session

    session = ort_session(path, threads=threads)
    gpt = manifest["gpt"]
    names = {i.name for i in session.get_inputs()}
    cond, length = conditions(manifest, guided)
    size = manifest["codebook_size"]

    def generate() -> None:
        past = np.zeros((gpt["n_layer"], 2, len(cond), gpt["n_head"], 0, gpt["head_dim"]), np.float32)
        token = np.zeros(len(cond), np.int64)
        for position in range(tokens):
            feeds = {"cond": cond, "token": token, "position": np.array([position], np.int64), "past_kv": past}
            if "length" in names:
                feeds["length"] = length
            logits, past = session.run(None, feeds)
            scores = logits[1] + 3.0 * (logits[0] - logits[1]) if guided else logits[0]
            token = np.full(len(cond), int(scores[:size].argmax()), np.int64)

    generate()  # warm-up: pre-packing, allocations
    wall, cpu = median_ms(generate, repeats)
    return wall / tokens, cpu / tokens


def eager_ms_per_token(release: Path, manifest: dict, guided: bool, tokens: int,
                       threads: int) -> tuple[float, float]:
    """MotionGPT.forward on the whole prefix at every token (one timed run after a short warm-up)."""
    from t2m.families.gpt.import_t2m_gpt import load_release

    torch.set_num_threads(threads)
    files = {name: release / name for name in ("net_last.pth", "net_best_fid.pth", "mean.npy", "std.npy")}
    gpt = load_release(files["net_last.pth"], files["net_best_fid.pth"], files["mean.npy"], files["std.npy"]).gpt.eval()
    cond, _ = conditions(manifest, guided)
    cond_t = torch.from_numpy(cond)
    size = manifest["codebook_size"]

    @torch.no_grad()
    def generate(count: int) -> None:
        prefix = torch.zeros(len(cond), 0, dtype=torch.long)
        for _ in range(count):
            logits = gpt(cond_t, prefix, None)[:, -1]
            scores = logits[1] + 3.0 * (logits[0] - logits[1]) if guided else logits[0]
            prefix = torch.cat([prefix, scores[:size].argmax().repeat(len(cond), 1)], dim=1)

    generate(2)
    wall, cpu = median_ms(lambda: generate(tokens), 1)
    return wall / tokens, cpu / tokens


def release_folder(workdir: Path) -> Path:
    """Where the release writer put net_last.pth & co (the folder holding them)."""
    return next(p.parent for p in (workdir / "releases" / "t2m-gpt").rglob("net_last.pth"))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").strip().splitlines()[0])
    parser.add_argument("--workdir", type=Path, default=Path("tmp") / "int8-release",
                        help="keeps the release, the imported bundle and the quantised graphs "
                             "(default tmp/int8-release)")
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2], help="onnxruntime / torch threads")
    parser.add_argument("--tokens", type=int, default=50, help="tokens per run (default 50 = a 10 s motion)")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per step graph (median; default 3)")
    parser.add_argument("--variants", default=",".join(VARIANTS), help=f"step graphs (default {','.join(VARIANTS)})")
    parser.add_argument("--no-eager", action="store_true", help="skip the PyTorch reference")
    args = parser.parse_args(argv)
    variants = [v for v in args.variants.split(",") if v]
    unknown = sorted(set(variants) - set(VARIANTS))
    if unknown or args.tokens < 1 or args.repeats < 1 or min(args.threads) < 1:
        parser.error(f"unknown variants {unknown}" if unknown else "--tokens, --repeats, --threads must be >= 1")
    import json

    bundle = build_release_bundle(args.workdir)
    manifest = json.loads((bundle / "manifest.json").read_text())
    if args.tokens > manifest["max_tokens"]:
        parser.error(f"--tokens must be <= {manifest['max_tokens']}")
    graphs = {}
    for variant in variants:
        try:
            graphs[variant] = variant_graph(bundle, variant)
        except Exception as error:  # e.g. an onnxruntime without MatMulNBits for these bits: say so, time the rest
            print(f"- {variant}: not timed ({type(error).__name__}: {str(error).splitlines()[0][:200]})", flush=True)
    print()
    for line in describe_machine(max(args.threads), f"torch {torch.__version__}"):
        print(line)
    print(f"- OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}; niceness {os.nice(0)}")
    print()
    rows: list[Row] = []
    for threads in args.threads:
        for guided in (False, True):
            for variant, path in graphs.items():
                wall, cpu = ort_ms_per_token(path, manifest, guided, args.tokens, args.repeats, threads)
                rows.append(Row(variant, threads, guided, wall, cpu, path.stat().st_size / 1e6))
                print(f"  {variant} threads={threads} guided={guided}: {wall:.2f} ms/token wall, {cpu:.2f} CPU",
                      flush=True)
            if not args.no_eager:
                wall, cpu = eager_ms_per_token(release_folder(args.workdir), manifest, guided, args.tokens, threads)
                rows.append(Row("eager", threads, guided, wall, cpu, float("nan")))
                print(f"  eager threads={threads} guided={guided}: {wall:.2f} ms/token wall, {cpu:.2f} CPU",
                      flush=True)
    print()
    print(f"load average at the end {os.getloadavg()[0]:.1f}")
    print()
    print_table(rows, args.tokens)
    return 0


def print_table(rows: list[Row], tokens: int) -> None:
    """Markdown: one line per method, wall ms per token (and CPU ms) for each (threads, guidance) column."""
    columns = sorted({(r.threads, r.guided) for r in rows})
    head = [f"{t} thread{'s' if t > 1 else ''}, {'guided (2 rows)' if g else 'no guidance (1 row)'}"
            for t, g in columns]
    print(f"ms per token, batch 1, {tokens} tokens (median of the timed runs): wall (CPU of this process)")
    print()
    print("| method | graph MB | " + " | ".join(head) + " |")
    print("| --- | ---: | " + " | ".join("---:" for _ in columns) + " |")
    for method in dict.fromkeys(r.method for r in rows):
        mine = {(r.threads, r.guided): r for r in rows if r.method == method}
        size = next(iter(mine.values())).megabytes
        cells = [f"{mine[c].ms_per_token:.2f} ({mine[c].cpu_ms_per_token:.2f})" if c in mine else "-"
                 for c in columns]
        print(f"| {LABELS[method]} | {'-' if size != size else f'{size:.0f}'} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    raise SystemExit(main())
