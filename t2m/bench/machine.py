"""Where a benchmark ran, written once for all of them (torch-free, so the service-side benchmarks can use it): the
CPU model and cores, the load average when it started, the library versions."""
from __future__ import annotations

import os
import platform
from pathlib import Path


def cpu_model() -> str:
    """The CPU's model name (/proc/cpuinfo on Linux), else what `platform` knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine_facts() -> dict[str, str]:
    """The facts as a record (a benchmark's JSON, or a before/after pair of them around a run)."""
    import numpy
    import onnxruntime

    load = " ".join(f"{x:.2f}" for x in os.getloadavg()) if hasattr(os, "getloadavg") else "unknown"
    return {"cpu": f"{cpu_model()} ({os.cpu_count()} cores visible)", "load_average": load,
            "python": platform.python_version(), "onnxruntime": onnxruntime.__version__, "numpy": numpy.__version__}


def describe_machine(threads: int, extra: str = "") -> list[str]:
    """The facts as markdown lines; ``extra`` adds e.g. torch's version."""
    import onnxruntime

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return [
        f"- CPU: {cpu_model()}; {os.cpu_count()} logical cores; load average {load:.1f} when the run started",
        f"- onnxruntime {onnxruntime.__version__} (intra-op threads {threads})" + (f"; {extra}" if extra else "")
        + f"; Python {platform.python_version()}",
    ]
