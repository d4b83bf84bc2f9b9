#!/usr/bin/env bash
# Makes sure a Docker engine answers, starting one if this machine has dockerd and we are root; exits non-zero with
# the reason on stderr otherwise (callers report it and skip). The engine gets no bridge network and no iptables
# rules: everything here uses --network host, so containers only ever talk over loopback.
# containerd is started first and waited for: on a loaded machine dockerd's own 5 s wait for it is too short.
set -euo pipefail
logs="${T2M_DOCKER_LOG_DIR:-/tmp}"
if docker info > /dev/null 2>&1; then exit 0; fi
command -v docker > /dev/null || { echo "no docker client (apt-get install docker.io)" >&2; exit 1; }
command -v dockerd > /dev/null || { echo "no dockerd (apt-get install docker.io)" >&2; exit 1; }
[ "$(id -u)" = 0 ] || { echo "dockerd is not running and only root can start it" >&2; exit 1; }
wait_for() {  # wait_for SECONDS COMMAND...: until COMMAND succeeds
  local deadline=$((SECONDS + $1)); shift
  until "$@" > /dev/null 2>&1; do
    [ "$SECONDS" -lt "$deadline" ] || return 1
    sleep 1
  done
}
socket=/run/containerd/containerd.sock
if [ -S "$socket" ] && ! pgrep -x containerd > /dev/null; then
  rm -f "$socket"  # left by a containerd that was killed: dockerd would wait on it in vain
fi
if [ ! -S "$socket" ]; then
  command -v containerd > /dev/null || { echo "no containerd (apt-get install docker.io)" >&2; exit 1; }
  nohup nice -n 19 containerd > "$logs/containerd.log" 2>&1 &
  wait_for 60 test -S "$socket" || { echo "containerd did not start (see $logs/containerd.log)" >&2; exit 1; }
fi
nohup nice -n 19 dockerd --bridge=none --iptables=false --containerd="$socket" > "$logs/dockerd.log" 2>&1 &
if ! wait_for 120 docker info; then
  echo "dockerd did not start:" >&2; tail -5 "$logs/dockerd.log" >&2; exit 1
fi
