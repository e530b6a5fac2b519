#!/usr/bin/env bash
# The real pipeline in one command: an in-process volwarp server on the bundled CT head, and the
# client connected to it over loopback TCP. Opens a window where a display exists; headless it
# writes PNG frames of a 90° orbit (and timings.csv) into out/demo/.
# Extra arguments go to volwarp-client (see `volwarp-client --help`).
set -euo pipefail
cd "$(dirname "$0")/.."
if [ -n "${DISPLAY:-}${WAYLAND_DISPLAY:-}" ]; then
  exec cargo run --release -p volwarp-client -- "$@"
else
  echo "demo: no display found: running headless, PNG frames go to out/demo/"
  exec cargo run --release -p volwarp-client -- --headless --frames 60 --orbit 90 --size 512x512 --out out/demo "$@"
fi
