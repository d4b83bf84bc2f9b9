"""GPU suite: every embedded model and the release sizes, onnxruntime on CUDA with the step caches kept on
the device (I/O binding, t2m/runtime/bound_step.py) against the PyTorch eager reference of the same loop on
the same GPU (t2m/model/sampling: the project's own reference steps, their caches left on the device too).

Both columns run the one numpy decoding loop of each family (t2m/decoding: gpt.py, hifigpt.py, masked.py), so the
work is the same algorithm; they differ in the network calls. A "10 s motion" is one segment of 10 s (50 steps for
the 4-frame GPT and masked models, 25 for T2M-HiFiGPT's 8 frames) with guidance (a cond and a null row each);
"batch B" is B such motions stepped together. Decoding (decoder.onnx, on the same providers) is timed apart and added
to both columns, which differ only in sampling. Speed depends on sizes, not values, so random weights at the
release sizes give the releases' speed (T2M-GPT: 228M-parameter GPT, t2m/bench/models.py; MoMask: 8 + 8
layers of 384, t2m/families/masked/momask_release.py). The embedded bundles run their own graphs (int8 step graphs
included, as served); their PyTorch column uses random modules of the manifest's sizes (the masked model's
transformer sizes are not in its manifest: no PyTorch column).

Needs only numpy, torch, onnx, onnxruntime(-gpu) and this repository (no tokenizers, no service stack, no network):
    python -m benchmarks.gpu_suite --out OUT [--device cuda|cpu] [--batches 1,16,64] [--repeats 3]
        [--models gpt,default,masked,t2m-gpt-release,momask-release] [--tiny] [--processes 2,4]
Prints one markdown table, writes OUT/gpu_suite.json (the rows and the machine), and says what is missing (no CUDA
in torch, no CUDAExecutionProvider in onnxruntime) instead of failing. --tiny: the release cases at toy sizes (the
CPU test, tests/test_gpu_suite.py).
"""
from __future__ import annotations

import argparse
import gc
import json
import platform
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort
import torch

from t2m.bench.loops import Generate, gpt_generate, hifigpt_generate, masked_generate, momask_release_decoding

REPO = Path(__file__).resolve().parents[1]

MODELS = ("gpt", "default", "masked", "t2m-gpt-release", "momask-release")


@dataclass
class Row:
    model: str
    batch: int
    method: str
    steps: int                  # network positions per motion (GPT/HiFiGPT: time steps; masked: passes)
    ms_step: float
    ms_generate: float
    ms_decode: float

    @property
    def ms_motion(self) -> float:
        """The batch's 10 s motions, sampled and decoded (the latency of each of them)."""
        return self.ms_generate + self.ms_decode

    @property
    def motions_per_s(self) -> float:
        return 1000 * self.batch / self.ms_motion


@dataclass
class Case:
    """One model: how its two samplers are made and how its codes decode."""

    label: str
    note: str
    steps: int
    onnx: Callable[[Any], Generate]             # execution -> generate
    torch: Callable[[torch.device], Generate] | None
    decoder: Path
    kv_cache: bool = True                       # False: whole-map passes (masked), nothing to bind
    graphed: Callable[[str], Generate] | None = None  # device -> generate with CUDA graphs (engine/graphed_step.py)
    graphed_label: str = "CUDA graphs"
    host: Callable[[int], Generate] | None = None   # largest batch -> the loop over instant steps (host_loop.py)


GRAPHS = ("shipped", "float32", "fp16", "fp16-fused")


@dataclass
class Graphs:
    """Which graphs the onnxruntime column runs: as shipped/exported, int8 ones dequantised to float32, or float16
    (int8 dequantised first); the PyTorch column runs under float16 autocast for fp16. Converted copies go to
    `workdir`, once per file."""

    kind: str
    workdir: Path

    def __call__(self, path: Path) -> Path:
        if self.kind == "shipped":
            return path
        import onnx

        from t2m.export.writing.dequantize import dequantize_graph, is_int8_dynamic
        from t2m.export.writing.quantize import convert_graph_fp16

        out = self.workdir / f"{self.kind}_{path.parent.name}_{path.name}"
        if not out.exists():
            source = path
            if is_int8_dynamic(onnx.load(str(path))):
                source = dequantize_graph(path, self.workdir / f"dequantized_{path.parent.name}_{path.name}")
            if self.kind == "fp16":
                convert_graph_fp16(source, out)
            elif self.kind == "fp16-fused":     # onnxruntime's transformer fusions (SkipLayerNorm, ...), then fp16
                from onnxruntime.transformers.optimizer import optimize_model

                fused = optimize_model(str(source), model_type="gpt2", num_heads=0, hidden_size=0, opt_level=1,
                                       use_gpu=True)
                fused.convert_float_to_float16(keep_io_types=True)
                fused.save_model_to_file(str(out))
            else:
                out.write_bytes(source.read_bytes())
        return out

    @property
    def half(self) -> bool:
        return self.kind.startswith("fp16")

    def torch_context(self, device: str) -> Any:
        import contextlib

        return torch.autocast(device, dtype=torch.float16) if self.half else contextlib.nullcontext()


def median_ms(fn: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1000 * statistics.median(times)


GRAPH_VARIANT: Graphs | None = None      # set by main from --graphs


def session(path: Path, execution: Any, options: ort.SessionOptions | None = None) -> ort.InferenceSession:
    """The graph at `path` on the execution's providers, converted as --graphs says (decoders stay as they are: they
    are timed apart, the same for every column)."""
    from t2m.runtime.bundle_loader import open_session, session_options

    decoder = path.stem == "decoder" or path.stem.endswith("_decoder")
    served = GRAPH_VARIANT(path) if GRAPH_VARIANT is not None and not decoder else path
    return open_session(served, options or session_options(0, 1), execution)


def onnx_gpt(step_path: Path, n_layer: int, n_head: int, head_dim: int, length: bool, dim: int, tokens: int,
             max_tokens: int, end_id: int) -> Callable[[Any], Generate]:
    def make(execution: Any) -> Generate:
        from t2m.runtime.bound_step import BoundGptStep
        from t2m.runtime.onnx_step import OnnxGptStep

        kind = BoundGptStep if execution.binds else OnnxGptStep
        step = kind(session(step_path, execution), n_layer, n_head, head_dim, length)
        return gpt_generate(step, dim, tokens, max_tokens, end_id)
    return make


def capturing_session(path: Path, device: str) -> ort.InferenceSession:
    """The graph at `path` (converted as --graphs says) on `device`, its CUDA provider capturing CUDA graphs."""
    from t2m.runtime.bundle_loader import session_options
    from t2m.runtime.execution import Execution
    from t2m.runtime.graphed_step import graph_session

    served = GRAPH_VARIANT(path) if GRAPH_VARIANT is not None else path
    providers = Execution(("cuda",) if device == "cuda" else ("cpu",)).ort_providers
    return graph_session(served, providers, cuda_graph=device == "cuda", options=session_options(0, 1))


def fixed_gpt(step_path: Path, config: Any, dim: int, tokens: int) -> Callable[[str], Generate]:
    """The GPT loop over the fixed-capacity step (engine/graphed_step.py): CUDA graphs on 'cuda', none on 'cpu'."""
    def make(device: str) -> Generate:
        from t2m.runtime.graphed_step import FixedCacheGptStep

        step = FixedCacheGptStep(capturing_session(step_path, device), config.n_layer, config.n_head,
                                 config.head_dim, config.block_size, config.length_conditioning,
                                 cuda_graph=device == "cuda")
        return gpt_generate(step, dim, tokens, config.max_tokens, config.end_id)
    return make


def torch_gpt(config: Any, dim: int, tokens: int) -> Callable[[torch.device], Generate]:
    def make(device: torch.device) -> Generate:
        from t2m.families.gpt.network import MotionGPT
        from t2m.families.gpt.sampling import TorchGptStep

        torch.manual_seed(0)
        gpt = MotionGPT(config).to(device).eval()
        return gpt_generate(TorchGptStep(gpt, device), dim, tokens, config.max_tokens, config.end_id)
    return make


def embedded_gpt_case() -> Case:
    from t2m.bench.models import gpt_sizes
    from t2m.bundles import GPT_BUNDLE

    manifest = json.loads((GPT_BUNDLE / "manifest.json").read_text())
    g, dim = manifest["gpt"], manifest["text_encoder"]["dim"]
    config, _, _ = gpt_sizes()
    return Case("gpt (t2m/bundles/gpt)", f"{manifest['name']}: {g['n_layer']} layers x "
                f"{g['n_head'] * g['head_dim']}", 50,
                onnx_gpt(GPT_BUNDLE / "gpt_step.onnx", g["n_layer"], g["n_head"], g["head_dim"],
                         g["length_conditioning"], dim, 50, manifest["max_tokens"], manifest["end_id"]),
                torch_gpt(config, dim, 50), GPT_BUNDLE / "decoder.onnx")


def embedded_hifigpt_case() -> Case:
    from t2m.bench.host_loop import default_loop
    from t2m.bundles import DEFAULT_BUNDLE
    from t2m.families.hifigpt.network import HiFiGPTConfig

    manifest = json.loads((DEFAULT_BUNDLE / "manifest.json").read_text())
    h, dim, depth, steps = manifest["hifigpt"], manifest["text_encoder"]["dim"], manifest["residual_layers"], 25

    def make_onnx(execution: Any) -> Generate:
        from t2m.runtime.bound_step import BoundResidualGptStep, BoundTemporalStep
        from t2m.runtime.onnx_step import OnnxResidualGptStep, OnnxTemporalStep

        temporal_kind = BoundTemporalStep if execution.binds else OnnxTemporalStep
        residual_kind = BoundResidualGptStep if execution.binds else OnnxResidualGptStep
        temporal = temporal_kind(session(DEFAULT_BUNDLE / "temporal_step.onnx", execution), depth,
                                 h["n_layer_temporal"], h["n_head"], h["head_dim"], h["length_conditioning"])
        residual = residual_kind(session(DEFAULT_BUNDLE / "residual_step.onnx", execution), h["n_layer_residual"],
                                 h["n_head"], h["head_dim"])
        return hifigpt_generate(temporal, residual, dim, steps, manifest["max_tokens"])

    def make_torch(device: torch.device) -> Generate:
        from t2m.families.hifigpt.network import HiFiGPT
        from t2m.families.hifigpt.sampling import TorchResidualGptStep, TorchTemporalStep

        torch.manual_seed(0)
        config = HiFiGPTConfig(codebook_size=manifest["codebook_size"], depth=depth, embed=h["n_head"] * h["head_dim"],
                               n_head=h["n_head"], n_layer_temporal=h["n_layer_temporal"],
                               n_layer_residual=h["n_layer_residual"], max_tokens=manifest["max_tokens"],
                               text_dim=dim, dropout=0.0, length_conditioning=h["length_conditioning"])
        model = HiFiGPT(config).to(device).eval()
        return hifigpt_generate(TorchTemporalStep(model, device), TorchResidualGptStep(model, device), dim, steps,
                                config.max_tokens)

    quantized = ", ".join(sorted({v for v in manifest.get("quantization", {}).values() if v})) or "float32"
    return Case("default (t2m/bundles/default, T2M-HiFiGPT)", f"{manifest['name']}: step graphs {quantized}; "
                f"{steps} steps x (1 temporal + {depth} residual calls)", steps, make_onnx, make_torch,
                DEFAULT_BUNDLE / "decoder.onnx", host=lambda largest: default_loop(largest)[0])


def onnx_masked(masked_path: Path, residual_path: Path | None, columns: int, mask_id: int, layers: int, pad_id: int,
                dim: int, rows: int, passes: int, decoding: dict[str, Any]) -> Callable[[Any], Generate]:
    def make(execution: Any) -> Generate:
        from t2m.runtime.onnx_step import OnnxMaskedStep, OnnxResidualStep

        masked = OnnxMaskedStep(session(masked_path, execution), columns, mask_id)
        residual = None if residual_path is None else OnnxResidualStep(session(residual_path, execution), layers,
                                                                         pad_id)
        return masked_generate(masked, residual, dim, rows, passes, decoding)
    return make


def graphed_masked(masked_path: Path, residual_path: Path | None, columns: int, mask_id: int, layers: int,
                   pad_id: int, dim: int, rows: int, passes: int,
                   decoding: dict[str, Any]) -> Callable[[str], Generate]:
    """The masked loop with its calls replayed as CUDA graphs, one per input shape (engine/graphed_step.py's
    GraphedSession; on 'cpu' the same buffers, no capture)."""
    def make(device: str) -> Generate:
        from t2m.runtime.graphed_step import GraphedSession
        from t2m.runtime.onnx_step import OnnxMaskedStep, OnnxResidualStep

        def graphed(path: Path) -> Any:
            return GraphedSession(capturing_session(path, device), cuda_graph=device == "cuda")

        masked = OnnxMaskedStep(graphed(masked_path), columns, mask_id)
        residual = None if residual_path is None else OnnxResidualStep(graphed(residual_path), layers, pad_id)
        return masked_generate(masked, residual, dim, rows, passes, decoding)
    return make


def embedded_masked_case() -> Case:
    from t2m.bundles import EMBEDDED_BUNDLES

    MASKED_BUNDLE = EMBEDDED_BUNDLES["masked"]
    manifest = json.loads((MASKED_BUNDLE / "manifest.json").read_text())
    m, layers = manifest["masked"], manifest["residual_layers"]
    decoding = {name: m[name] for name in ("guidance", "residual_guidance", "top_k", "residual_top_k")}
    loop = (MASKED_BUNDLE / "masked.onnx", MASKED_BUNDLE / "residual.onnx" if layers > 1 else None, m["columns"],
            m["mask_id"], layers, m["pad_id"], manifest["text_encoder"]["dim"], 50, m["steps"], decoding)
    return Case("masked (t2m/bundles/masked)", f"{manifest['name']}: {m['steps']} mask passes + {layers - 1} "
                "residual passes; no PyTorch column (transformer sizes not in the manifest)", m["steps"] + layers - 1,
                onnx_masked(*loop), None, MASKED_BUNDLE / "decoder.onnx", kv_cache=False, graphed=graphed_masked(*loop))


def release_gpt_case(workdir: Path, tiny: bool) -> Case:
    """T2M-GPT's release sizes (random weights), exported with the project's exporters."""
    from t2m.bench.models import RELEASE_GPT, RELEASE_VQ
    from t2m.export.graphs.decoder import export_decoder
    from t2m.families.gpt.export_graphs import export_gpt_fixed_cache_step, export_gpt_step
    from t2m.families.gpt.network import GPTConfig, MotionGPT
    from t2m.model.networks.vqvae import MotionVQVAE, VQConfig

    config = (GPTConfig(codebook_size=64, embed=64, n_head=4, n_layer_base=1, n_layer_head=1, block_size=51,
                        dropout=0.0, text_dim=512, length_conditioning=False) if tiny else RELEASE_GPT)
    vq = VQConfig(width=32, code_dim=32, nb_code=64) if tiny else RELEASE_VQ
    step_path, decoder_path = workdir / "t2m_gpt_step.onnx", workdir / "t2m_gpt_decoder.onnx"
    fixed_path = workdir / "t2m_gpt_step_fixed.onnx"
    torch.manual_seed(0)
    gpt = MotionGPT(config).eval()
    export_gpt_step(gpt, step_path)
    export_gpt_fixed_cache_step(gpt, fixed_path)
    export_decoder(MotionVQVAE(vq).eval(), np.zeros(vq.feat_dim, np.float32), np.ones(vq.feat_dim, np.float32),
                   decoder_path)
    params = sum(p.numel() for p in gpt.parameters()) / 1e6
    dim = config.text_dim
    return Case("t2m-gpt-release" + (" (--tiny)" if tiny else ""), f"random weights, GPT {config.n_layer} layers x "
                f"{config.embed}, {params:.0f}M parameters", 50,
                onnx_gpt(step_path, config.n_layer, config.n_head, config.head_dim, config.length_conditioning, dim,
                         50, config.max_tokens, config.end_id),
                torch_gpt(config, dim, 50), decoder_path, graphed=fixed_gpt(fixed_path, config, dim, 50),
                graphed_label="fixed cache + CUDA graphs")


def release_momask_case(workdir: Path, tiny: bool) -> Case:
    """MoMask's release sizes (random weights): the masked and residual transformers and the RVQ decoder."""
    from t2m.families.masked.export_graphs import export_joint_decoder, export_masked, export_residual
    from t2m.families.masked.masked_transformer import MaskedTransformer
    from t2m.families.masked.residual_transformer import ResidualTransformer
    from t2m.model.networks.token_transformer import TokenTransformerConfig
    from t2m.model.networks.vqvae import MotionVQVAE, VQConfig

    size = {"latent": 48, "n_head": 6, "n_layer": 1, "ff_size": 64, "codebook": 64, "width": 32} if tiny else \
        {"latent": 384, "n_head": 6, "n_layer": 8, "ff_size": 1024, "codebook": 512, "width": 512}
    layers, rows, passes, dim = 6, 49, 10, 512
    config = TokenTransformerConfig(codebook_size=size["codebook"], columns=1, residual_layers=layers,
                                    max_tokens=rows, latent=size["latent"], n_head=size["n_head"],
                                    n_layer=size["n_layer"], ff_size=size["ff_size"], dropout=0.0, text_dim=dim,
                                    code_dim=size["width"], positional="1d", spatial_attention=False,
                                    temporal_attention=False)
    torch.manual_seed(0)
    masked, residual = MaskedTransformer(config).eval(), ResidualTransformer(config).eval()
    vq = MotionVQVAE(VQConfig(width=size["width"], code_dim=size["width"], nb_code=size["codebook"],
                              quantizer="residual", residual_layers=layers)).eval()
    paths = {name: workdir / f"momask_{name}.onnx" for name in ("masked", "residual", "decoder")}
    export_masked(masked, paths["masked"])
    export_residual(residual, paths["residual"])
    export_joint_decoder(vq, np.zeros(vq.config.feat_dim, np.float32), np.ones(vq.config.feat_dim, np.float32),
                         paths["decoder"])

    def make_torch(device: torch.device) -> Generate:
        from t2m.families.masked.sampling import TorchMaskedStep, TorchResidualStep

        return masked_generate(TorchMaskedStep(masked.to(device), device),
                               TorchResidualStep(residual.to(device), device), dim, rows, passes,
                               momask_release_decoding(size["codebook"]))

    params = sum(p.numel() for p in [*masked.parameters(), *residual.parameters()]) / 1e6
    loop = (paths["masked"], paths["residual"], 1, masked.config.mask_id, layers, residual.pad_id, dim, rows, passes,
            momask_release_decoding(size["codebook"]))
    return Case("momask-release" + (" (--tiny)" if tiny else ""), f"random weights, masked + residual transformers "
                f"{config.n_layer} layers x {config.latent} ({params:.0f}M parameters), {rows} rows (196 frames), "
                f"{passes} mask passes + {layers - 1} residual passes", passes + layers - 1,
                onnx_masked(*loop), make_torch, paths["decoder"], kv_cache=False, graphed=graphed_masked(*loop))


def case_builders(workdir: Path, tiny: bool) -> dict[str, Callable[[], Case]]:
    """Each model's Case builder (the release cases write their random checkpoints under `workdir`)."""
    return {"gpt": embedded_gpt_case, "default": embedded_hifigpt_case, "masked": embedded_masked_case,
            "t2m-gpt-release": lambda: release_gpt_case(workdir, tiny),
            "momask-release": lambda: release_momask_case(workdir, tiny)}


def processes_rows(case: Case, name: str, args: argparse.Namespace, workdir: Path, failures: list[str]) -> list[Row]:
    """--processes: N processes, each generating and decoding batches of B on the device at once
    (benchmarks/gpu_processes.py); the row's batch is N x B and its ms the wall time per round, decode included."""
    from benchmarks.gpu_processes import EMBEDDED, processes_wall_s

    if name not in EMBEDDED:
        return []
    kind = GRAPH_VARIANT.kind if GRAPH_VARIANT is not None else "shipped"
    graphs = "" if kind == "shipped" else f" {kind}"
    rows = []
    for processes in args.processes:
        for batch in args.batches:
            def one_row(processes: int = processes, batch: int = batch) -> Row:
                wall = processes_wall_s(name, kind, workdir, args.device, processes, batch, args.repeats)
                ms = 1000 * wall / args.repeats
                return Row(case.label, processes * batch, f"onnxruntime {args.device}{graphs}, {processes} processes "
                           f"x batch {batch} (decode included)", case.steps, ms / case.steps, ms, 0.0)

            row = attempt(failures, f"{case.label} {processes} processes x batch {batch}", one_row)
            if row is not None:
                rows.append(row)
                print(f"  {row.method}: {row.motions_per_s:.0f} motions/s", file=sys.stderr, flush=True)
    return rows


def what_is_missing(device: str) -> tuple[bool, bool, list[str]]:
    """(onnxruntime can run on the device, torch can, the missing pieces in words)."""
    missing = []
    ort_ok = device == "cpu" or "CUDAExecutionProvider" in ort.get_available_providers()
    torch_ok = device == "cpu" or torch.cuda.is_available()
    if not ort_ok:
        missing.append(f"onnxruntime {ort.__version__} has no CUDAExecutionProvider (available: "
                       f"{', '.join(ort.get_available_providers())}): install onnxruntime-gpu; no onnxruntime column")
    if not torch_ok:
        missing.append(f"torch {torch.__version__} sees no CUDA device: no PyTorch column")
    return ort_ok, torch_ok, missing


def load_cuda_libraries() -> None:
    """Load CUDA, cuBLAS and cuDNN into the process through torch (the nvidia-* wheels it brought), so that
    onnxruntime-gpu's CUDA provider finds them by name; then onnxruntime's own preload where it has one."""
    x = torch.ones(1, 4, 8, device="cuda")
    torch.nn.functional.conv1d(x, torch.ones(4, 4, 3, device="cuda")).sum().item()
    (x[0] @ x[0].T).sum().item()
    if hasattr(ort, "preload_dlls"):
        try:
            ort.preload_dlls()
        except Exception as error:  # pragma: no cover - only where those libraries are broken
            print(f"onnxruntime.preload_dlls(): {error}", file=sys.stderr)


def decode_ms(decoder: Any, codes: np.ndarray, repeats: int) -> float:
    decoder.run(None, {"codes": codes})
    return median_ms(lambda: decoder.run(None, {"codes": codes}), repeats)


def agreement(case: Case, samplers: dict[str, Generate | None], notes: list[str]) -> None:
    """How many of the CUDA-graph column's codes (batch 4) equal the plain onnxruntime column's (I/O binding where
    there is a cache): the check, on the device, that the captured graphs compute the same calls
    (tests/service/test_graphed_step.py checks it on the CPU)."""
    graphed = next((g for method, g in samplers.items() if case.graphed_label in method and g is not None), None)
    plain = next((g for method, g in samplers.items() if method.startswith("onnxruntime")
                  and case.graphed_label not in method and "numpy caches" not in method and g is not None), None)
    if graphed is None or plain is None:
        return
    want, got = plain(4), graphed(4)
    same = got == want if got.shape == want.shape else np.zeros(1, bool)
    notes.append(f"- {case.label}, {case.graphed_label}: its codes equal to the plain onnxruntime ones: "
                 f"{int(same.sum())} of {want.size} (batch 4, same seeds)")


def bench_case(case: Case, device: str, batches: list[int], repeats: int, ort_ok: bool, torch_ok: bool,
               failures: list[str], notes: list[str]) -> list[Row]:
    """The case's rows; a method that cannot be built or run is reported in `failures`, the others go on."""
    from t2m.runtime.execution import Execution

    providers = ("cuda",) if device == "cuda" else ("cpu",)
    variant = GRAPH_VARIANT or Graphs("shipped", Path())
    graphs = "" if variant.kind == "shipped" else f" {variant.kind}"
    makers: dict[str, Callable[[], Generate]] = {}
    if ort_ok and case.kv_cache:
        makers[f"onnxruntime {device}{graphs}, I/O binding"] = \
            lambda: case.onnx(Execution(providers, io_binding="on"))
        makers[f"onnxruntime {device}{graphs}, numpy caches"] = \
            lambda: case.onnx(Execution(providers, io_binding="off"))
    elif ort_ok:
        makers[f"onnxruntime {device}{graphs}"] = lambda: case.onnx(Execution(providers))
    if case.host is not None:
        host, largest = case.host, max(batches)
        makers["host loop alone (instant network)"] = lambda: host(largest)
    if ort_ok and case.graphed is not None:
        graphed, label = case.graphed, case.graphed_label if device == "cuda" else f"{case.graphed_label}, no capture"
        makers[f"onnxruntime {device}{graphs}, {label}"] = lambda: graphed(device)
    if torch_ok and case.torch is not None:
        def make_torch() -> Generate:
            generate = case.torch(torch.device(device))  # type: ignore[misc]

            def in_precision(batch: int) -> np.ndarray:
                with variant.torch_context(device):
                    return generate(batch)
            return in_precision
        makers[f"PyTorch eager {device}{' fp16 autocast' if variant.half else ''}"] = make_torch
    decoder = attempt(failures, f"{case.label} decoder.onnx", lambda: session(case.decoder, Execution(providers)))
    samplers = {method: attempt(failures, f"{case.label} {method}", make) for method, make in makers.items()}
    if case.graphed is not None:
        attempt(failures, f"{case.label} {case.graphed_label} agreement", lambda: agreement(case, samplers, notes))
    sync = torch.cuda.synchronize if device == "cuda" and torch_ok else (lambda: None)
    rows = []
    for batch in batches:
        for method, generate in samplers.items():
            if generate is None:
                continue

            def timed(generate: Generate = generate, batch: int = batch) -> np.ndarray:
                codes = generate(batch)
                sync()
                return codes

            def one_row(method: str = method, timed: Callable[[], np.ndarray] = timed, batch: int = batch) -> Row:
                codes = timed()                     # warm-up: allocations, kernels, cuDNN/cuBLAS choices
                ms_generate = median_ms(timed, repeats)
                ms_decode = decode_ms(decoder, codes, repeats) if decoder is not None else float("nan")
                return Row(case.label, batch, method, case.steps, ms_generate / case.steps, ms_generate, ms_decode)

            row = attempt(failures, f"{case.label} batch {batch} {method}", one_row)
            if row is not None:
                rows.append(row)
                print(f"  {case.label} batch {batch} {method}: {row.ms_generate:.0f} ms", file=sys.stderr,
                      flush=True)
    return rows


def attempt(failures: list[str], what: str, fn: Callable[[], Any]) -> Any:
    """fn(), or None with the failure noted in one line (one method's failure must not lose the other rows)."""
    try:
        return fn()
    except Exception as error:
        failures.append(f"- {what}: failed: {type(error).__name__}: {str(error).splitlines()[0][:300]}")
        print(failures[-1], file=sys.stderr, flush=True)
        return None


def table(rows: list[Row]) -> list[str]:
    lines = ["| model | batch | method | steps | ms / step | ms generate | ms decode | ms per 10 s motion | "
             "motions / s | vs PyTorch |", "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for row in rows:
        torch_row = next((r for r in rows if r.model == row.model and r.batch == row.batch
                          and r.method.startswith("PyTorch")), None)
        ratio = f"{torch_row.ms_motion / row.ms_motion:.2f}x" if torch_row is not None else "-"
        lines.append(f"| {row.model} | {row.batch} | {row.method} | {row.steps} | {row.ms_step:.2f} | "
                     f"{row.ms_generate:.1f} | {row.ms_decode:.1f} | {row.ms_motion:.1f} | {row.motions_per_s:.1f} | "
                     f"{ratio} |")
    return lines


def machine(device: str) -> dict[str, Any]:
    info: dict[str, Any] = {"python": platform.python_version(), "platform": platform.platform(),
                            "torch": torch.__version__, "onnxruntime": ort.__version__,
                            "ort_providers": ort.get_available_providers(), "device": device}
    if torch.cuda.is_available():
        info["gpu"] = torch.cuda.get_device_name(0)
        info["torch_cuda"] = torch.version.cuda
    return info


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=(__doc__ or "").strip().splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="folder for gpu_suite.json")
    parser.add_argument("--device", choices=("cuda", "cpu"), default="cuda")
    parser.add_argument("--batches", default="1,16,64", help="comma-separated motions per batch (default 1,16,64)")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per row, median reported (default 3)")
    parser.add_argument("--models", default=",".join(MODELS), help=f"comma-separated subset of {', '.join(MODELS)}")
    parser.add_argument("--tiny", action="store_true", help="release cases at toy sizes (tests on CPU)")
    parser.add_argument("--graphs", choices=GRAPHS, default="shipped",
                        help="shipped: the graphs as exported (the default model's steps are int8); float32: int8 "
                             "graphs dequantised; fp16: float16 graphs (int8 dequantised first) and PyTorch under "
                             "float16 autocast; fp16-fused: onnxruntime's transformer fusions first")
    parser.add_argument("--processes", default="",
                        help="comma-separated process counts: also run the embedded models in N processes at once "
                             "on the device, each at every batch (benchmarks/gpu_processes.py)")
    args = parser.parse_args(argv)
    args.batches = [int(b) for b in args.batches.split(",") if b.strip()]
    args.processes = [int(n) for n in args.processes.split(",") if n.strip()]
    args.models = [m.strip() for m in args.models.split(",") if m.strip()]
    unknown = [m for m in args.models if m not in MODELS]
    if unknown or args.repeats < 1 or not args.batches or min(args.batches + args.processes) < 1:
        parser.error(f"--models from {', '.join(MODELS)} (unknown: {unknown}); --repeats, --batches and "
                     "--processes >= 1")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    ort_ok, torch_ok, missing = what_is_missing(args.device)
    if args.device == "cuda" and torch_ok:
        load_cuda_libraries()
    for line in missing:
        print(f"missing: {line}")
    if not (ort_ok or torch_ok):
        print("nothing can run on this device; no table")
        return 3
    torch.set_grad_enabled(False)
    started = time.perf_counter()
    rows: list[Row] = []
    notes: list[str] = []
    failures: list[str] = []
    global GRAPH_VARIANT
    with tempfile.TemporaryDirectory(prefix="gpu-suite-") as temporary:
        workdir = Path(temporary)
        GRAPH_VARIANT = Graphs(args.graphs, workdir)
        builders = case_builders(workdir, args.tiny)
        for name in args.models:
            built = time.perf_counter()
            case = attempt(failures, name, builders[name])
            gc.collect()
            gc.freeze()      # as the service does once its models are loaded (T2M_GC_FREEZE)
            if case is not None:
                notes.append(f"- {case.label}: {case.note} (built in {time.perf_counter() - built:.0f} s)")
                case_rows = bench_case(case, args.device, args.batches, args.repeats, ort_ok, torch_ok, failures,
                                       notes)
                if args.processes and ort_ok:
                    case_rows += processes_rows(case, name, args, workdir, failures)
                rows += case_rows
                print("\n".join(table(case_rows)[2:]), file=sys.stderr, flush=True)   # a cut-off run keeps them
                write_record(args.out, machine(args.device), missing, failures, notes, rows)
    info = machine(args.device)
    print(f"## GPU suite ({args.device}; {info.get('gpu', platform.processor() or 'cpu')}; torch {torch.__version__}; "
          f"onnxruntime {ort.__version__})\n")
    print("\n".join(table(rows)))
    print("\n" + "\n".join(notes + failures + [
        f"- batch B = B motions of 10 s with guidance (2B rows); median of {args.repeats} run(s) after a warm-up; "
        "ms per 10 s motion = the batch's generate + decode; motions / s = B / that; vs PyTorch = the PyTorch "
        "row's ms per 10 s motion / this row's; the garbage collector frozen after each model's build, as the service "
        "freezes it after loading", f"- whole run {time.perf_counter() - started:.0f} s"]))
    write_record(args.out, info, missing, failures, notes, rows)
    return 1 if failures else 0


def write_record(out: Path, info: dict[str, Any], missing: list[str], failures: list[str], notes: list[str],
                 rows: list[Row]) -> None:
    """OUT/gpu_suite.json, rewritten after each model so that a run cut off by its time limit keeps what it measured."""
    out.mkdir(parents=True, exist_ok=True)
    record = {"machine": info, "missing": missing, "failures": failures, "notes": notes,
              "rows": [{**asdict(row), "ms_motion": row.ms_motion, "motions_per_s": row.motions_per_s}
                       for row in rows]}
    (out / "gpu_suite.json").write_text(json.dumps(record, indent=2))


if __name__ == "__main__":
    raise SystemExit(main())
