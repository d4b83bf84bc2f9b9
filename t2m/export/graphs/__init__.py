"""The ONNX graphs, one builder a module (decoder, GPT step, T2M-HiFiGPT steps, masked and residual transformers,
text encoders), over one export function (export.py)."""
