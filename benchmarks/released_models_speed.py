"""Speed of the three released models (T2M-GPT, MoMask, MoGenTS) at their released sizes, in one run.

No released weights can be fetched here, so each release is written with random values in its exact file layout by
the test suite's writers (tests/export/*_release_files.py, t2m_gpt_release_keys.py), imported with the importers
`t2m import` runs (OpenAI's CLIP ViT-B/32 text tower at full size, random, in OpenAI's TorchScript format from
tests/model/openai_clip_format.py), quantised as `t2m import --quantize` / `t2m quantize` quantise them (--schemes:
each bundle's token graphs as int8, int4, fp16; parity is the slow tests' subject, not measured here), and every
bundle is timed by `t2m bench --bundle`'s code (t2m.export.bench.bundles: text / codes / decode per request, a 10 s
motion and a 3-sentence stream), one table per thread count. Speed depends on sizes, not values, so these are the
figures of the real releases on this machine; the figures are printed, never asserted.

    OMP_NUM_THREADS=1 PYTHONPATH=. .venv/bin/python benchmarks/released_models_speed.py [--repeats 3] [--threads 1 2]
        [--schemes float32,int8,int4] [--workdir DIR]   (keep the releases and bundles there; bundles already there
        are reused)
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import torch

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests" / "export"))   # the release writers are test helpers

from mogents_release_files import RELEASE as MOGENTS_RELEASE  # type: ignore[import-not-found]  # noqa: E402
from mogents_release_files import release_states as mogents_states  # noqa: E402
from mogents_release_files import write_release as write_mogents  # noqa: E402
from momask_release_files import RELEASE as MOMASK_RELEASE  # type: ignore[import-not-found]  # noqa: E402
from momask_release_files import release_states as momask_states  # noqa: E402
from momask_release_files import write_release as write_momask  # noqa: E402
from t2m_gpt_release_keys import release_gpt_state, release_vq_state, write_release_files  # type: ignore[import-not-found]  # noqa: E402

from t2m.export.bench.bundles import run_bundle_bench  # noqa: E402
from t2m.export.importers.mogents import import_mogents  # noqa: E402
from t2m.export.importers.momask import import_momask  # noqa: E402
from t2m.export.importers.t2m_gpt import import_t2m_gpt  # noqa: E402
from tests.model.openai_clip_format import VIT_B_32_TEXT, openai_clip_state, save_torchscript_archive  # noqa: E402


def write_clip(folder: Path) -> Path:
    """ViT-B/32's text tower at full size (and a one-block vision stub), OpenAI's keys, dtypes and archive format."""
    path = folder / "ViT-B-32.pt"
    if not path.is_file():
        folder.mkdir(parents=True, exist_ok=True)
        state = openai_clip_state(width=VIT_B_32_TEXT["width"], layers=VIT_B_32_TEXT["layers"],
                                  embed_dim=VIT_B_32_TEXT["embed_dim"], seed=6)
        save_torchscript_archive(state, path)
    return path


def import_t2m_gpt_release(folder: Path, clip: Path, out: Path) -> None:
    """net_last.pth + net_best_fid.pth (19.7M VQ, 228.4M GPT) and the meta mean/std, then the import."""
    files = write_release_files(folder, release_vq_state(seed=1), release_gpt_state(seed=2, std=0.02))
    import_t2m_gpt(files["net_last.pth"], files["net_best_fid.pth"], files["mean.npy"], files["std.npy"], out,
                   clip_weights=clip, check_parity=False)


def import_momask_release(folder: Path, clip: Path, out: Path) -> None:
    """checkpoints/t2m as MoMask's download script unpacks it (RVQ-VAE, masked and residual transformers, length
    estimator, meta mean/std), then the import."""
    root = folder / "checkpoints" / "t2m"
    write_momask(root, momask_states(MOMASK_RELEASE))
    import_momask(root, out, clip_weights=clip, check_parity=False)


def import_mogents_release(folder: Path, clip: Path, out: Path) -> None:
    """logs/humanml3d as pretrain_models.zip unpacks (fused VQ, both branches' transformers) and the length
    estimator under checkpoints/humanml3d, then the import."""
    files = write_mogents(folder, mogents_states(MOGENTS_RELEASE))
    import_mogents(files["logs"], out, clip_weights=clip, check_parity=False)


IMPORTS: dict[str, Callable[[Path, Path, Path], None]] = {
    "t2m-gpt": import_t2m_gpt_release, "momask": import_momask_release, "mogents": import_mogents_release}


def folder_mb(folder: Path) -> float:
    return sum(f.stat().st_size for f in folder.rglob("*") if f.is_file()) / 1e6


def build_bundles(workdir: Path, schemes: Sequence[str] = ("float32",)) -> dict[str, Path]:
    """One bundle per release and scheme in workdir/bundles (reused when already there), {row label: folder}; prints
    how long each import and quantisation took."""
    from t2m.export.writing.int8 import quantize_bundle

    clip = write_clip(workdir / "clip")
    bundles = {}
    for name, run_import in IMPORTS.items():
        out = workdir / "bundles" / name
        if not (out / "manifest.json").is_file():
            start = time.perf_counter()
            run_import(workdir / "releases" / name, clip, out)
            print(f"- {name}: written and imported in {time.perf_counter() - start:.0f} s, bundle "
                  f"{folder_mb(out):.0f} MB", flush=True)
        for scheme in schemes:
            copy = out if scheme == "float32" else workdir / "bundles" / f"{name}-{scheme}"
            if not (copy / "manifest.json").is_file():
                start = time.perf_counter()
                quantize_bundle(out, copy, scheme=scheme, parity=False)
                print(f"- {name} {scheme}: quantised in {time.perf_counter() - start:.0f} s, bundle "
                      f"{folder_mb(copy):.0f} MB", flush=True)
            bundles[f"{name} {scheme}"] = copy
    return bundles


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").strip().splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="requests timed per case and model (default 3)")
    parser.add_argument("--threads", type=int, nargs="+", default=[1],
                        help="onnxruntime intra-op threads, one table each (default 1)")
    parser.add_argument("--schemes", default="float32",
                        help="comma-separated: float32 (the import) and quantised copies int8, int4, fp16")
    parser.add_argument("--workdir", type=Path, default=None,
                        help="keep releases and bundles here (default: a temporary folder, removed at the end)")
    args = parser.parse_args(argv)
    schemes = [scheme.strip() for scheme in args.schemes.split(",") if scheme.strip()]
    if args.repeats < 1 or min(args.threads) < 1:
        parser.error("--repeats and --threads must be >= 1")
    if not schemes or set(schemes) - {"float32", "int8", "int4", "fp16"}:
        parser.error(f"--schemes: float32, int8, int4 or fp16, got {args.schemes!r}")
    torch.set_num_threads(max(args.threads))
    with tempfile.TemporaryDirectory(prefix="released-speed-") as temporary:
        workdir = args.workdir or Path(temporary)
        bundles = build_bundles(workdir, schemes)
        for threads in args.threads:
            print()
            run_bundle_bench(list(bundles.values()), repeats=args.repeats, threads=threads, names=list(bundles))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
