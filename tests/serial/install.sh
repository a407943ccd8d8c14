#!/usr/bin/env bash
# Installs the independent Modbus serial peers the serial tests use when they are missing:
# libmodbus's mbpoll (an RTU master, from Debian) and pymodbus (RTU and ASCII masters and
# slaves, with pyserial, from PyPI, pinned, into tests/.venv). Idempotent; safe to run from several test processes
# at once.
set -euo pipefail
lock="${TMPDIR:-/tmp}/iogate-install-serial.lock"
exec 9>"$lock"
flock 9
if ! command -v mbpoll >/dev/null 2>&1; then
  sudo=""
  if [ "$(id -u)" -ne 0 ]; then sudo="sudo -n"; fi
  export DEBIAN_FRONTEND=noninteractive
  $sudo apt-get update -qq
  $sudo apt-get install -y -qq --no-install-recommends mbpoll >/dev/null
fi
bash "$(dirname "$0")/../python/venv.sh" >/dev/null
