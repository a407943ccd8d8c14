#!/usr/bin/env bash
# Makes the tests' own Python, tests/.venv (git-ignored), from tests/python/requirements.txt,
# and prints its interpreter's path. The user's own Python is neither used nor changed: a
# newer asyncua or paho-mqtt there does not matter. Made again when the requirements change.
# Idempotent; safe to run from several test processes at once.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
venv="$(dirname "$here")/.venv"
requirements="$here/requirements.txt"
want="$(sha256sum "$requirements" | cut -d' ' -f1)"
exec 9>"$(dirname "$here")/.venv.lock"
flock 9
if [ "$(cat "$venv/.requirements" 2>/dev/null || true)" != "$want" ]; then
  rm -rf "$venv"
  if ! python3 -m venv "$venv" >/dev/null 2>&1; then
    # Debian's python3 makes virtual environments only with python3-venv.
    sudo=""
    if [ "$(id -u)" -ne 0 ]; then sudo="sudo -n"; fi
    export DEBIAN_FRONTEND=noninteractive
    $sudo apt-get update -qq
    $sudo apt-get install -y -qq --no-install-recommends python3-venv >/dev/null
    rm -rf "$venv"
    python3 -m venv "$venv"
  fi
  "$venv/bin/python" -m pip install --quiet --disable-pip-version-check --no-input \
    --requirement "$requirements" >&2
  echo "$want" >"$venv/.requirements"
fi
echo "$venv/bin/python"
