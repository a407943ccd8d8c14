#!/usr/bin/env bash
# The soak (tests/src/bin/soak/): a release gateway with every link kind and front-end busy
# at once, writes, a fault every minute, for MINUTES (default 10); prints its report and
# exits non-zero when it found a wrong value, a lost or reordered write, or /readyz lying.
#
#   bash soak/run.sh 120                 # two hours
#   bash soak/run.sh 30 --fault-every 30 # a fault every 30 seconds
set -euo pipefail
cd "$(dirname "$0")/.."
minutes=${1:-10}
shift || true
bash tests/mqtt/install.sh
bash tests/opcua/install.sh
bash tests/s7/install.sh
cargo build --release --locked -p iogate-tests --bin soak --bin gateway
exec target/release/soak --minutes "$minutes" "$@"
