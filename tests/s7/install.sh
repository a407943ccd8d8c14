#!/usr/bin/env bash
# Installs the independent peer these tests use: python-snap7 (the Snap7 library with its Python binding; the wheel carries the library), from PyPI, pinned in
# tests/python/requirements.txt, into the tests' own Python (tests/.venv). Idempotent; safe to
# run from several test processes at once.
set -euo pipefail
bash "$(dirname "$0")/../python/venv.sh" >/dev/null
