"""T2M-GPT: one code per step from gpt_step.onnx (KV cache, End token), decoded by a 1D VQ decoder.

Served, torch-free (the service imports these; the import-direction test holds them to it):
- family.py: the declaration (manifest block, graphs, capabilities, hooks) registered as FAMILY;
- loop.py: the decoding loop over a step object (onnxruntime in the service, PyTorch in the reference);
- served.py: the engine's object for a loaded bundle (requests -> jobs -> codes).
Offline (torch; never imported by the service):
- network.py, fixed_cache.py: the PyTorch GPT and its fixed-cache step for CUDA graphs;
- training.py, sampling.py, evaluation.py: `t2m train gpt`, the reference sampler, `t2m eval --gpt`;
- export_graphs.py, export.py, random_bundle.py: its ONNX graphs, `t2m export --family gpt`, tiny random bundles;
- import_t2m_gpt.py: `t2m import t2m-gpt` (the released checkpoints).
"""
from t2m.families.gpt.family import FAMILY

__all__ = ["FAMILY"]
