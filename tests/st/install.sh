#!/usr/bin/env bash
# Installs the independent peer these tests use: blark (a lark grammar of IEC 61131-3 Structured Text, not written by us), from PyPI, pinned in
# tests/python/requirements.txt, into the tests' own Python (tests/.venv). Idempotent; safe to
# run from several test processes at once.
set -euo pipefail
bash "$(dirname "$0")/../python/venv.sh" >/dev/null
