#!/usr/bin/env bash
# The real pipeline in one command: the volwarp client starts the real volwarp-server program as
# a child process on a free loopback port (the bundled MRI head, slowed to ~3 frames/s so that
# latency hiding is visible) and talks to it over TCP, with the default warp levers on
# (prediction and warp-sized radii; see the title bar). Opens a window where a display
# exists; headless it writes PNG frames of a 90° orbit at 30 FPS (and timings.csv) into
# out/demo/, records the session, and writes out/demo/strip.png: truth | stale | volwarp for
# four of the displayed frames (their FLIP in out/demo/strip.csv).
# Extra arguments go to volwarp-client (see `volwarp-client --help`).
set -euo pipefail
cd "$(dirname "$0")/.."
# Both programs: the thin client does not link the server; it runs it beside itself.
cargo build --release -p volwarp-server -p volwarp-client
bin=target/release
if [ -n "${CARGO_TARGET_DIR:-}" ]; then bin="$CARGO_TARGET_DIR/release"; fi
volume=data/mri_colin27.nrrd
if [ -n "${DISPLAY:-}${WAYLAND_DISPLAY:-}" ]; then
  exec "$bin/volwarp-client" --volume "$volume" --server-delay-ms 300 "$@"
else
  echo "demo: no display found: running headless, PNG frames go to out/demo/"
  cargo build --release -p volwarp-eval --bin volwarp-eval
  mkdir -p out/demo
  "$bin/volwarp-client" --headless --frames 90 --fps 30 --orbit 90 --size 512x512 --volume "$volume" \
    --server-delay-ms 300 --record out/demo/session.vwrec --out out/demo "$@"
  "$bin/volwarp-eval" strip --record out/demo/session.vwrec --volume "$volume" --out out/demo/strip.png
fi
