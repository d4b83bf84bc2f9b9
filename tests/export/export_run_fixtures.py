"""Tiny training runs laid out as model/ writes them (t2m.model.training.checkpoint.save_checkpoint), for the export
tests."""
from __future__ import annotations


def make_runs(root, cond_drop: float = 0.1, length_conditioning: bool = True, text_dim: int = 384):
    """A tiny VQ run and GPT run laid out as model/ training writes them, plus a dataset summary.json."""
    import json

    import numpy as np
    import torch

    from t2m.families.gpt.network import GPTConfig, MotionGPT
    from t2m.model.networks.vqvae import MotionVQVAE, VQConfig
    from t2m.model.training.checkpoint import save_checkpoint

    torch.manual_seed(0)
    data_dir = root / "data"
    data_dir.mkdir(parents=True)
    summary = {"name": "bandai-namco-smpl22", "license": "CC BY-NC 4.0",
               "attribution": "Kobayashi et al., Bandai Namco", "captions": "templated from labels"}
    (data_dir / "summary.json").write_text(json.dumps(summary))
    rng = np.random.default_rng(0)
    vq_run, gpt_run = root / "vq", root / "gpt"
    vq = MotionVQVAE(VQConfig(width=32, code_dim=16, nb_code=32, depth=1))
    save_checkpoint(vq_run, vq, step=10, data={"data_dir": str(data_dir)})
    np.save(vq_run / "mean.npy", rng.normal(size=263).astype(np.float32))
    np.save(vq_run / "std.npy", rng.uniform(0.5, 1.5, size=263).astype(np.float32))
    gpt = MotionGPT(GPTConfig(codebook_size=32, embed=32, n_head=2, n_layer_base=1, n_layer_head=1, text_dim=text_dim,
                              length_conditioning=length_conditioning))
    text = {"kind": "minilm", "dim": text_dim, "max_length": 64, "pooling": "mean", "normalize": True,
            "null_condition": "zeros"}
    save_checkpoint(gpt_run, gpt, step=20, data={"data_dir": str(data_dir), "vq_run": str(vq_run.resolve()),
                                                 "text_encoder": text, "training": {"cond_drop": cond_drop}})
    return vq_run, gpt_run, data_dir
