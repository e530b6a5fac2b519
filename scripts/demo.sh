#!/usr/bin/env bash
# The real pipeline in one command: the volwarp client starts the real volwarp-server program as
# a child process on a free loopback port (the bundled CT head) and talks to it over TCP. Opens a
# window where a display exists; headless it writes PNG frames of a 90° orbit (and timings.csv)
# into out/demo/.
# Extra arguments go to volwarp-client (see `volwarp-client --help`).
set -euo pipefail
cd "$(dirname "$0")/.."
# Both programs: the thin client does not link the server; it runs it beside itself.
cargo build --release -p volwarp-server -p volwarp-client
client=target/release/volwarp-client
if [ -n "${CARGO_TARGET_DIR:-}" ]; then client="$CARGO_TARGET_DIR/release/volwarp-client"; fi
if [ -n "${DISPLAY:-}${WAYLAND_DISPLAY:-}" ]; then
  exec "$client" "$@"
else
  echo "demo: no display found: running headless, PNG frames go to out/demo/"
  exec "$client" --headless --frames 60 --orbit 90 --size 512x512 --out out/demo "$@"
fi
