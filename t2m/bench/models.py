"""Speed of generation: onnxruntime with the KV cache vs PyTorch eager recomputing the whole prefix every step.

What one "10 s motion" costs: 50 code tokens for a guidance pair (batch 2: the conditional row and the
zero-condition row) plus decoding the 50 codes to 200 frames. Three ways, side by side, with the same
random weights:

- "onnxruntime + KV cache": the bundle's graphs in onnxruntime (what the service runs);
- "PyTorch eager + KV cache": MotionGPT.forward_step (separates the cache's gain from onnxruntime's);
- "PyTorch eager, prefix recomputed": MotionGPT.forward on the whole prefix at every step (T2M-GPT's sampler).

Sizes: our embedded GPT-family model (read from t2m/bundles/gpt/manifest.json when present, else the default
GPTConfig/VQConfig) and the T2M-GPT release (1024 embed, 9+9 layers, 16 heads; 228M parameters).
The text encoder is not timed (it runs once per request, not per token).
"""
from __future__ import annotations

import hashlib
import json
import os
import statistics
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from t2m.bench.machine import describe_machine
from t2m.bundles import GPT_BUNDLE
from t2m.families.gpt.network import GPTConfig, MotionGPT
from t2m.model.networks.vqvae import MotionVQVAE, VQConfig

GPT_MANIFEST = GPT_BUNDLE / "manifest.json"
RELEASE_GPT = GPTConfig(codebook_size=512, embed=1024, n_head=16, n_layer_base=9, n_layer_head=9, block_size=51,
                        dropout=0.0, text_dim=512, length_conditioning=False)
RELEASE_VQ = VQConfig(width=512, code_dim=512, nb_code=512)
BENCH_SEED = 0


@dataclass
class BenchCase:
    label: str
    gpt: GPTConfig
    vq: VQConfig
    tokens: int
    repeats: int
    note: str = ""


@dataclass
class BenchRow:
    case: BenchCase
    method: str
    ms_per_token: float
    ms_generate: float
    ms_decode: float

    @property
    def ms_total(self) -> float:
        return self.ms_generate + self.ms_decode


def gpt_sizes() -> tuple[GPTConfig, VQConfig, str]:
    """The embedded GPT bundle's sizes (t2m/bundles/gpt: the 1-layer GPT these timings are about), else defaults.

    VQ sizes are not in a manifest: the VQ gets VQConfig's defaults (with the bundle's codebook size)."""
    if GPT_MANIFEST.is_file():
        manifest = json.loads(GPT_MANIFEST.read_text())
        g = manifest["gpt"]
        n_layer = g["n_layer"]
        gpt = GPTConfig(codebook_size=manifest["codebook_size"], embed=g["n_head"] * g["head_dim"], n_head=g["n_head"],
                        n_layer_base=n_layer - n_layer // 2, n_layer_head=n_layer // 2, block_size=g["block_size"],
                        dropout=0.0, text_dim=manifest["text_encoder"]["dim"],
                        length_conditioning=g["length_conditioning"])
        return gpt, VQConfig(nb_code=manifest["codebook_size"]), f"t2m/bundles/gpt ({manifest['name']})"
    return GPTConfig(dropout=0.0), VQConfig(), "default GPTConfig (no t2m/bundles/gpt/manifest.json)"


def median_ms(fn: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1000 * statistics.median(times)


def _rows_inputs(config: GPTConfig, tokens: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    cond = rng.normal(size=(1, config.text_dim)).astype(np.float32)
    cond = np.concatenate([cond, np.zeros_like(cond)])  # the guidance pair
    return cond, np.full(2, tokens if config.length_conditioning else 0, np.int64)


def default_cache_dir() -> Path:
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "t2m" / "bench"


def case_key(case: BenchCase, gpt: MotionGPT, vq: MotionVQVAE) -> str:
    """Names a case's exported graphs: sizes, opset, torch version and a fingerprint of the weights themselves."""
    from t2m.export.graphs.export import OPSET

    digest = hashlib.sha256()
    sizes = [case.gpt.to_dict(), case.vq.to_dict(), torch.__version__, OPSET]
    digest.update(json.dumps(sizes, sort_keys=True).encode())
    for tensor in [*gpt.state_dict().values(), *vq.state_dict().values()]:
        digest.update(tensor.detach().flatten()[:256].numpy().tobytes())  # cheap, and changes with any re-init
    return f"{case.label}-{digest.hexdigest()[:16]}"


def export_case(case: BenchCase, gpt: MotionGPT, vq: MotionVQVAE, graph_dir: Path) -> tuple[Path, Path, float]:
    """The case's step and decoder graphs in graph_dir (reused when already there); returns their paths and export s."""
    from t2m.export.graphs.decoder import export_decoder
    from t2m.families.gpt.export_graphs import export_gpt_step

    key = case_key(case, gpt, vq)
    step_path, decoder_path = graph_dir / f"{key}_gpt_step.onnx", graph_dir / f"{key}_decoder.onnx"
    start = time.perf_counter()
    if not (step_path.is_file() and decoder_path.is_file()):
        mean, std = np.zeros(case.vq.feat_dim, np.float32), np.ones(case.vq.feat_dim, np.float32)
        export_gpt_step(gpt, step_path.with_suffix(".tmp"))
        export_decoder(vq, mean, std, decoder_path.with_suffix(".tmp"))
        step_path.with_suffix(".tmp").replace(step_path)
        decoder_path.with_suffix(".tmp").replace(decoder_path)
    return step_path, decoder_path, time.perf_counter() - start


def bench_case(case: BenchCase, threads: int, graph_dir: Path) -> tuple[list[BenchRow], float]:
    """Export (or reuse) the case's random-weight graphs and time the three methods; also returns the export s."""
    from t2m.export.graphs.export import ort_session

    torch.manual_seed(BENCH_SEED)
    gpt = MotionGPT(case.gpt).eval()
    vq = MotionVQVAE(case.vq).eval()
    step_path, decoder_path, export_seconds = export_case(case, gpt, vq, graph_dir)
    step = ort_session(step_path, threads=threads)
    decoder = ort_session(decoder_path, threads=threads)
    c = case.gpt
    cond, length = _rows_inputs(c, case.tokens)
    names = {i.name for i in step.get_inputs()}
    codes = np.random.default_rng(1).integers(0, c.codebook_size, size=(1, case.tokens)).astype(np.int64)
    cond_t, length_t = torch.from_numpy(cond), torch.from_numpy(length) if c.length_conditioning else None

    def ort_generate() -> None:
        past = np.zeros((c.n_layer, 2, 2, c.n_head, 0, c.head_dim), np.float32)
        token = np.zeros(2, np.int64)
        for position in range(case.tokens):
            feeds = {"cond": cond, "token": token, "position": np.array([position], np.int64), "past_kv": past}
            if "length" in names:
                feeds["length"] = length
            logits, past = step.run(None, feeds)
            guided = logits[1] + 3.0 * (logits[0] - logits[1])
            token = np.full(2, int(guided[: c.codebook_size].argmax()), np.int64)

    @torch.no_grad()
    def torch_kv_generate() -> None:
        past = gpt.empty_cache(2)
        token = torch.zeros(2, dtype=torch.long)
        for position in range(case.tokens):
            logits, past = gpt.forward_step(cond_t, token, position, length_t, past)
            guided = logits[1] + 3.0 * (logits[0] - logits[1])
            token = guided[: c.codebook_size].argmax().repeat(2)

    @torch.no_grad()
    def torch_recompute_generate() -> None:
        prefix = torch.zeros(2, 0, dtype=torch.long)
        for _ in range(case.tokens):
            logits = gpt(cond_t, prefix, length_t)[:, -1]
            guided = logits[1] + 3.0 * (logits[0] - logits[1])
            prefix = torch.cat([prefix, guided[: c.codebook_size].argmax().repeat(2, 1)], dim=1)

    @torch.no_grad()
    def torch_decode() -> None:
        vq.decode(torch.from_numpy(codes))

    def ort_decode() -> None:
        decoder.run(None, {"codes": codes})

    rows = []
    for method, generate, decode in (("onnxruntime + KV cache", ort_generate, ort_decode),
                                     ("PyTorch eager + KV cache", torch_kv_generate, torch_decode),
                                     ("PyTorch eager, prefix recomputed", torch_recompute_generate, torch_decode)):
        decode()  # warm-up (allocations, ORT's first-run optimisations)
        generate() if case.repeats > 1 else None
        ms_generate = median_ms(generate, case.repeats)
        ms_decode = median_ms(decode, max(case.repeats, 3))
        rows.append(BenchRow(case, method, ms_generate / case.tokens, ms_generate, ms_decode))
    return rows, export_seconds


def machine_lines(threads: int) -> list[str]:
    return describe_machine(threads, f"torch {torch.__version__} (threads {torch.get_num_threads()})")


def run_bench(quick: bool = False, threads: int | None = None, include_release: bool = True,
              echo: Callable[[str], None] = print, cases: list[BenchCase] | None = None,
              cache_dir: Path | None = None) -> float:
    """Run the benchmark, print a markdown table; return the embedded GPT size's speedup vs eager recomputation.

    ``cases`` replaces the two standard sizes (the first one is reported as the speedup). Exported graphs
    are kept in ``cache_dir`` (default ~/.cache/t2m/bench; exporting the 1 GB release-size graph takes
    about a minute here, so only the first run pays it); ``cache_dir=None`` with ``cases`` given uses a
    temporary directory.
    """
    threads = threads or os.cpu_count() or 1
    torch.set_num_threads(threads)
    gpt_small, vq_small, source = gpt_sizes()
    if cases is None:
        cases = [BenchCase("gpt", gpt_small, vq_small, tokens=50, repeats=1 if quick else 3, note=source)]
    if include_release and cases[0].label == "gpt" and len(cases) == 1:
        release_tokens = 10 if quick else 50
        cases.append(BenchCase("t2m-gpt-release", RELEASE_GPT, RELEASE_VQ, tokens=release_tokens, repeats=1,
                               note="random weights, 228M-parameter GPT" +
                                    (f"; --quick: {release_tokens} tokens only" if quick else "")))
    echo("## t2m bench" + (" --quick" if quick else ""))
    echo("")
    for line in machine_lines(threads):
        echo(line)
    echo("")
    rows: list[BenchRow] = []
    exports: list[str] = []
    with tempfile.TemporaryDirectory(prefix="t2m-bench-") as tmp:
        graph_dir = Path(cache_dir) if cache_dir else Path(tmp)
        graph_dir.mkdir(parents=True, exist_ok=True)
        for case in cases:
            case_rows, export_seconds = bench_case(case, threads, graph_dir)
            rows += case_rows
            exports.append(f"{case.label} {export_seconds:.1f} s")
    echo("| model | tokens | method | ms / token | ms generate (batch 2) | ms decode | ms total | vs recompute |")
    echo("| --- | --- | --- | --- | --- | --- | --- | --- |")
    speedups = {}
    for case in cases:
        case_rows = [r for r in rows if r.case is case]
        baseline = case_rows[-1].ms_total
        for row in case_rows:
            echo(f"| {case.label} | {case.tokens} | {row.method} | {row.ms_per_token:.2f} | {row.ms_generate:.0f} |"
                 f" {row.ms_decode:.1f} | {row.ms_total:.0f} | {baseline / row.ms_total:.1f}x |")
        speedups[case.label] = baseline / case_rows[0].ms_total
    echo("")
    for case in cases:
        c = case.gpt
        params = sum(p.numel() for p in MotionGPT(c).parameters()) / 1e6
        echo(f"- {case.label}: GPT {c.n_layer} layers x {c.embed} ({c.n_head} heads), ~{params:.1f}M parameters;"
             f" {case.note}; median of {case.repeats} run(s)")
    echo(f"- graph export (not timed): {', '.join(exports)}" + (f"; graphs cached in {cache_dir}" if cache_dir else ""))
    echo("- ms total = generate (50 tokens = 10 s at 4 frames/token, 20 fps, guidance pair) + decode;"
         " vs recompute = PyTorch-recompute total / this total")
    speedup = speedups[cases[0].label]
    echo(f"speedup_vs_eager_recompute={speedup:.1f}x")
    return speedup
