"""The PyTorch reference samplers: each family's modules as the steps of its numpy decoding loop (t2m.decoding),
so that the service (over onnxruntime) and the reference (over PyTorch) run one recipe and parity tests compare
them for a fixed seed."""
