#!/usr/bin/env bash
# Fills a wheelhouse with every wheel the image needs (the runtime dependencies of pyproject.toml and the build
# backend), downloaded with this machine's pip configuration (its index, mirror, proxy and CA certificate), so that
# `docker build --build-arg WHEELHOUSE=1` installs with --no-index: for builds behind TLS-intercepting proxies and in
# air-gapped networks, where pip inside the build cannot reach (or cannot verify) a package index.
# Usage: scripts/build_wheelhouse.sh [DIR]   (default deploy/wheelhouse, the directory the Dockerfile copies)
# The wheels are for the image's Python (T2M_IMAGE_PYTHON, default 3.11: python:3.11-slim and Debian bookworm) on
# x86_64 glibc Linux (T2M_IMAGE_PLATFORMS), whatever Python runs this script. The GPU image (a CUDA runtime base, Ubuntu
# 24.04's Python): T2M_IMAGE_PYTHON=3.12 T2M_EXTRAS=gpu scripts/build_wheelhouse.sh (onnxruntime-gpu: ~255 MB).
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
dest="${1:-$repo/deploy/wheelhouse}"
python="${PYTHON:-python3}"
version="${T2M_IMAGE_PYTHON:-3.11}"
platforms="${T2M_IMAGE_PLATFORMS:-manylinux_2_28_x86_64 manylinux_2_17_x86_64 manylinux2014_x86_64 linux_x86_64}"
mkdir -p "$dest"
# up to date: the same dependencies (pyproject.toml) and target were downloaded before
stamp="$dest/.stamp"
wanted="$(sha256sum < "$repo/pyproject.toml" | cut -d' ' -f1) $version $platforms ${T2M_EXTRAS:-}"
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$wanted" ] && compgen -G "$dest/*.whl" > /dev/null; then
  echo "$dest is up to date ($(find "$dest" -name '*.whl' | wc -l) wheels)"; exit 0
fi
requirements="$(mktemp)"
trap 'rm -f "$requirements"' EXIT
# T2M_EXTRAS: the extras the image installs (the Dockerfile's EXTRAS; gpu: onnxruntime-gpu instead of onnxruntime)
"$python" "$repo/scripts/image_requirements.py" "$repo/pyproject.toml" "${T2M_EXTRAS:-}" --build-system > "$requirements"
platform_args=()
for platform in $platforms; do platform_args+=(--platform "$platform"); done
abi="cp${version/./}"
"$python" -m pip download --quiet --dest "$dest" --only-binary=:all: --python-version "$version" \
  --implementation cp --abi "$abi" --abi abi3 --abi none "${platform_args[@]}" --platform any -r "$requirements"
echo "$wanted" > "$stamp"
echo "$(find "$dest" -name '*.whl' | wc -l) wheels ($(du -sh "$dest" | cut -f1)) in $dest"
