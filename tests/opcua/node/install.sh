#!/usr/bin/env bash
# Installs the independent OPC UA server node-opcua, pinned by package-lock.json, into
# tests/opcua/node/node_modules (git-ignored), with Debian's Node.js and npm when missing.
# Idempotent; safe to run from several test processes at once.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
exec 9>"$here/.install.lock"
flock 9
if ! command -v node >/dev/null 2>&1 || ! command -v npm >/dev/null 2>&1; then
  sudo=""
  if [ "$(id -u)" -ne 0 ]; then sudo="sudo -n"; fi
  export DEBIAN_FRONTEND=noninteractive
  $sudo apt-get update -qq
  $sudo apt-get install -y -qq --no-install-recommends nodejs npm >/dev/null
fi
want="$(sha256sum "$here/package-lock.json" | cut -d' ' -f1)"
if [ "$(cat "$here/node_modules/.installed" 2>/dev/null || true)" != "$want" ]; then
  (cd "$here" && npm ci --no-audit --no-fund --silent >&2)
  echo "$want" >"$here/node_modules/.installed"
fi
