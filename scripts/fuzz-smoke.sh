#!/usr/bin/env bash
# Runs the cargo-fuzz targets of fuzz/ briefly on nightly (default 20 s each), starting from
# the committed seeds (fuzz/seeds/<target>/; new inputs go to the ignored fuzz/corpus/).
# Fails on the first finding; the crash input is left under fuzz/artifacts/<target>/.
#
# Seven targets: the five volwarp-core ones, and `volume_header` and `volume_load`, which fuzz the
# server's volume parsers and loaders and need the server's dependencies (a clean sanitizer build of
# several minutes more; VOLWARP_FUZZ_VOLUME=0 leaves them out for a quick local run). Their stable
# mirrors run in `cargo test`.
# The libFuzzer seed is fixed (VOLWARP_FUZZ_SEED, default 1) so that a CI failure reproduces;
# long campaigns with random seeds are run by hand (docs/fuzzing.md).
# Needs: a nightly toolchain and `cargo install cargo-fuzz --locked` (scripts/setup.sh).
#
# A smoke run is mostly its clean sanitizer build, so it builds at opt-level 1 with line tables
# (VOLWARP_FUZZ_OPT, default 1) rather than the fuzz crate's release profile (opt-level 3), which
# long campaigns keep: the five core targets build from clean in about 2 minutes on the 2-core
# machine, and 20 s still replay every seed and run 1-28 thousand new inputs a second.
set -euo pipefail
secs="${1:-20}"
export CARGO_PROFILE_RELEASE_OPT_LEVEL="${VOLWARP_FUZZ_OPT:-1}"
export CARGO_PROFILE_RELEASE_DEBUG=line-tables-only
cd "$(dirname "$0")/../fuzz"
targets=(wire_decode_chunked frame_decode roundtrip lbvh compact_decode)
features=()
if [ "${VOLWARP_FUZZ_VOLUME:-1}" = 1 ]; then
  targets+=(volume_header volume_load)
  features=(--features volume)
fi
cargo +nightly fuzz build "${features[@]}"
for t in "${targets[@]}"; do
  mkdir -p "corpus/$t"
  echo "-- fuzz $t for ${secs} s"
  log="$(mktemp)"
  if ! cargo +nightly fuzz run "${features[@]}" "$t" "corpus/$t" "seeds/$t" -- \
      -max_total_time="$secs" -max_len=65536 -seed="${VOLWARP_FUZZ_SEED:-1}" -print_final_stats=1 >"$log" 2>&1; then
    tail -n 60 "$log"
    echo "fuzz target $t failed; see fuzz/artifacts/$t/"
    exit 1
  fi
  grep -E "stat::(number_of_executed_units|average_exec_per_sec)" "$log" || true
  rm -f "$log"
done
