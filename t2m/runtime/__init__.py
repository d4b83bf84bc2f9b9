"""The runtime: everything that turns a request into a motion, with no HTTP in it (no FastAPI, no starlette).

The engine (bundle loading, text encoding, the families' served objects, one decode), the batcher and its
scheduling, streaming, the answer formats, handles and recipes, and the edit flow. The HTTP service
(t2m.service), the CLI, the exporters and the benchmarks all use it the same way.

Kept import-light: `from t2m.runtime.types import ...` must not pull in onnxruntime.
"""
