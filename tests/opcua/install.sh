#!/usr/bin/env bash
# Installs the independent peer these tests use: asyncua (FreeOpcUa's Python implementation, with its own stack and crypto), from PyPI, pinned in
# tests/python/requirements.txt, into the tests' own Python (tests/.venv). Idempotent; safe to
# run from several test processes at once.
set -euo pipefail
bash "$(dirname "$0")/../python/venv.sh" >/dev/null
