#!/usr/bin/env bash
# Installs the independent MQTT peers the MQTT tests use, when they are missing: Debian's
# mosquitto (the broker; the tests start their own on a free loopback port) and
# mosquitto-clients (`mosquitto_sub`, the benchmark's subscriber) and, from PyPI,
# paho-mqtt (a subscriber and publisher not written by us) and pysparkplug (a Sparkplug B
# implementation of its own, to decode the gateway's payloads), pinned, into tests/.venv. Idempotent; safe to run from
# several test processes at once.
set -euo pipefail
lock="${TMPDIR:-/tmp}/iogate-install-mqtt.lock"
exec 9>"$lock"
flock 9
if { ! command -v mosquitto >/dev/null 2>&1 && ! [ -x /usr/sbin/mosquitto ]; } \
  || ! command -v mosquitto_sub >/dev/null 2>&1; then
  sudo=""
  if [ "$(id -u)" -ne 0 ]; then sudo="sudo -n"; fi
  export DEBIAN_FRONTEND=noninteractive
  $sudo apt-get update -qq
  $sudo apt-get install -y -qq --no-install-recommends mosquitto mosquitto-clients >/dev/null
  # The package's own broker is not needed: the tests start theirs.
  $sudo systemctl disable --now mosquitto >/dev/null 2>&1 || true
fi
bash "$(dirname "$0")/../python/venv.sh" >/dev/null
