"""T2M-HiFiGPT vs the 1-layer GPT at equal width and depth: ms per generated step and per 10 s motion.

Random weights, onnxruntime, the service's own loops and graphs (t2m.families.gpt.loop over gpt_step.onnx;
t2m.families.hifigpt.loop over temporal_step.onnx + residual_step.onnx), guidance on (cond + null rows, batch 2), a 10 s
motion of fixed length: the GPT makes 50 codes of 4 frames, HiFiGPT 25 time steps of 8 frames x R depths. The GPT
has L layers; HiFiGPT L/2 temporal + L/2 residual ("equal width and depth"). Decoding (a random VQ decoder of the
default width, 4 or 8 frames per code) is timed apart. Printed, never asserted; one run per row (median of --repeats).

Part 2 (--variants) measures the two ways of exporting the residual GPT at the paper's size: one graph call per depth
with its own small cache and the draws in numpy (what the bundle contract uses), against the whole depth loop in one
graph (the R depth steps unrolled, with guidance, temperature and the inverse-CDF draw inside, uniforms fed in).

    t2m bench hifigpt-vs-gpt [--threads 1] [--repeats 3] [--depths 4 6] [--no-paper] [--variants]
"""
from __future__ import annotations

import argparse
import tempfile
from collections.abc import Callable
from functools import partial
from pathlib import Path

import numpy as np
import torch
from torch import nn

from t2m.bench.machine import describe_machine
from t2m.bench.models import median_ms
from t2m.decoding.lockstep import SamplingJob
from t2m.export.graphs.decoder import export_decoder
from t2m.export.graphs.export import export_graph, ort_session
from t2m.families.gpt.export_graphs import export_gpt_step
from t2m.families.gpt.loop import sample_codes
from t2m.families.gpt.network import GPTConfig, MotionGPT
from t2m.families.hifigpt.export_graphs import export_residual_step, export_temporal_step, onnx_steps
from t2m.families.hifigpt.loop import depth_loop, sample_code_rows
from t2m.families.hifigpt.network import HiFiGPT, HiFiGPTConfig
from t2m.model.networks.vqvae import MotionVQVAE, VQConfig
from t2m.runtime.onnx_step import OnnxGptStep

TEXT_DIM = 384
SECONDS = 10


def _median_ms(fn: Callable[[], object], repeats: int) -> float:
    """t2m bench's median after one warm-up call."""
    fn()
    return median_ms(fn, repeats)


def _job(steps: int, guidance: float = 3.0) -> SamplingJob:
    cond = np.random.default_rng(0).normal(size=(1, TEXT_DIM)).astype(np.float32)
    return SamplingJob(conds=cond, targets=[steps], guidance=guidance, temperature=1.0, top_k=None,
                       rng=np.random.default_rng(0))


def _decoder_ms(down_t: int, codes_shape: tuple[int, ...], out: Path, repeats: int, threads: int) -> float:
    torch.manual_seed(0)
    residual = len(codes_shape) == 2   # [steps, R]; the GPT's [tokens]
    vq = MotionVQVAE(VQConfig(nb_code=256, down_t=down_t, quantizer="residual" if residual else "ema_reset",
                              residual_layers=codes_shape[-1] if residual else 1)).eval()
    name = "decoder_" + "_".join(map(str, codes_shape)) + ".onnx"
    path = export_decoder(vq, np.zeros(263, np.float32), np.ones(263, np.float32), out / name)
    session = ort_session(path, threads)
    codes = np.zeros((1, *codes_shape), np.int64)
    return _median_ms(lambda: session.run(None, {"codes": codes}), repeats)


def compare(label: str, embed: int, heads: int, layers: int, depths: list[int], out: Path, repeats: int,
            threads: int) -> None:
    """One GPT row and one HiFiGPT row per depth R, at width `embed` and `layers` layers in all."""
    torch.manual_seed(0)
    gpt = MotionGPT(GPTConfig(codebook_size=512, embed=embed, n_head=heads, n_layer_base=layers - layers // 2,
                              n_layer_head=layers // 2, block_size=51, dropout=0.0, text_dim=TEXT_DIM)).eval()
    path = export_gpt_step(gpt, out / f"gpt_{label}.onnx")
    c = gpt.config
    step = OnnxGptStep(ort_session(path, threads), c.n_layer, c.n_head, c.head_dim, True)
    tokens = SECONDS * 20 // 4
    gpt_ms = _median_ms(lambda: sample_codes(step, [_job(tokens)], c.max_tokens, c.end_id), repeats)
    decode_ms = _decoder_ms(2, (tokens,), out, repeats, threads)
    print(f"| {label} | 1-layer GPT, {layers} layers, K 512, 4 frames/code | {gpt.num_parameters() / 1e6:.1f} | "
          f"{tokens} x 1 | {gpt_ms / tokens:.2f} | {gpt_ms:.0f} | {decode_ms:.1f} | {gpt_ms + decode_ms:.0f} |")
    for depth in depths:
        model = HiFiGPT(HiFiGPTConfig(codebook_size=256, depth=depth, code_dim=256, shared_codebook=True,
                                      embed=embed, n_head=heads, n_layer_temporal=layers // 2,
                                      n_layer_residual=layers - layers // 2, max_tokens=25, text_dim=TEXT_DIM,
                                      dropout=0.0)).eval()
        temporal_path = export_temporal_step(model, out / f"temporal_{label}_{depth}.onnx")
        residual_path = export_residual_step(model, out / f"residual_{label}_{depth}.onnx")
        temporal, residual = onnx_steps(model, temporal_path, residual_path, threads)
        steps = SECONDS * 20 // 8
        ms = _median_ms(partial(sample_code_rows, temporal, residual, [_job(steps)], 25), repeats)
        decode_ms = _decoder_ms(3, (steps, depth), out, repeats, threads)
        print(f"| {label} | HiFiGPT {layers // 2} + {layers - layers // 2} layers, K 256, R {depth}, 8 frames/code"
              f" | {model.num_parameters() / 1e6:.1f} | {steps} x (1 + {depth}) | {ms / steps:.2f} "
              f"({ms / steps / (1 + depth):.2f} per call) | {ms:.0f} | {decode_ms:.1f} | {ms + decode_ms:.0f} |")


class DepthLoopGraph(nn.Module):
    """The whole depth loop of one time step in one graph: R residual steps with the cache kept inside, guidance,
    temperature and the inverse-CDF draw from given uniforms (rows: S cond rows then S null rows)."""

    def __init__(self, model: HiFiGPT) -> None:
        super().__init__()
        self.model = model

    def forward(self, context: torch.Tensor, guidance: torch.Tensor, inv_temperature: torch.Tensor,
                uniforms: torch.Tensor) -> torch.Tensor:
        model, segments = self.model, guidance.shape[0]
        past = model.empty_cache("residual", context.shape[0])
        code = torch.zeros(context.shape[0], dtype=torch.long)
        chosen = []
        for depth in range(model.config.depth):
            logits, past = model.residual_step(context, code, depth, past)
            cond, null = logits[:segments], logits[segments:]
            guided = (null + guidance[:, None] * (cond - null)) * inv_temperature[:, None]
            cdf = torch.cumsum(torch.softmax(guided, dim=-1), dim=-1)
            pick = (cdf < uniforms[:, depth:depth + 1]).sum(dim=-1).clamp(max=guided.shape[-1] - 1)
            chosen.append(pick)
            code = torch.cat([pick, pick])
        return torch.stack(chosen, dim=1)


def variants(depths: list[int], out: Path, repeats: int, threads: int) -> None:
    """Paper size (E 512, 16 heads, 9 residual layers, K 256): per-depth calls vs one depth-loop graph, one step."""
    print("\n| residual GPT export (paper size: E 512, 16 heads, 9 layers, K 256), guidance pair | R | ms per time"
          " step: one call per depth + numpy draws | ms: whole depth loop in one graph | ratio |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for depth in depths:
        torch.manual_seed(0)
        model = HiFiGPT(HiFiGPTConfig(codebook_size=256, depth=depth, code_dim=256, shared_codebook=True, embed=512,
                                      n_head=16, n_layer_temporal=1, n_layer_residual=9, max_tokens=25,
                                      text_dim=TEXT_DIM, dropout=0.0)).eval()
        temporal_path = export_temporal_step(model, out / f"vt_{depth}.onnx")
        residual_path = export_residual_step(model, out / f"vr_{depth}.onnx")
        _, residual = onnx_steps(model, temporal_path, residual_path, threads)
        job = _job(1)
        context = np.random.default_rng(1).normal(size=(2, 512)).astype(np.float32)
        per_call = _median_ms(partial(depth_loop, residual, context, [(job, [0])], np.array([0, 0]), depth, None),
                              repeats)
        inputs = (torch.from_numpy(context), torch.tensor([3.0]), torch.tensor([1.0]), torch.rand(1, depth))
        loop_path = export_graph(DepthLoopGraph(model).eval(), inputs, out / f"loop_{depth}.onnx",
                                 ["context", "guidance", "inv_temperature", "uniforms"], ["codes"],
                                 {"context": {0: "rows"}, "guidance": {0: "segments"},
                                  "inv_temperature": {0: "segments"}, "uniforms": {0: "segments"},
                                  "codes": {0: "segments"}})
        session = ort_session(loop_path, threads)
        feeds = {"context": context, "guidance": np.array([3.0], np.float32),
                 "inv_temperature": np.array([1.0], np.float32),
                 "uniforms": np.random.default_rng(0).random((1, depth)).astype(np.float32)}
        whole = _median_ms(partial(session.run, None, feeds), repeats)
        print(f"| | {depth} | {per_call:.2f} | {whole:.2f} | {per_call / whole:.2f}x |")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--depths", type=int, nargs="+", default=[4, 6])
    parser.add_argument("--no-paper", action="store_true", help="skip the paper's size (E 512, 18 layers)")
    parser.add_argument("--variants", action="store_true", help="also time the residual GPT's two export variants")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    for line in describe_machine(args.threads):
        print(line)
    print(f"\n10 s motion ({SECONDS * 20} frames), guidance 3 (cond + null rows), median of {args.repeats} after a "
          "warm-up, random weights\n")
    print("| size | model | M params | steps x calls | ms per step | ms codes (10 s) | ms decode | ms total |")
    print("| --- | --- | ---: | --- | ---: | ---: | ---: | ---: |")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        compare("default (E 256, 4 heads, 4 layers)", 256, 4, 4, args.depths, out, args.repeats, args.threads)
        if not args.no_paper:
            compare("paper (E 512, 16 heads, 18 layers)", 512, 16, 18, args.depths, out, args.repeats, args.threads)
        if args.variants:
            variants(args.depths, out, args.repeats, args.threads)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
