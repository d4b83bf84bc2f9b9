"""The masked family (MoMask / MoGenTS): token maps filled by confidence re-masking and residual passes.

Served, torch-free (the service imports these; the import-direction test holds them to it):
- family.py: the declaration (manifest block, graphs, capabilities, hooks) registered as FAMILY;
- loop.py: the masking / re-masking loop, inpainting included, over step objects;
- served.py: the engine's object for a loaded bundle (length.onnx draws, body-part edits).
Offline (torch; never imported by the service):
- masked_transformer.py, residual_transformer.py, length_estimator.py, masking.py: the PyTorch networks;
- train_masked.py, train_residual.py, train_length.py, sampling.py, evaluation.py: training, reference, `t2m eval`;
- export_graphs.py, export.py, random_bundle.py: its ONNX graphs, `t2m export --family masked`, random bundles;
- import_momask.py, momask_files.py, momask_card.py, import_mogents.py, mogents_files.py, mogents_card.py: the
  `t2m import momask` / `mogents` readers of the released checkpoints, and their model cards.
"""
from t2m.families.masked.family import FAMILY

__all__ = ["FAMILY"]
