#!/usr/bin/env bash
# Installs the IEC 61131-3 Structured Text parser the tests check generated declarations
# with, when it is missing: blark (PyPI; a lark grammar of the standard's syntax, not
# written by us). Idempotent; safe to run from several test processes at once.
set -euo pipefail
lock="${TMPDIR:-/tmp}/iogate-install-blark.lock"
exec 9>"$lock"
flock 9
if command -v blark >/dev/null 2>&1; then
  exit 0
fi
python3 -m pip install --quiet --disable-pip-version-check blark
