"""OpenAI CLIP's text tower at ViT-B/32's text size (random weights in OpenAI's file format: no real weights here):
loading, ONNX export, onnxruntime vs PyTorch, and the text graph's latency padded to 77 vs to the batch's longest.

    t2m bench clip-text        (from the repository root; prints the figures)
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from t2m.export.graphs.export import ort_session
from t2m.export.graphs.text import tokenize
from t2m.export.kit.text_sources import encoder_text_source
from t2m.model.networks.text_encoders import ClipEncoder
from t2m.testing.clip_release import VIT_B_32_TEXT, openai_clip_state, save_torchscript_archive

TEXTS = ["a person walks forward", "someone waves with the left hand while jumping", "a man runs " * 30,
         "the person\u2019s arms swing", "ΟΔΥΣΣΕΥΣ bows", "rock &amp; roll", "a", "walk backwards then turn left"]


def mean_ms(run, repeats: int) -> float:
    run()
    start = time.perf_counter()
    for _ in range(repeats):
        run()
    return (time.perf_counter() - start) / repeats * 1000


def main(argv: list[str] | None = None) -> int:
    argparse.ArgumentParser(description=(__doc__ or "").strip().splitlines()[0]).parse_args(argv)
    torch.set_num_threads(1)
    folder = Path(tempfile.mkdtemp())
    state = openai_clip_state(width=VIT_B_32_TEXT["width"], layers=VIT_B_32_TEXT["layers"],
                              embed_dim=VIT_B_32_TEXT["embed_dim"], seed=6)
    archive = save_torchscript_archive(state, folder / "ViT-B-32.pt")
    print(f"archive: {archive.stat().st_size / 1e6:.1f} MB (text tower + a one-block vision stub, OpenAI's dtypes)")
    start = time.perf_counter()
    encoder = ClipEncoder(archive)
    print(f"ClipEncoder (archive + tokenizer): {time.perf_counter() - start:.2f} s")
    start = time.perf_counter()
    encoder_text_source(encoder).write(folder)
    graph = folder / "text_encoder.onnx"
    print(f"text graph export: {time.perf_counter() - start:.2f} s, {graph.stat().st_size / 1e6:.1f} MB")
    session = ort_session(graph)

    ids, mask = tokenize(folder / "tokenizer.json", TEXTS)  # the long one makes this batch 77 wide
    (features,) = session.run(None, {"input_ids": ids.numpy(), "attention_mask": mask.numpy()})
    print(f"onnxruntime vs PyTorch, {len(TEXTS)} sentences x {ids.shape[1]} tokens: max |diff| "
          f"{np.abs(features - encoder.encode(TEXTS)).max():.2e} (largest feature {np.abs(features).max():.2f})")

    short = [t for t in TEXTS if len(t) < 60]
    ids, mask = tokenize(folder / "tokenizer.json", short)
    wide = {"input_ids": np.pad(ids.numpy(), ((0, 0), (0, 77 - ids.shape[1]))),
            "attention_mask": np.pad(mask.numpy(), ((0, 0), (0, 77 - ids.shape[1])))}
    tight = {"input_ids": ids.numpy(), "attention_mask": mask.numpy()}
    (at_77,), (at_longest,) = session.run(None, wide), session.run(None, tight)
    print(f"{len(short)} short sentences, onnxruntime 1 thread: padded to 77 "
          f"{mean_ms(lambda: session.run(None, wide), 20):.1f} ms, to their longest ({ids.shape[1]}) "
          f"{mean_ms(lambda: session.run(None, tight), 20):.1f} ms; max |diff| {np.abs(at_77 - at_longest).max():.2e}")
    with torch.no_grad():
        eager = mean_ms(lambda: encoder.module(torch.from_numpy(wide["input_ids"]), None), 5)
    print(f"PyTorch eager, padded to 77, 1 thread: {eager:.1f} ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
