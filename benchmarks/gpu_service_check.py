"""The service's CUDA-graph path end to end: a MoMask import and a T2M-GPT import (`--cuda-graph-step`)
at their release sizes (random weights in the releases' exact checkpoint layouts, a small random CLIP), each as
imported (float32) and as `t2m quantize --scheme fp16` converts it, served by the engine plainly and with
T2M_CUDA_GRAPHS, one 9.8 s request (49 token rows or tokens, the releases' longest) at a time: ms per request (text,
codes, decode), ms in the codes stage and per network call, whether the motions are the same, and what /health says
is captured. On 'cpu' the same code runs without capture (the check that this script works before it spends device
time).

    python -m benchmarks.gpu_service_check --device cuda [--sizes release|small] [--repeats 5]
        [--models momask,t2m-gpt] [--schemes float32,fp16]
"""
from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def _small_clip(workdir: Path) -> Path:
    from t2m.testing.clip_release import openai_clip_state, save_torchscript_archive

    return save_torchscript_archive(openai_clip_state(width=64, layers=2, embed_dim=512, seed=5),
                                    workdir / "ViT-B-32.pt")


def import_momask_release(workdir: Path, release_sizes: bool) -> Path:
    """`t2m import momask` of random release-layout checkpoints: the bundle folder."""
    from t2m.families.masked.import_momask import import_momask
    from t2m.families.masked.momask_release import (
        RELEASE,
        SMALL,
        release_states,
        write_release,
    )

    sizes = RELEASE if release_sizes else SMALL
    root = workdir / "checkpoints" / "t2m"
    write_release(root, release_states(sizes, std=0.7 / sizes.latent ** 0.5))
    out = workdir / "momask"
    import_momask(root, out, clip_weights=_small_clip(workdir), check_parity=False)
    return out


def import_t2m_gpt_release(workdir: Path, release_sizes: bool) -> Path:
    """`t2m import t2m-gpt --cuda-graph-step` of random release-layout checkpoints (the release's 18 layers of 1024,
    or a small stand-in): the bundle folder."""
    from t2m.families.gpt.import_t2m_gpt import import_t2m_gpt
    from t2m.families.gpt.t2m_gpt_release import (
        release_gpt_state,
        release_vq_state,
        write_release_files,
    )

    vq = release_vq_state(seed=1) if release_sizes else release_vq_state(width=64, code_dim=32, nb_code=64, seed=1)
    gpt = (release_gpt_state(seed=2) if release_sizes else
           release_gpt_state(codebook=64, embed=64, layers=(1, 1), seed=2, std=0.05))
    files = write_release_files(workdir / "t2m-gpt-release", vq, gpt)
    out = workdir / "t2m-gpt"
    import_t2m_gpt(files["net_last.pth"], files["net_best_fid.pth"], files["mean.npy"], files["std.npy"], out,
                   clip_weights=_small_clip(workdir), check_parity=False, fixed_step=True)
    return out


IMPORTS: dict[str, tuple[str, Callable[[Path, bool], Path]]] = {
    "momask": ("MoMask", import_momask_release), "t2m-gpt": ("T2M-GPT", import_t2m_gpt_release)}


def fp16_copy(bundle: Path) -> Path:
    """`t2m quantize BUNDLE --scheme fp16` (gpt_step_fixed.onnx included), without its parity run (CPU time)."""
    from t2m.export.writing.int8 import quantize_bundle

    out = bundle.with_name(bundle.name + "-fp16")
    quantize_bundle(bundle, out, scheme="fp16", parity=False)
    return out


class StageClock:
    """Times the engine's codes stage and counts its network calls (the engine's `codes.sample` wrapped)."""

    def __init__(self, engine) -> None:
        self.seconds: list[float] = []
        self.calls = 0
        sample = engine.codes.sample

        def timed_sample(jobs, max_tokens, on_step):
            def count(rows: int) -> None:
                self.calls += 1
                if on_step is not None:
                    on_step(rows)
            started = time.perf_counter()
            try:
                return sample(jobs, max_tokens, count)
            finally:
                self.seconds.append(time.perf_counter() - started)

        engine.codes.sample = timed_sample


def timed(engine, clock: StageClock, request, repeats: int) -> tuple[float, float, float, np.ndarray]:
    """Medians over `repeats` requests after two warm-ups (allocations, captures): ms per request, ms in the codes
    stage, ms per network call of that stage; and the motion."""
    for _ in range(2):
        motion = engine.generate(request)
    clock.seconds.clear()
    clock.calls = 0
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        motion = engine.generate(request)
        times.append((time.perf_counter() - started) * 1e3)
    codes_ms = 1e3 * statistics.median(clock.seconds)
    return statistics.median(times), codes_ms, codes_ms / (clock.calls / repeats), motion.joints


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").strip().splitlines()[0])
    parser.add_argument("--device", choices=("cuda", "cpu"), default="cuda")
    parser.add_argument("--sizes", choices=("release", "small"), default="release")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path, help="folder for gpu_service_check.md (tools/gpu/run_suite.sh passes "
                                                 "one when it runs this as GPU_SCRIPT)")
    parser.add_argument("--models", default="momask,t2m-gpt", help=f"comma-separated, of {', '.join(IMPORTS)}")
    parser.add_argument("--schemes", default="float32,fp16", help="float32 (as imported) and/or fp16 (t2m quantize)")
    args = parser.parse_args(argv)
    from t2m.runtime.engine import OnnxEngine
    from t2m.runtime.execution import Execution
    from t2m.runtime.types import GenerationRequest, SegmentRequest

    request = GenerationRequest([SegmentRequest("a person walks forward and turns around", 9.8)], seed=3)
    rows, notes = [], []
    with tempfile.TemporaryDirectory(prefix="gpu-service-") as folder:
        for model in args.models.split(","):
            label, build = IMPORTS[model]
            started = time.perf_counter()
            bundle = build(Path(folder), args.sizes == "release")
            print(f"- {label} import ({args.sizes} sizes, random weights) in {time.perf_counter() - started:.0f} s",
                  flush=True)
            for scheme in args.schemes.split(","):
                served = bundle if scheme == "float32" else fp16_copy(bundle)
                motions = {}
                for graphs in (False, True):
                    engine = OnnxEngine.load(served, intra_op_threads=1,
                                             execution=Execution((args.device,), cuda_graphs=graphs))
                    ms, codes_ms, call_ms, motions[graphs] = timed(engine, StageClock(engine), request, args.repeats)
                    captured = engine.limits.details["execution"]["cuda_graphs"]
                    rows.append(f"| {label} | {scheme} | {args.device} | {'on' if graphs else 'off'} | {ms:.1f} | "
                                f"{codes_ms:.1f} | {call_ms:.2f} | {captured} |")
                    print(rows[-1], flush=True)
                difference = float(np.abs(motions[True] - motions[False]).max())
                notes.append(f"- {label} {scheme}: largest joint difference between the two motions: "
                             f"{difference:.2e} m (same seed)")
    lines = ["| model | graphs | provider | T2M_CUDA_GRAPHS | ms per 9.8 s request | ms in codes | ms per network "
             "call | captured graphs |", "| --- | --- | --- | --- | ---: | ---: | ---: | --- |", *rows, "",
             f"- medians of {args.repeats} requests after two warm-ups; a T2M-GPT call is one token, a MoMask call "
             "one mask or residual pass", *notes]
    print("\n" + "\n".join(lines))
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "gpu_service_check.md").write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
