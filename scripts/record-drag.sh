#!/bin/sh
# Records a real mouse drag in the window client under Xvfb and keeps its camera path only:
# the bundled data/drag_ct_head.vwrec (`volwarp-eval session --scenarios record:data/drag_ct_head.vwrec`).
#
#   scripts/record-drag.sh [OUT]      (default data/drag_ct_head.vwrec)
#
# Needs Xvfb and xdotool (scripts/setup.sh installs them) and release builds of volwarp-client
# and volwarp-server in $CARGO_TARGET_DIR (default target/). The drag, as xdotool moves the
# mouse over the 512x512 window while the client draws at 60 Hz with a 300 ms server:
#   1. 1 s still, then a fast turn: 400 px right in 0.5 s (20 px every 25 ms), release, 1.5 s rest;
#   2. a short drag: 40 px left in 0.2 s, release, 1.5 s rest;
#   3. a slow turn with a tilt: 150 px right and 60 px down in 1.5 s, release, 1 s rest.
# The record file holds every displayed camera with its time; the frames (megabytes) are
# dropped by `scripts/record_cameras.py`, which keeps the magic and the camera entries.
set -eu
. "$(dirname "$0")/x11.sh"
out=${1:-data/drag_ct_head.vwrec}
target=${CARGO_TARGET_DIR:-target}
client="$target/release/volwarp-client"
export VOLWARP_SERVER="$target/release/volwarp-server"
tmp=$(mktemp -d)
trap 'kill $xvfb 2>/dev/null || true; rm -rf "$tmp"' EXIT
Xvfb :77 -screen 0 800x700x24 >/dev/null 2>&1 &
xvfb=$!
export DISPLAY=:77
sleep 1
"$client" --size 512x512 --server-delay-ms 300 --fps 60 --record "$tmp/full.vwrec" >"$tmp/log" 2>&1 &
client_pid=$!
# Wait for the window and its first frame.
wait_window "$tmp/log"
sleep 3
moves() { # n dx dy: n relative moves of (dx, dy) px, 25 ms apart
  i=0
  while [ "$i" -lt "$1" ]; do
    xdotool mousemove_relative -- "$2" "$3"
    sleep 0.025
    i=$((i + 1))
  done
}
xdotool mousemove --window "$id" 56 256
sleep 1
xdotool mousedown 1
moves 20 20 0
xdotool mouseup 1
sleep 1.5
xdotool mousedown 1
moves 8 -5 0
xdotool mouseup 1
sleep 1.5
xdotool mousedown 1
moves 60 3 1
xdotool mouseup 1
sleep 1
# Held for a while: a press and release within one display frame would not be seen.
xdotool mousemove --window "$id" 256 256 keydown Escape sleep 0.3 keyup Escape
wait "$client_pid" || { cat "$tmp/log"; exit 1; }
python3 "$(dirname "$0")/record_cameras.py" "$tmp/full.vwrec" "$out"
