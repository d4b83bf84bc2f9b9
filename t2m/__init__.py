"""t2m-service: sentence streams in, continuous 3D human motion out.

One version number for the package, the HTTP API (OpenAPI `info.version`, `/health`) and `t2m --version`.
"""
from __future__ import annotations

__version__ = "0.4.0"
DISTRIBUTION = "t2m-service"   # the installed distribution's name, as `t2m --version` prints it
