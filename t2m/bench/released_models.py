"""Speed of the released models (T2M-GPT, MoMask, MoGenTS; MDM 1000-step and 50-step, DiP) at their released sizes.

No released weights can be fetched here, so each release is written with random values in its exact file layout by
each family's writer (t2m/families/*/*_release.py, shared with the tests), imported with the importers
`t2m import` runs (OpenAI's CLIP ViT-B/32 text tower at full size, random, in OpenAI's TorchScript format from
t2m/testing/clip_release.py), quantised as `t2m import --quantize` / `t2m quantize` quantise them (--schemes:
each bundle's token graphs as int8, int4, fp16; parity is the slow tests' subject, not measured here), and every
bundle is timed by `t2m bench --bundle`'s code (t2m.bench.bundles: text / codes / decode per request, a 10 s
motion and a 3-sentence stream), one table per thread count. Speed depends on sizes, not values, so these are the
figures of the real releases on this machine; the figures are printed, never asserted.

The diffusion family (MDM's paper model with 1000 steps, MDM-50, DiP; t2m/families/diffusion/mdm_release.py, DistilBERT
at distilbert-base-uncased's sizes with the bert-base-uncased vocabulary MiniLM ships, HumanML3D's Mean/Std of the
test fixtures) gets a table of its own beside them, on 1 and 2 threads (--diffusion-threads): ms per denoiser call
(guidance's 2 rows batched; MDM at 196 frames, DiP at 20 + 40), a DiP call (2 s of motion: 10 steps), a DiP 10 s
sentence, a 9.8 s MDM-50 motion (196 frames, its longest; the 1000-step model's is 1000 calls, estimated from the
call), with the authors' published GPU figures beside them; then the same with denoiser.onnx quantised to int8
(onnxruntime's dynamic quantisation, t2m.export.writing.quantize) and its parity: max |x0 diff| on one call and the
max |diff| of a whole seeded run with injected noise, float32 vs int8.

    OMP_NUM_THREADS=1 t2m bench released [--repeats 3] [--threads 1 2]
        [--schemes float32,int8,int4] [--workdir DIR]   (keep the releases and bundles there; bundles already there
        are reused) [--models mdm-1000,mdm-50,dip]   (a subset; default all six; --schemes applies to the three
        token-model releases) [--json-out FILE]   (the token models' figures)
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict
from pathlib import Path

import torch

from t2m.bench.bundles import run_bundle_bench
from t2m.families.diffusion.distilbert_release import RELEASE as BERT_RELEASE
from t2m.families.diffusion.distilbert_release import write_distilbert_folder
from t2m.families.diffusion.importer import import_dip, import_mdm
from t2m.families.diffusion.mdm_release import RELEASE_SIZES as MDM_RELEASE
from t2m.families.diffusion.mdm_release import make_release as write_mdm
from t2m.families.diffusion.mdm_release import write_statistics
from t2m.families.gpt.import_t2m_gpt import import_t2m_gpt
from t2m.families.gpt.t2m_gpt_release import release_gpt_state, release_vq_state, write_release_files
from t2m.families.masked.import_mogents import import_mogents
from t2m.families.masked.import_momask import import_momask
from t2m.families.masked.mogents_release import RELEASE as MOGENTS_RELEASE
from t2m.families.masked.mogents_release import release_states as mogents_states
from t2m.families.masked.mogents_release import write_release as write_mogents
from t2m.families.masked.momask_release import RELEASE as MOMASK_RELEASE
from t2m.families.masked.momask_release import release_states as momask_states
from t2m.families.masked.momask_release import write_release as write_momask
from t2m.testing.clip_release import VIT_B_32_TEXT, openai_clip_state, save_torchscript_archive


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


def write_bert(folder: Path) -> Path:
    """distilbert-base-uncased at its sizes (66.4M parameters + the MLM head, random) in the hub's layout, with
    the bert-base-uncased vocabulary MiniLM ships (30,522 word pieces)."""
    from t2m.model.networks.text_encoders import minilm_model_dir

    path = folder / "distilbert-base-uncased"
    if not (path / "config.json").is_file():
        vocab = (minilm_model_dir() / "vocab.txt").read_text(encoding="utf-8").splitlines()
        write_distilbert_folder(path, dict(BERT_RELEASE), vocab)
    return path


def import_mdm_release(release: str) -> Callable[[Path, Path, Path], None]:
    """MDM's save/<name> folder (args.json + model000200000.pt, 17.9M parameters) at the released sizes, then the
    import with HumanML3D's Mean/Std."""
    def run(folder: Path, clip: Path, out: Path) -> None:
        write_mdm(folder, release, MDM_RELEASE)
        import_mdm(folder, out, clip_file=clip, humanml3d=write_statistics(folder.parent / "humanml3d"),
        check_parity=False)

    return run


def import_dip_release(folder: Path, clip: Path, out: Path) -> None:
    """DiP's folder (args.json + {'model', 'model_avg'}, 26.4M parameters) and a DistilBERT folder, then the import."""
    write_mdm(folder, "dip", MDM_RELEASE)
    import_dip(folder, out, bert_dir=write_bert(folder.parents[1] / "bert"),
    humanml3d=write_statistics(folder.parents[1] / "humanml3d"),
               check_parity=False)


IMPORTS: dict[str, Callable[[Path, Path, Path], None]] = {
    "t2m-gpt": import_t2m_gpt_release, "momask": import_momask_release, "mogents": import_mogents_release,
    "mdm-1000": import_mdm_release("paper"), "mdm-50": import_mdm_release("fifty"), "dip": import_dip_release}
DIFFUSION = ("mdm-1000", "mdm-50", "dip")


def folder_mb(folder: Path) -> float:
    return sum(f.stat().st_size for f in folder.rglob("*") if f.is_file()) / 1e6


def build_bundles(workdir: Path, models: Sequence[str], schemes: Sequence[str] = ("float32",)) -> dict[str, Path]:
    """One bundle per release (and, for the token models, per scheme) in workdir/bundles (reused when already there),
    {row label: folder}; prints how long each import and quantisation took."""
    from t2m.export.writing.int8 import quantize_bundle

    clip = write_clip(workdir / "clip")
    bundles = {}
    for name in models:
        run_import = IMPORTS[name]
        out = workdir / "bundles" / name
        if not (out / "manifest.json").is_file():
            start = time.perf_counter()
            run_import(workdir / "releases" / name, clip, out)
            print(f"- {name}: written and imported in {time.perf_counter() - start:.0f} s, bundle "
                  f"{folder_mb(out):.0f} MB", flush=True)
        for scheme in schemes if name not in DIFFUSION else ("float32",):
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
    parser.add_argument("--models", default=",".join(IMPORTS),
                        help=f"comma-separated subset of {','.join(IMPORTS)} (default all)")
    parser.add_argument("--diffusion-threads", default="1,2",
                        help="the diffusion table's onnxruntime threads, comma-separated (default 1,2)")
    parser.add_argument("--json-out", type=Path, default=None,
                        help="also write the token models' figures here: {threads: {model: {request: ms per stage}}}")
    args = parser.parse_args(argv)
    models = [name for name in args.models.split(",") if name]
    unknown = sorted(set(models) - set(IMPORTS))
    if unknown:
        parser.error(f"--models: unknown {', '.join(unknown)} (known: {', '.join(IMPORTS)})")
    schemes = [scheme.strip() for scheme in args.schemes.split(",") if scheme.strip()]
    if args.repeats < 1 or min(args.threads) < 1:
        parser.error("--repeats and --threads must be >= 1")
    if not schemes or set(schemes) - {"float32", "int8", "int4", "fp16"}:
        parser.error(f"--schemes: float32, int8, int4 or fp16, got {args.schemes!r}")
    if args.json_out is not None and not args.json_out.parent.is_dir():
        parser.error(f"--json-out: no folder {args.json_out.parent}")
    torch.set_num_threads(max(args.threads))
    with tempfile.TemporaryDirectory(prefix="released-speed-") as temporary:
        workdir = args.workdir or Path(temporary)
        bundles = build_bundles(workdir, models, schemes)
        tokens = {label: bundle for label, bundle in bundles.items() if label.split(" ")[0] not in DIFFUSION}
        figures: dict[str, dict[str, dict[str, dict[str, float]]]] = {}
        for threads in args.threads if tokens else ():
            print()
            results = run_bundle_bench(list(tokens.values()), repeats=args.repeats, threads=threads,
                                       names=list(tokens))
            figures[str(threads)] = {model: {request: {**asdict(times), "total": times.total}
                                             for request, times in cases.items()}
                                     for model, cases in results.items()}
        if args.json_out:
            args.json_out.write_text(json.dumps(figures, indent=2))
        diffusion = {label.split(" ")[0]: bundle for label, bundle in bundles.items()
                     if label.split(" ")[0] in DIFFUSION}
        if diffusion:
            from t2m.families.diffusion.bench import run_diffusion_speed

            print()
            run_diffusion_speed(diffusion, workdir / "int8", [int(n) for n in args.diffusion_threads.split(",")],
                                repeats=args.repeats)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
