#!/usr/bin/env bash
# Installs the independent EtherNet/IP peers the EtherNet/IP tests use when they are
# missing: cpppo (a Logix controller simulator) and pylogix (a Logix client), from PyPI.
# Idempotent; safe to run from several test processes at once.
set -euo pipefail
lock="${TMPDIR:-/tmp}/iogate-install-eip.lock"
exec 9>"$lock"
flock 9
if ! python3 -c 'import cpppo, pylogix' >/dev/null 2>&1; then
  python3 -m pip install --quiet --disable-pip-version-check 'cpppo>=5.2,<6' 'pylogix>=1,<2'
fi
