#!/usr/bin/env bash
# The one command that passes every test of volwarp: installs what it needs, then checks
# formatting, lints, the no_std build of core, the whole test suite (GPU tests on lavapipe,
# the window test under Xvfb) and a short run of every fuzz target.
set -euo pipefail
cd "$(dirname "$0")/.."
export CARGO_TERM_COLOR=never
# A clean clone builds once: incremental caches would only cost disk.
export CARGO_INCREMENTAL="${CARGO_INCREMENTAL:-0}"

scripts/setup.sh

# Software Vulkan for the GPU tests; a private runtime dir keeps Mesa quiet.
export VK_DRIVER_FILES=/usr/share/vulkan/icd.d/lvp_icd.x86_64.json
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp/volwarp-xdg-$$}"
mkdir -p "$XDG_RUNTIME_DIR" && chmod 700 "$XDG_RUNTIME_DIR"

echo "== cargo fmt --check"
cargo fmt --all --check

echo "== cargo clippy --all-targets -- -D warnings"
cargo clippy --workspace --all-targets -- -D warnings

echo "== no_std build of volwarp-core for thumbv7em-none-eabihf (bare, and with alloc: the compact codec)"
cargo build -p volwarp-core --no-default-features --target thumbv7em-none-eabihf
cargo build -p volwarp-core --no-default-features --features alloc --target thumbv7em-none-eabihf

echo "== volwarp-core's codec tests on its no_std + alloc build (ruzstd, libm; its own workspace)"
(cd core/alloc-tests && cargo test)

echo "== ARM thin client: cargo check for aarch64-unknown-linux-gnu (portable SIMD maps to NEON)"
cargo check --target aarch64-unknown-linux-gnu -p volwarp-cpu-tracer -p volwarp-client

echo "== tests (window tests under Xvfb)"
xvfb-run -a -s "-screen 0 1280x1024x24" cargo test --workspace

echo "== the server across MPI ranks: clippy and mpiexec -n 1..4 end to end (feature mpi, MPICH)"
# The default server and the client link no MPI.
if cargo tree -p volwarp-server -p volwarp-client -e normal | grep -q " mpi v"; then
  echo "the default build depends on MPI"; exit 1
fi
cargo clippy -p volwarp-server --all-targets --features mpi -- -D warnings
cargo test -p volwarp-server --features mpi --test mpi
# The real client, headless over loopback, against 3 ranks.
scripts/mpi-client.sh target/debug/volwarp-server target/debug/volwarp-client

# The same code run on aarch64 under qemu-user: lanes', core's and cpu-tracer's tests and a
# headless aarch64 client against the local server the tests above built.
scripts/aarch64.sh

if [ "${VOLWARP_NO_FUZZ:-0}" != 1 ]; then
  echo "== fuzz smoke"
  scripts/fuzz-smoke.sh "${VOLWARP_FUZZ_SECONDS:-30}"
fi
echo "== all checks passed"
