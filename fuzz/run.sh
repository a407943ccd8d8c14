#!/usr/bin/env bash
# Runs every fuzz target (or the ones named) for SECONDS each and prints, per target, the
# executions, their rate, the coverage reached and the findings (inputs that crashed, kept
# in fuzz/artifacts/TARGET/: each becomes a file in fuzz/regressions/TARGET/, which the
# normal tests run). The seed corpora are copied to fuzz/work/ so that what the fuzzer adds
# stays out of the repository.
#
#   bash fuzz/run.sh 600                 # every target, ten minutes each
#   bash fuzz/run.sh 60 s7_answer tokens # two of them
#   RUNS=10000000 bash fuzz/run.sh 3600  # each until 10 million executions or an hour
set -euo pipefail
secs=${1:-60}
shift || true
cd "$(dirname "$0")"
command -v cargo-fuzz >/dev/null || cargo install cargo-fuzz --locked
rustup toolchain list | grep -q nightly || rustup toolchain install nightly --profile minimal
targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then
  mapfile -t targets < <(cargo +nightly fuzz list)
fi
cargo +nightly fuzz build -O "${targets[@]:0:1}" >/dev/null 2>&1 || cargo +nightly fuzz build -O
printf '| target | seconds | executions | exec/s | coverage | findings |\n| --- | ---: | ---: | ---: | ---: | ---: |\n'
for t in "${targets[@]}"; do
  mkdir -p "work/$t"
  cp -n "corpus/$t/"* "work/$t/" 2>/dev/null || true
  log=$(mktemp)
  before=$(find "artifacts/$t" -type f 2>/dev/null | wc -l || true)
  cargo +nightly fuzz run -O "$t" "work/$t" -- -max_total_time="$secs" ${RUNS:+-runs="$RUNS"} -print_final_stats=1 >"$log" 2>&1 || true
  execs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | awk '{print $2}' | tail -1 || true)
  rate=$(grep -o 'stat::average_exec_per_sec: *[0-9]*' "$log" | awk '{print $2}' | tail -1 || true)
  cov=$(grep -o 'cov: [0-9]*' "$log" | tail -1 | awk '{print $2}' || true)
  after=$(find "artifacts/$t" -type f 2>/dev/null | wc -l || true)
  echo "| $t | $secs | ${execs:-?} | ${rate:-?} | ${cov:-?} | $((after - before)) |"
  if [ "$after" -gt "$before" ]; then
    grep -m1 -A3 'panicked at\|ERROR: libFuzzer' "$log" | sed 's/^/    /' || true
  fi
  rm -f "$log"
done
