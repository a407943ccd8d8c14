#!/usr/bin/env bash
# Installs what the deployment checks use, when it is missing: promtool and prometheus
# (Debian's prometheus package), kubernetes-validate (PyPI, ships the Kubernetes
# schemas) and prometheus-client (PyPI, its OpenMetrics parser), these two into tests/.venv. Idempotent; safe to run
# from several test processes at once.
set -euo pipefail
lock="${TMPDIR:-/tmp}/iogate-install-tools.lock"
exec 9>"$lock"
flock 9

if ! command -v promtool >/dev/null 2>&1 || ! command -v prometheus >/dev/null 2>&1; then
  sudo=""
  if [ "$(id -u)" -ne 0 ]; then sudo="sudo -n"; fi
  export DEBIAN_FRONTEND=noninteractive
  $sudo apt-get update -qq
  $sudo apt-get install -y -qq --no-install-recommends prometheus >/dev/null
fi

# The Python tools are pinned in tests/python/requirements.txt, in the tests' own Python.
bash "$(dirname "$0")/../../tests/python/venv.sh" >/dev/null
