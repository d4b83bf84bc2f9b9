"""The denoiser interface fits an ONNX graph: the modules export (the project's exporter) with dynamic batch, frame
and text-token axes and per-row steps, and the graph run through onnxruntime as the numpy loop's Denoiser matches
the module. (The family's real graphs and their export are another step; this guards the module design: torch's
own nn.Transformer* layers would fix the sequence length at export.)"""
from __future__ import annotations

import numpy as np
import onnxruntime as ort
import pytest
import torch

from t2m.export.graphs.export import export_graph
from t2m.families.diffusion.loop import DiffusionJob, cosine_schedule, noise_from, sample
from t2m.families.diffusion.network import MDM, DiffusionConfig
from t2m.families.diffusion.sampling import TorchDenoiser

torch.set_num_threads(1)

F, DT = 7, 5
NAMES = ["x_t", "t", "text", "text_mask", "length", "prefix"]


class DipGraph(torch.nn.Module):
    def __init__(self, model: MDM) -> None:
        super().__init__()
        self.model = model

    def forward(self, x_t, t, text, text_mask, length, prefix):
        return self.model(x_t, t, text, text_mask, length, prefix)


class OrtDenoiser:
    """An onnxruntime session as the loop's Denoiser (inputs named as the Denoiser's arguments)."""

    def __init__(self, path) -> None:
        self.session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
        self.names = {node.name for node in self.session.get_inputs()}

    def __call__(self, x_t, t, text, text_mask, length, prefix):
        feed = {"x_t": x_t, "t": t, "text": text, "text_mask": text_mask, "length": length, "prefix": prefix}
        return self.session.run(None, {k: v for k, v in feed.items() if k in self.names})[0]


@pytest.fixture(scope="module")
def dip_graph(tmp_path_factory):
    torch.manual_seed(0)
    model = MDM(DiffusionConfig(arch="trans_dec", text_tokens=True, mask_frames=True, context_len=4, pred_len=8,
                                features=F, latent_dim=16, layers=2, heads=2, ff_size=32, text_dim=DT,
                                diffusion_steps=10, pos_embed_max_len=64)).eval()
    args = (torch.randn(2, 8, F), torch.tensor([3, 3]), torch.randn(2, 3, DT), torch.ones(2, 3, dtype=torch.bool),
            torch.tensor([8, 8]), torch.randn(2, 4, F))
    axes = {"x_t": {0: "batch", 1: "frames"}, "t": {0: "batch"}, "text": {0: "batch", 1: "tokens"},
            "text_mask": {0: "batch", 1: "tokens"}, "length": {0: "batch"}, "prefix": {0: "batch"},
            "x0": {0: "batch", 1: "frames"}}
    path = export_graph(DipGraph(model), args, tmp_path_factory.mktemp("dip") / "denoiser.onnx", NAMES, ["x0"], axes)
    return model, OrtDenoiser(path)


def test_graph_matches_the_module_at_other_sizes(dip_graph):
    model, graph = dip_graph
    rng = np.random.default_rng(0)
    x, t = rng.standard_normal((3, 11, F)).astype(np.float32), np.array([9, 0, 5])
    text = rng.standard_normal((3, 5, DT)).astype(np.float32)
    mask = np.array([[1, 1, 1, 0, 0], [1, 1, 1, 1, 1], [1, 0, 0, 0, 0]], bool)
    length, prefix = np.array([11, 6, 9]), rng.standard_normal((3, 4, F)).astype(np.float32)
    ours, theirs = graph(x, t, text, mask, length, prefix), TorchDenoiser(model)(x, t, text, mask, length, prefix)
    valid = np.arange(11)[None, :, None] < length[:, None, None]
    assert ours.shape == (3, 11, F) and np.abs((ours - theirs) * valid).max() < 1e-5


def test_the_loop_runs_over_the_graph(dip_graph):
    model, graph = dip_graph
    rng = np.random.default_rng(1)
    prefix = rng.standard_normal((4, F)).astype(np.float32)
    noise = [rng.standard_normal((8, F)).astype(np.float32) for _ in range(11)]

    def job() -> DiffusionJob:
        return DiffusionJob(text=np.ones((2, DT), np.float32), frames=8, rng=np.random.default_rng(2),
                            guidance=7.5, text_mask=np.ones(2, bool), prefix=prefix, noise=noise_from(noise))

    (through_graph,) = sample(graph, cosine_schedule(10), [job()], F)
    (through_module,) = sample(TorchDenoiser(model), cosine_schedule(10), [job()], F)
    assert np.abs(through_graph - through_module).max() < 1e-4
