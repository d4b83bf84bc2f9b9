"""Print the requirements an image installs: pyproject.toml's runtime dependencies plus those of the extras named
(comma-separated, e.g. "gpu"), plus the build backend with --build-system; used by the Dockerfile and by
scripts/build_wheelhouse.sh so that both install the same set.

Why a script: onnxruntime and onnxruntime-gpu install the same `onnxruntime` module, so with the `gpu` extra the CPU
wheel of the base dependencies must be left out, or whichever pip installs last would overwrite the other's files.
Usage: python scripts/image_requirements.py PYPROJECT [EXTRAS] [--build-system]   (Python 3.11+: tomllib)
"""
from __future__ import annotations

import re
import sys

import tomllib  # type: ignore[import-not-found,unused-ignore]  # 3.11+: the image's Python


def requirements(pyproject: dict, extras: list[str], build_system: bool = False) -> list[str]:
    project = pyproject["project"]
    wanted = [*project["dependencies"], *(req for extra in extras for req in project["optional-dependencies"][extra])]
    if any(re.match(r"onnxruntime-gpu\b", req) for req in wanted):
        wanted = [req for req in wanted if not re.match(r"onnxruntime(?![-\w])", req)]
    return wanted + (pyproject["build-system"]["requires"] if build_system else [])


def main(argv: list[str]) -> int:
    args = [arg for arg in argv if arg != "--build-system"]
    with open(args[0], "rb") as file:
        pyproject = tomllib.load(file)
    extras = [extra.strip() for extra in (args[1] if len(args) > 1 else "").split(",") if extra.strip()]
    print("\n".join(requirements(pyproject, extras, "--build-system" in argv)))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
