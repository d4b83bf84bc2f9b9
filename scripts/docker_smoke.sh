#!/usr/bin/env bash
# Builds the image and runs it: /health, a 3-sentence glb request (200), a bad request (422), non-root, no torch,
# the image's own HEALTHCHECK turning healthy, and a graceful `docker stop` (exit code 0). Prints the image size and
# the time to healthy. Idempotent: the base image and the wheelhouse are cached, the container is removed on exit.
# Usage: scripts/docker_smoke.sh   (needs a running Docker engine: scripts/start_dockerd.sh)
#   T2M_BASE_IMAGE=python:3.11-slim  use this base (default: see scripts/docker_base_image.sh)
#   T2M_WHEELHOUSE=0                 let pip inside the build use the package index (default 1: the offline mode)
#   T2M_IMAGE=t2m-service:smoke      the tag to build
# Everything is on loopback: the build and the container use --network host, the server listens on 127.0.0.1.
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
cd "$repo"
image="${T2M_IMAGE:-t2m-service:smoke}"
wheelhouse="${T2M_WHEELHOUSE:-1}"
step() { echo "== $*"; }
fail() { echo "FAILED: $*" >&2; exit 1; }

base="$(scripts/docker_base_image.sh)"
step "base image: $base"
if [ "$wheelhouse" = 1 ]; then
  step "wheelhouse (offline build mode): scripts/build_wheelhouse.sh"
  scripts/build_wheelhouse.sh deploy/wheelhouse
fi
# Each build leaves the previous smoke image's layers dangling; without this, repeated CI runs fill the disk.
docker image prune -f > /dev/null
docker builder prune -f > /dev/null 2>&1 || true
docker_root="$(docker info -f '{{.DockerRootDir}}')"
free_mb="$(df -Pm "$docker_root" | awk 'NR == 2 {print $4}')"
[ "$free_mb" -ge 3000 ] || fail "only ${free_mb} MB free under $docker_root: the build needs about 3 GB (docker system prune)"
step "docker build -t $image (BASE_IMAGE=$base, WHEELHOUSE=$wheelhouse)"
started=$SECONDS
docker build --network host --build-arg BASE_IMAGE="$base" --build-arg WHEELHOUSE="$wheelhouse" -t "$image" . \
  > /tmp/t2m-docker-build.log 2>&1 || { tail -30 /tmp/t2m-docker-build.log; fail "docker build"; }
build_s=$((SECONDS - started))
size_bytes="$(docker image inspect -f '{{.Size}}' "$image")"

port="$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')"
url="http://127.0.0.1:$port"
name="t2m-smoke-$port"
trap 'docker rm -f "$name" > /dev/null 2>&1 || true' EXIT
step "docker run --network host $image on 127.0.0.1:$port"
start_ns="$(date +%s%N)"
docker run -d --name "$name" --network host -e T2M_HOST=127.0.0.1 -e T2M_PORT="$port" "$image" > /dev/null
elapsed() { echo "$(( ($(date +%s%N) - start_ns) / 1000000 ))"; }  # ms since docker run

health_ms=""
for _ in $(seq 1 600); do
  [ "$(docker inspect -f '{{.State.Running}}' "$name")" = true ] || { docker logs "$name" | tail -20; fail "container exited"; }
  if [ "$(curl -s -o /dev/null -w '%{http_code}' "$url/health")" = 200 ]; then health_ms="$(elapsed)"; break; fi
  sleep 0.2
done
[ -n "$health_ms" ] || { docker logs "$name" | tail -20; fail "/health not 200 after 120 s"; }

status_of() {  # status_of BODY [OUTFILE]: POST /generate, prints the HTTP status
  curl -s -o "${2:-/dev/null}" -w '%{http_code}' -H 'content-type: application/json' -d "$1" "$url/generate"
}
glb="$(mktemp)"
trap 'docker rm -f "$name" > /dev/null 2>&1 || true; rm -f "$glb"' EXIT
glb_status="$(status_of '{"segments": [{"text": "a person walks forward", "duration": 3.0},
  {"text": "a person waves with the right hand", "duration": 2.0}, {"text": "a person bows", "duration": 2.0}],
  "format": "glb", "seed": 123}' "$glb")"
[ "$glb_status" = 200 ] || fail "glb request: HTTP $glb_status"
[ "$(head -c 4 "$glb")" = glTF ] || fail "glb request: the answer is not a glTF binary"
bad_status="$(status_of '{"segments": [{"text": "a person walks forward", "duration": 99}]}')"
[ "$bad_status" = 422 ] || fail "bad request: HTTP $bad_status, expected 422"

uid="$(docker exec "$name" id -u)"
[ "$uid" != 0 ] || fail "the server runs as root"
torch="$(docker exec "$name" python -c 'import importlib.util; print(importlib.util.find_spec("torch") is not None)')"
[ "$torch" = False ] || fail "torch is installed in the image"

healthy_ms=""
for _ in $(seq 1 600); do
  state="$(docker inspect -f '{{.State.Health.Status}}' "$name")"
  if [ "$state" = healthy ]; then healthy_ms="$(elapsed)"; break; fi
  [ "$state" != unhealthy ] || fail "HEALTHCHECK says unhealthy"
  sleep 0.2
done
[ -n "$healthy_ms" ] || fail "HEALTHCHECK not healthy after 120 s"

started=$SECONDS
docker stop -t 75 "$name" > /dev/null
exit_code="$(docker inspect -f '{{.State.ExitCode}}' "$name")"
# uvicorn re-raises the SIGTERM it handled once it has shut down: 0 as PID 1 (the kernel ignores it), else 143
# The log is read whole before it is searched: `docker logs | grep -q` under pipefail fails at random (grep exits
# at the first match, docker logs dies of SIGPIPE while it still writes, and the pipeline reports that failure).
container_log="$(docker logs "$name" 2>&1)"
case "$exit_code" in 0|143) ;; *) tail -20 <<<"$container_log"; fail "docker stop: exit code $exit_code" ;; esac
grep -q "Application shutdown complete" <<<"$container_log" \
  || { tail -20 <<<"$container_log"; fail "docker stop: no graceful shutdown in the log"; }

echo
echo "image $image: $((size_bytes / 1000000)) MB (base $base, WHEELHOUSE=$wheelhouse, build ${build_s} s)"
echo "time to /health 200: $((health_ms / 1000)).$(printf %03d $((health_ms % 1000))) s after docker run"
echo "time to HEALTHCHECK healthy: $((healthy_ms / 1000)).$(printf %03d $((healthy_ms % 1000))) s after docker run"
echo "POST /generate 3 sentences glb: $glb_status ($(wc -c < "$glb") bytes); bad request (duration 99): $bad_status"
echo "uid in the container: $uid; torch installed: $torch; docker stop (SIGTERM): exit $exit_code in $((SECONDS - started)) s"
echo "docker smoke test: ok"
