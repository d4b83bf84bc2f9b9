"""Decoding loops, torch-free: one recipe per model family, shared by the service and the PyTorch reference.

The service runs a loop over onnxruntime graphs; training, evaluation and parity checks run the same loop over
PyTorch modules. Each loop takes a small "step" object (the family's network call), so the recipe (guidance,
temperature, top-k, the length rule, the order of random draws) is written once.
"""
from __future__ import annotations
