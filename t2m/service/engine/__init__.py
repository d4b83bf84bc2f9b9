"""The inference engine: bundle loading, text encoding, the GPT sampling loop and the decoder, on onnxruntime.

Kept import-light: `from t2m.service.engine.types import ...` must not pull in onnxruntime.
"""
