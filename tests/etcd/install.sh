#!/usr/bin/env bash
# Installs etcd (Debian's etcd-server) for the tests of `ha: {arbiter: etcd}`, when it is
# missing; the tests start their own on free loopback ports. Idempotent; safe to run from
# several test processes at once.
set -euo pipefail
lock="${TMPDIR:-/tmp}/iogate-install-etcd.lock"
exec 9>"$lock"
flock 9
if ! command -v etcd >/dev/null 2>&1; then
  sudo=""
  if [ "$(id -u)" -ne 0 ]; then sudo="sudo -n"; fi
  export DEBIAN_FRONTEND=noninteractive
  $sudo apt-get update -qq
  $sudo apt-get install -y -qq --no-install-recommends etcd-server >/dev/null
  # The package's own server is not needed: the tests start theirs.
  $sudo systemctl disable --now etcd >/dev/null 2>&1 || true
fi
