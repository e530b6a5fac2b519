#!/usr/bin/env bash
# The one command that passes every test of volwarp: installs what it needs, then checks
# formatting, lints, the no_std build of core, the whole test suite (GPU tests on lavapipe,
# the window test under Xvfb) and a short run of every fuzz target.
set -euo pipefail
cd "$(dirname "$0")/.."
export CARGO_TERM_COLOR=never
# A clean clone builds once: incremental caches would only cost disk.
export CARGO_INCREMENTAL="${CARGO_INCREMENTAL:-0}"

# Each stage's wall time, printed when the next one starts and summed up at the end.
stage_name="" stage_t0=$(date +%s) run_t0=$(date +%s) stage_times=()
stage() {
  local now; now=$(date +%s)
  if [ -n "$stage_name" ]; then stage_times+=("$(printf '%5d s  %s' $((now - stage_t0)) "$stage_name")"); fi
  stage_name="$1" stage_t0=$now
  echo "== $1"
}

stage "setup (scripts/setup.sh)"
scripts/setup.sh

# Software Vulkan for the GPU tests; a private runtime dir keeps Mesa quiet.
export VK_DRIVER_FILES=/usr/share/vulkan/icd.d/lvp_icd.x86_64.json
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp/volwarp-xdg-$$}"
mkdir -p "$XDG_RUNTIME_DIR" && chmod 700 "$XDG_RUNTIME_DIR"

stage "cargo fmt --check"
cargo fmt --all --check

# The workspace is checked, built and tested once, with the server's feature `mpi` on (it only
# adds code: src/distributed/mpi.rs and the `mpiexec` launch), so the server is not compiled a
# second time for the MPI stage; its default build is linted on its own below.
stage "cargo clippy --workspace --all-targets --features volwarp-server/mpi -- -D warnings"
cargo clippy --workspace --all-targets --features volwarp-server/mpi -- -D warnings
stage "cargo clippy -p volwarp-server --lib --bins -- -D warnings (the default build, no MPI)"
cargo clippy -p volwarp-server --lib --bins -- -D warnings
# The default server and the client link no MPI.
if cargo tree -p volwarp-server -p volwarp-client -e normal | grep -q " mpi v"; then
  echo "the default build depends on MPI"; exit 1
fi

stage "no_std build of volwarp-core for thumbv7em-none-eabihf (bare, and with alloc: the compact codec)"
cargo build -p volwarp-core --no-default-features --target thumbv7em-none-eabihf
cargo build -p volwarp-core --no-default-features --features alloc --target thumbv7em-none-eabihf

stage "volwarp-core's codec tests on its no_std + alloc build (ruzstd, libm; its own workspace)"
(cd core/alloc-tests && cargo test)

stage "tests (window tests under Xvfb; the server's mpiexec -n 1..4 tests with MPICH)"
xvfb-run -a -s "-screen 0 1280x1024x24" cargo test --workspace --features volwarp-server/mpi

stage "the real client, headless over loopback, against 3 MPI ranks"
scripts/mpi-client.sh target/debug/volwarp-server target/debug/volwarp-client

# The ARM thin client (aarch64, no GPU; portable SIMD maps to NEON): lanes', core's and
# cpu-tracer's tests built for aarch64 and run under qemu-user, and the headless aarch64 client
# against the local server the tests above built.
stage "aarch64 under qemu-user (scripts/aarch64.sh)"
scripts/aarch64.sh

if [ "${VOLWARP_NO_FUZZ:-0}" != 1 ]; then
  # The five volwarp-core targets (wire format, frames, round trip, LBVH, compact codec). The
  # two volume targets' sanitizer build instruments all of the server's dependencies (32 minutes
  # for all seven on the 2-core machine beside another build, 2 for the core targets alone,
  # idle: docs/fuzzing.md); their checks run in
  # `cargo test` above (server/tests/hardening.rs feeds the same functions their seeds and
  # mutations). VOLWARP_FUZZ_VOLUME=1 fuzzes them here too.
  stage "fuzz smoke (scripts/fuzz-smoke.sh)"
  VOLWARP_FUZZ_VOLUME="${VOLWARP_FUZZ_VOLUME:-0}" scripts/fuzz-smoke.sh "${VOLWARP_FUZZ_SECONDS:-20}"
fi
stage "done"
echo "== stage times"
printf '%s\n' "${stage_times[@]}"
echo "$(( $(date +%s) - run_t0 )) s in all"
echo "== all checks passed"
