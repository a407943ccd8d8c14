#!/usr/bin/env bash
# Installs the independent OPC UA client the OPC UA tests use when it is missing: asyncua
# (FreeOpcUa's Python implementation, with its own stack and crypto), from PyPI.
# Idempotent; safe to run from several test processes at once.
set -euo pipefail
lock="${TMPDIR:-/tmp}/iogate-install-opcua.lock"
exec 9>"$lock"
flock 9
if ! python3 -c 'import asyncua' >/dev/null 2>&1; then
  python3 -m pip install --quiet --disable-pip-version-check 'asyncua>=1.1,<2'
fi
