"""The diffusion family (MDM, DiP): an x0-predicting transformer sampled by DDPM, making feature frames itself.

Served, torch-free (the service imports these; the import-direction test holds them to it):
- family.py: the declaration (manifest block, graphs, capabilities, hooks) registered as FAMILY;
- loop.py: the sampler, the joins and the inpainting over a denoiser object;
- served.py: the engine's object for a loaded bundle;
- edits.py: POST /edit on a recipe handle (replayed, then inpainted on its frames).
Offline (torch; never imported by the service):
- network.py, text_encoders.py, distilbert.py: the PyTorch denoiser and MDM's / DiP's text encoders;
- train_dip.py, sampling.py, evaluation.py, bench.py: training, the reference sampler, `t2m eval`, `t2m bench`;
- export_graphs.py, export.py, random_bundle.py: its ONNX graphs, the exporter, random bundles;
- importer.py, import_mdm.py, mdm_files.py, import_dip.py, import_card.py: `t2m import mdm` / `dip`.
"""
from t2m.families.diffusion.family import FAMILY

__all__ = ["FAMILY"]
