"""HTTP routes: generate (POST /generate), health (GET /health), metrics (GET /metrics)."""
