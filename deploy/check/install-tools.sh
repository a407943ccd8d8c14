#!/usr/bin/env bash
# Installs what the deployment checks use, when it is missing: promtool and prometheus
# (Debian's prometheus package), kubernetes-validate (PyPI, ships the Kubernetes
# schemas) and prometheus-client (PyPI, its OpenMetrics parser). Idempotent; safe to run
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

if ! python3 -c "import kubernetes_validate" >/dev/null 2>&1; then
  python3 -m pip install --quiet --disable-pip-version-check kubernetes-validate
fi

# An OpenMetrics parser not written by us (the official Python client's), for /metrics.
if ! python3 -c "import prometheus_client.openmetrics.parser" >/dev/null 2>&1; then
  python3 -m pip install --quiet --disable-pip-version-check prometheus-client
fi
