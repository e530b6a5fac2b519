#!/usr/bin/env bash
# Runs every cargo-fuzz target of fuzz/ briefly on nightly (default 30 s each), starting from
# the committed seeds (fuzz/seeds/<target>/; new inputs go to the ignored fuzz/corpus/).
# Fails on the first finding; the crash input is left under fuzz/artifacts/<target>/.
# Needs: a nightly toolchain and `cargo install cargo-fuzz --locked` (scripts/setup.sh).
set -euo pipefail
secs="${1:-30}"
cd "$(dirname "$0")/../fuzz"
cargo +nightly fuzz build
for t in $(cargo +nightly fuzz list); do
  mkdir -p "corpus/$t"
  echo "-- fuzz $t for ${secs} s"
  log="$(mktemp)"
  if ! cargo +nightly fuzz run "$t" "corpus/$t" "seeds/$t" -- \
      -max_total_time="$secs" -max_len=65536 -print_final_stats=1 >"$log" 2>&1; then
    tail -n 60 "$log"
    echo "fuzz target $t failed; see fuzz/artifacts/$t/"
    exit 1
  fi
  grep -E "stat::(number_of_executed_units|average_exec_per_sec)" "$log" || true
  rm -f "$log"
done
