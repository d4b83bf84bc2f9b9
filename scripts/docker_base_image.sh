#!/usr/bin/env bash
# Prints the name of a base image for the Dockerfile's BASE_IMAGE, making it if needed (idempotent, cached):
#   T2M_BASE_IMAGE if set; else python:3.11-slim if it is already here; else a local Debian bookworm image
#   (t2m-base:bookworm) made with debootstrap from the Debian mirror apt uses, for machines that cannot pull from an
#   image registry. Progress goes to stderr, the name alone to stdout.
set -euo pipefail
if [ -n "${T2M_BASE_IMAGE:-}" ]; then echo "$T2M_BASE_IMAGE"; exit 0; fi
if docker image inspect python:3.11-slim > /dev/null 2>&1; then echo python:3.11-slim; exit 0; fi
name="${T2M_LOCAL_BASE:-t2m-base:bookworm}"
if docker image inspect "$name" > /dev/null 2>&1; then echo "$name"; exit 0; fi
command -v debootstrap > /dev/null || { echo "no base image and no debootstrap (apt-get install debootstrap)" >&2; exit 1; }
mirror="${T2M_DEBIAN_MIRROR:-}"
if [ -z "$mirror" ]; then  # the first http(s) Debian mirror of apt's sources (deb822 or one-line format)
  mirror="$(grep -rhoE '(URIs:|^deb) +https?://[^ ]+/debian/?( |$)' /etc/apt/sources.list /etc/apt/sources.list.d/ \
            2>/dev/null | grep -oE 'https?://[^ ]+' | head -1 || true)"
fi
[ -n "$mirror" ] || { echo "cannot tell apt's Debian mirror: set T2M_DEBIAN_MIRROR" >&2; exit 1; }
rootfs="$(mktemp -d)"
trap 'rm -rf "$rootfs"' EXIT
echo "making $name with debootstrap from $mirror ..." >&2
debootstrap --variant=minbase --include=python3,python3-venv,ca-certificates bookworm "$rootfs" "$mirror" >&2
# apt's lists and caches are not needed in an image
rm -rf "$rootfs"/var/lib/apt/lists/* "$rootfs"/var/cache/apt/*.bin "$rootfs"/var/cache/apt/archives/*.deb
tar -C "$rootfs" -c . | docker import --change 'ENV LANG=C.UTF-8' - "$name" > /dev/null
echo "$name"
