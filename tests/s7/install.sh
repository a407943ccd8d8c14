#!/usr/bin/env bash
# Installs the independent S7 server the S7 tests use when it is missing: python-snap7
# (the Snap7 library with its Python binding; the wheel carries the library), from PyPI.
# Idempotent; safe to run from several test processes at once.
set -euo pipefail
lock="${TMPDIR:-/tmp}/iogate-install-s7.lock"
exec 9>"$lock"
flock 9
if ! python3 -c 'import snap7' >/dev/null 2>&1; then
  python3 -m pip install --quiet --disable-pip-version-check 'python-snap7>=2,<3'
fi
