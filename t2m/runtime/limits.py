"""The limits of a request that do not depend on the model, in one place: the API's schemas declare them on their
fields (so OpenAPI shows them), and the runtime's handles, recipes, edits and uploads check what they read against
the same numbers. Limits that depend on the model (max_tokens, the codebook) live in t2m.runtime.types.ModelLimits."""
from __future__ import annotations

MAX_SEGMENTS = 32
MAX_TEXT_CHARS = 300
MIN_DURATION_S = 0.5
MAX_DURATION_S = 10.0
MAX_TOTAL_S = 120.0
MAX_GUIDANCE = 10.0
MAX_TEMPERATURE = 5.0
MAX_MODEL_NAME_CHARS = 200
MAX_SEED = 2**53 - 1   # the largest integer every JSON reader (JavaScript included) holds exactly
MAX_UPLOAD_FPS = 120.0
MAX_UPLOAD_FRAMES = int(MAX_TOTAL_S * MAX_UPLOAD_FPS) + 1   # a schema bound; the service checks frames / fps too
MAX_BVH_CHARS = 16_000_000
MAX_HANDLE_CHARS = 2_000_000      # a handle string; the decompressed body is bounded per model (handles._max_body)
