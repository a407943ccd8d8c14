#!/usr/bin/env bash
# Installs the independent OpenAPI fuzzer the API tests use when it is missing:
# schemathesis (it reads the served document and checks every answer against it), from
# PyPI. Idempotent; safe to run from several test processes at once.
set -euo pipefail
lock="${TMPDIR:-/tmp}/iogate-install-schemathesis.lock"
exec 9>"$lock"
flock 9
if ! python3 -m schemathesis.cli --version >/dev/null 2>&1; then
  python3 -m pip install --quiet --disable-pip-version-check 'schemathesis>=4.3,<5'
fi
