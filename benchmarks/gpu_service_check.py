"""The service's CUDA-graph path end to end (issue 29): a MoMask import at its release sizes (random weights in the
release's exact checkpoint layout, a small random CLIP) served by the engine plainly and with T2M_CUDA_GRAPHS,
one 9.8 s request (49 token rows, the release's longest) at a time: ms per request (text, codes, decode),
whether the motions are the same, and what /health says is captured. On 'cpu' the same code runs without capture
(the check that this script works before it spends device time).

    python benchmarks/gpu_service_check.py --device cuda [--sizes release|small] [--repeats 5]
"""
from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO), str(REPO / "tests" / "export")]   # the tests' release-layout writers


def build_import(workdir: Path, release_sizes: bool) -> Path:
    """`t2m import momask` of random release-layout checkpoints: the bundle folder."""
    from momask_release_files import (  # type: ignore[import-not-found]
        RELEASE,
        SMALL,
        release_states,
        write_release,
    )

    from t2m.export.importers.momask import import_momask
    from tests.model.openai_clip_format import openai_clip_state, save_torchscript_archive

    sizes = RELEASE if release_sizes else SMALL
    root = workdir / "checkpoints" / "t2m"
    write_release(root, release_states(sizes, std=0.7 / sizes.latent ** 0.5))
    clip = save_torchscript_archive(openai_clip_state(width=64, layers=2, embed_dim=512, seed=5),
                                    workdir / "ViT-B-32.pt")
    out = workdir / "momask"
    import_momask(root, out, clip_weights=clip, check_parity=False)
    return out


def timed(engine, request, repeats: int) -> tuple[float, np.ndarray]:
    """Median ms of `repeats` requests after two warm-ups (allocations, captures), and the motion."""
    for _ in range(2):
        motion = engine.generate(request)
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        motion = engine.generate(request)
        times.append((time.perf_counter() - started) * 1e3)
    return statistics.median(times), motion.joints


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").strip().splitlines()[0])
    parser.add_argument("--device", choices=("cuda", "cpu"), default="cuda")
    parser.add_argument("--sizes", choices=("release", "small"), default="release")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path, help="folder for gpu_service_check.md (benchmarks/gpu_suite.sh passes "
                                                 "one when it runs this as GPU_SCRIPT)")
    args = parser.parse_args(argv)
    from t2m.service.engine.engine import OnnxEngine
    from t2m.service.engine.execution import Execution
    from t2m.service.engine.types import GenerationRequest, SegmentRequest

    request = GenerationRequest([SegmentRequest("a person walks forward and turns around", 9.8)], seed=3)
    with tempfile.TemporaryDirectory(prefix="gpu-service-") as folder:
        started = time.perf_counter()
        bundle = build_import(Path(folder), args.sizes == "release")
        print(f"- MoMask import ({args.sizes} sizes, random weights) in {time.perf_counter() - started:.0f} s")
        rows, motions = [], {}
        for graphs in (False, True):
            engine = OnnxEngine.load(bundle, intra_op_threads=1,
                                     execution=Execution((args.device,), cuda_graphs=graphs))
            ms, motions[graphs] = timed(engine, request, args.repeats)
            rows.append(f"| {args.device} | {'on' if graphs else 'off'} | {ms:.1f} | "
                        f"{engine.limits.details['execution']['cuda_graphs']} |")
    difference = float(np.abs(motions[True] - motions[False]).max())
    lines = [f"| provider | T2M_CUDA_GRAPHS | ms per 9.8 s request (median of {args.repeats}) | captured graphs |",
             "| --- | --- | ---: | --- |", *rows, "",
             f"- largest joint difference between the two motions: {difference:.2e} m (same seed)"]
    print("\n" + "\n".join(lines))
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "gpu_service_check.md").write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
