"""The lines every benchmark prints about where it ran (torch-free, so the service-side benchmarks can use it)."""
from __future__ import annotations

import os
import platform
from pathlib import Path


def describe_machine(threads: int, extra: str = "") -> list[str]:
    """CPU model, cores, load average at the start, library versions; ``extra`` adds e.g. torch's version."""
    import onnxruntime

    cpu = platform.processor() or "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return [
        f"- CPU: {cpu}; {os.cpu_count()} logical cores; load average {load:.1f} when the run started",
        f"- onnxruntime {onnxruntime.__version__} (intra-op threads {threads})" + (f"; {extra}" if extra else "")
        + f"; Python {platform.python_version()}",
    ]
