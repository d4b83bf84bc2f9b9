"""PyTorch -> bundle, laid out by job: `graphs/` builds each ONNX graph, `families/` holds each family's exporter (and
its tiny random bundle for tests), `importers/` the released checkpoints' importers, `kit/` what they share (text
sources, training-run records, parity and int8 checks), `writing/` bundle writing, verifying, requantising and the
caption index, `bench/` the benchmarks, `evaluation.py` `t2m eval --bundle`'s adapter."""
