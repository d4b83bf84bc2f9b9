"""T2M-HiFiGPT: a double-tier GPT over a residual VQ's [steps, R] code maps (the default model).

Served, torch-free (the service imports these; the import-direction test holds them to it):
- family.py: the declaration (manifest block, graphs, capabilities, hooks) registered as FAMILY;
- loop.py: the temporal + residual decoding loop over step objects;
- served.py: the engine's object for a loaded bundle.
Offline (torch; never imported by the service):
- network.py: the PyTorch double-tier GPT;
- training.py, sampling.py, evaluation.py: `t2m train hifigpt`, the reference sampler, `t2m eval --hifigpt`;
- export_graphs.py, export.py, random_bundle.py: its ONNX graphs, `t2m export --family hifigpt`, random bundles.
"""
from t2m.families.hifigpt.family import FAMILY

__all__ = ["FAMILY"]
