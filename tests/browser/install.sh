#!/usr/bin/env bash
# Installs what the web page's tests drive, when it is missing: Debian's chromium and
# chromium-driver. Idempotent; safe to run from several test processes at once.
set -euo pipefail
lock="${TMPDIR:-/tmp}/iogate-install-chromium.lock"
exec 9>"$lock"
flock 9
if command -v chromium >/dev/null 2>&1 && command -v chromedriver >/dev/null 2>&1; then
  exit 0
fi
sudo=""
if [ "$(id -u)" -ne 0 ]; then sudo="sudo -n"; fi
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -qq
$sudo apt-get install -y -qq --no-install-recommends chromium chromium-driver >/dev/null
