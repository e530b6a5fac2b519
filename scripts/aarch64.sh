#!/usr/bin/env bash
# The ARM thin client's code *executed*, not only compiled: volwarp-lanes', volwarp-core's and
# volwarp-cpu-tracer's tests built for aarch64-unknown-linux-gnu and run under qemu-user (user-mode
# emulation: the aarch64 binaries run on this x86-64 machine against Debian's aarch64 libc), then
# an aarch64 headless client against a local x86-64 server for a few frames. Needs what
# scripts/setup.sh installs (gcc-aarch64-linux-gnu, libc6-dev-arm64-cross, qemu-user, the
# aarch64 Rust target). Run from the repository root; called by scripts/test.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
export CARGO_TARGET_AARCH64_UNKNOWN_LINUX_GNU_LINKER=aarch64-linux-gnu-gcc
export CARGO_TARGET_AARCH64_UNKNOWN_LINUX_GNU_RUNNER="qemu-aarch64 -L /usr/aarch64-linux-gnu"
TARGET_DIR="${CARGO_TARGET_DIR:-target}"

t0=$(date +%s)
echo "== aarch64 under qemu-user: volwarp-lanes, volwarp-core and volwarp-cpu-tracer tests"
# Every test of lanes and core (about 30 s emulated). Of cpu-tracer's, those that run its
# portable kernels against the scalar reference in seconds: arch_lanes (asserts the portable
# lanes are the kind taken), portable_simd, the unit tests, the layered frames, hole filling
# and the parallel LBVH build. Left to the x86-64 run (the same portable code, 30 s to minutes
# each under emulation): packet_vs_scalar, baselines, real_frames, robustness, tile_cull,
# tile_splat, avx2_lanes.
# One invocation: the three crates' dependencies are built once, with the same features.
cargo test --target aarch64-unknown-linux-gnu -p volwarp-lanes -p volwarp-core -p volwarp-cpu-tracer --lib \
  --test compact_fast --test compact_frame --test fuzz_mirror --test layers --test properties \
  --test arch_lanes --test portable_simd --test layer_frames --test hole_fill --test parallel_build
t1=$(date +%s)

echo "== aarch64 headless client (qemu-user) against a local x86-64 server"
cargo build --target aarch64-unknown-linux-gnu -p volwarp-client --no-default-features
# The x86-64 server the workspace tests built (scripts/test.sh runs this after them), else now.
[ -x "$TARGET_DIR/debug/volwarp-server" ] || cargo build -p volwarp-server
out=$(mktemp -d)
trap 'kill "${server_pid:-0}" 2>/dev/null || true; rm -rf "$out"' EXIT
"$TARGET_DIR/debug/volwarp-server" --listen 127.0.0.1:0 --threads 2 >"$out/server.log" 2>&1 &
server_pid=$!
for _ in $(seq 100); do grep -q "listening on" "$out/server.log" && break; sleep 0.1; done
addr=$(sed -n 's/^listening on //p' "$out/server.log" | head -1)
[ -n "$addr" ] || { cat "$out/server.log"; echo "aarch64: the server did not start"; exit 1; }
timeout 300 qemu-aarch64 -L /usr/aarch64-linux-gnu "$TARGET_DIR/aarch64-unknown-linux-gnu/debug/volwarp-client" \
  --connect "$addr" --no-reconnect --headless --out "$out/frames" --frames 3 --size 96x96 --threads 2
n=$(ls "$out/frames"/*.png | wc -l)
[ "$n" = 3 ] || { echo "aarch64 client: $n frames instead of 3"; exit 1; }
t2=$(date +%s)
echo "aarch64: tests $((t1 - t0)) s, headless client $((t2 - t1)) s (3 frames from $addr)"
