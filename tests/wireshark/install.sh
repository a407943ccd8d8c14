#!/usr/bin/env bash
# Installs Wireshark's command-line reader, tshark, from Debian when it is missing: the
# tests give it captures written from what passed through a recording proxy (no capture
# of a live interface, so no capture rights are asked for). Idempotent; safe to run from
# several test processes at once.
set -euo pipefail
lock="${TMPDIR:-/tmp}/iogate-install-wireshark.lock"
exec 9>"$lock"
flock 9
if ! command -v tshark >/dev/null 2>&1; then
  sudo=""
  if [ "$(id -u)" -ne 0 ]; then sudo="sudo -n"; fi
  export DEBIAN_FRONTEND=noninteractive
  echo "wireshark-common wireshark-common/install-setuid boolean false" | $sudo debconf-set-selections
  $sudo apt-get update -qq
  $sudo apt-get install -y -qq --no-install-recommends tshark >/dev/null
fi
