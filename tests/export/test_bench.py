"""`t2m bench` output shape on tiny models: a markdown table, the machine lines, and the speedup as the last line.
(Figures are printed by the benchmark, never asserted.)"""
from __future__ import annotations

import re

from t2m.bench.models import BenchCase, run_bench
from t2m.families.gpt.network import GPTConfig
from t2m.model.networks.vqvae import VQConfig


def test_bench_prints_a_table_and_ends_with_the_speedup_line():
    lines: list[str] = []
    tiny = BenchCase("tiny", GPTConfig(codebook_size=16, embed=16, n_head=2, n_layer_base=1, n_layer_head=1,
                                       text_dim=8, dropout=0.0),
                     VQConfig(width=16, code_dim=8, nb_code=16, depth=1), tokens=4, repeats=1)
    speedup = run_bench(threads=1, cases=[tiny], echo=lines.append)
    text = "\n".join(lines)
    assert "CPU:" in text and "onnxruntime" in text and "threads 1" in text
    methods = [line for line in lines if line.startswith("| tiny | 4 |")]
    assert len(methods) == 3 and "onnxruntime + KV cache" in methods[0] and "recomputed" in methods[2]
    assert re.fullmatch(r"speedup_vs_eager_recompute=\d+\.\dx", lines[-1])
    assert lines[-1] == f"speedup_vs_eager_recompute={speedup:.1f}x"
