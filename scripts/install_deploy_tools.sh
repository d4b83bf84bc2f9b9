#!/usr/bin/env bash
# Installs what the deployment checks need (Debian/Ubuntu, as root): Docker's engine and client, nginx and
# debootstrap (for a local base image where no registry can be reached). Exits non-zero with the reason otherwise.
set -euo pipefail
missing=()
for tool in docker:docker.io dockerd:docker.io nginx:nginx debootstrap:debootstrap; do
  command -v "${tool%%:*}" > /dev/null || [ -x "/usr/sbin/${tool%%:*}" ] || missing+=("${tool##*:}")
done
[ "${#missing[@]}" -eq 0 ] && exit 0
[ "$(id -u)" = 0 ] || { echo "missing ${missing[*]} and not root" >&2; exit 1; }
command -v apt-get > /dev/null || { echo "missing ${missing[*]} and no apt-get" >&2; exit 1; }
DEBIAN_FRONTEND=noninteractive nice -n 19 apt-get install -y --no-install-recommends $(printf '%s\n' "${missing[@]}" | sort -u)
