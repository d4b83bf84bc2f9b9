#!/usr/bin/env bash
# Getting onnxruntime-gpu onto a lent device machine, where one call of the device tool carries at most
# 64 MiB (the working tree included) and the machine stays warm only 30 s between calls: the 255 MB wheel travels as
# parts over several back-to-back calls and is put together there. Plan (docs/gpu.md has the whole sequence):
#
#   here:    tools/gpu/transport.sh prepare WHEEL    # .gpu/ort-slim.tar.xz (the wheel without its CUDA
#                                                         # provider, ~18 MB) + .gpu/cuda.xz.part-* (the provider,
#                                                         # 284 MB, sm_90 code only -> 52 MB xz, parts of PART_MB)
#            tools/gpu/transport.sh slim             # the bundles (70 MB) leave git's index (not the disk), so
#                                                         # the travelling tree is ~9 MB; `restore` puts them back
#   device:  one call per part, carrying it, each `tools/gpu/transport.sh keep DIR` (copies .gpu/* to DIR);
#            then `tools/gpu/transport.sh unpack DIR SITE` and tools/gpu/run_suite.sh with SITE=SITE
#   here:    tools/gpu/transport.sh restore
set -euo pipefail
repo="$(cd "$(dirname "$0")/../.." && pwd)"
cd "$repo"
stage=".gpu"
provider="onnxruntime/capi/libonnxruntime_providers_cuda.so"
bundles=(t2m/bundles/default t2m/bundles/gpt t2m/bundles/masked t2m/bundles/both)

exclude() {   # add (or with "-d" remove) one line of .git/info/exclude: ignored paths do not travel unless carried
  local file; file="$(git rev-parse --git-path info/exclude)"; mkdir -p "$(dirname "$file")"; touch "$file"
  if [ "$1" = "-d" ]; then grep -vxF "$2" "$file" >"$file.tmp" || true; mv "$file.tmp" "$file"
  else grep -qxF "$1" "$file" || echo "$1" >>"$file"; fi
}

case "${1:-}" in
  prepare)
    wheel="${2:?usage: gpu_transport.sh prepare ONNXRUNTIME_GPU_WHEEL}"
    [ -f "$wheel" ] || { echo "gpu_transport: no wheel at $wheel" >&2; exit 2; }
    work="$(mktemp -d)"; trap 'rm -rf "$work"' EXIT
    python3 -m zipfile -e "$wheel" "$work/site"
    [ -f "$work/site/$provider" ] || { echo "gpu_transport: $wheel holds no $provider" >&2; exit 2; }
    rm -rf "$stage"; mkdir -p "$stage"; exclude "/$stage/"
    # only the lent GPUs' machine code (sm_90: H100/H200) is kept, the other architectures' bytes are zeroed:
    # 185 MB of xz -> 52 MB, so the provider travels in one call (KEEP_SM=all keeps everything)
    if [ "${KEEP_SM:-90}" != all ]; then
      python3 "$repo/tools/gpu/fatbin_keep_arch.py" "$work/site/$provider" "$work/provider.so" --keep-sm "${KEEP_SM:-90}"
      mv "$work/provider.so" "$work/site/$provider"
    fi
    xz -T0 -6 -c "$work/site/$provider" | split -b "${PART_MB:-58}M" -d - "$stage/cuda.xz.part-"
    rm "$work/site/$provider"
    tar -C "$work/site" -cJf "$stage/ort-slim.tar.xz" .
    ls -l "$stage" | awk 'NR > 1 {printf "%s %.1f MB\n", $9, $5 / 1e6}'
    ;;
  slim)
    for b in "${bundles[@]}"; do [ -d "$b" ] || continue; git rm -r -q --cached "$b" && exclude "/$b/"; done
    echo "bundles out of the index (on disk still); travelling tree: $(git ls-files -z | du -cb --files0-from=- | tail -1 | cut -f1) bytes; run 'restore' after"
    ;;
  restore)
    for b in "${bundles[@]}"; do [ -d "$b" ] || continue; exclude -d "/$b/"; git reset -q -- "$b"; done
    git status --short -- t2m/bundles
    ;;
  keep)   # on the device: this call's parts into DIR, which outlives the call while the machine stays warm
    dir="${2:?usage: gpu_transport.sh keep DIR}"; mkdir -p "$dir"; cp "$stage"/* "$dir"/; ls "$dir"
    ;;
  unpack)   # on the device: DIR's parts -> an importable onnxruntime-gpu in SITE
    dir="${2:?usage: gpu_transport.sh unpack DIR SITE}"; site="${3:?usage: gpu_transport.sh unpack DIR SITE}"
    mkdir -p "$site"; tar -C "$site" -xJf "$dir/ort-slim.tar.xz"
    cat "$dir"/cuda.xz.part-* | xz -d >"$site/$provider"
    echo "onnxruntime-gpu unpacked in $site"
    ;;
  *)
    echo "usage: gpu_transport.sh prepare WHEEL | slim | restore | keep DIR | unpack DIR SITE" >&2; exit 2
    ;;
esac
