#!/usr/bin/env bash
# The IEC 104 tests' peer: c104 (lib60870's Python binding), pinned in
# tests/python/requirements.txt and installed with the other Python peers.
set -euo pipefail
bash "$(dirname "$0")/../python/venv.sh" >/dev/null
