#!/usr/bin/env bash
# Installs what the benchmarks' peers are built from, when it is missing: a C compiler,
# pkg-config and Debian's libmodbus-dev. Idempotent; safe to run from several processes.
set -euo pipefail
lock="${TMPDIR:-/tmp}/iogate-install-peers.lock"
exec 9>"$lock"
flock 9
if command -v cc >/dev/null 2>&1 && pkg-config --exists libmodbus 2>/dev/null; then
  exit 0
fi
sudo=""
if [ "$(id -u)" -ne 0 ]; then sudo="sudo -n"; fi
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -qq
$sudo apt-get install -y -qq --no-install-recommends gcc libc6-dev pkg-config libmodbus-dev >/dev/null
