#!/bin/sh
# Times what a user waits for after a short drag in the window client: six drags of 40 px in
# 0.2 s over the bundled MRI at 512x512 with a 300 ms server, each released for 2.5 s, and for
# each, the seconds from the release to the server's log line of the first full-resolution frame
# it rendered and sent after it (docs/results.md, "A server that drops the render a turn makes
# stale").
#
#   scripts/drag-release.sh [SERVER] [DIR]   (default target/release/volwarp-server, out/drag-release)
#
# Needs Xvfb, xdotool and python3 (scripts/setup.sh installs them) and a release build of
# volwarp-client in $CARGO_TARGET_DIR (default target/).
set -eu
. "$(dirname "$0")/x11.sh"
root=$(cd "$(dirname "$0")/.." && pwd)
target=${CARGO_TARGET_DIR:-$root/target}
export VOLWARP_SERVER=$(realpath "${1:-$target/release/volwarp-server}")
out=${2:-$root/out/drag-release}
rm -rf "$out"
mkdir -p "$out"
Xvfb :79 -screen 0 800x700x24 >/dev/null 2>&1 &
xvfb=$!
trap 'kill $xvfb 2>/dev/null || true' EXIT
export DISPLAY=:79
sleep 1
# Every log line stamped with the wall clock as it is printed.
RUST_LOG=info "$target/release/volwarp-client" --size 512x512 --volume "$root/data/mri_colin27.nrrd" \
  --server-delay-ms 300 --fps 60 2>&1 |
  python3 -u -c 'import sys, time
for l in sys.stdin: print(f"{time.time():.3f} {l}", end="")' >"$out/log" &
wait_window "$out/log"
sleep 4
xdotool mousemove --window "$id" 256 256
sleep 1
for _ in 1 2 3 4 5 6; do
  xdotool mousedown 1
  i=0
  while [ "$i" -lt 8 ]; do
    xdotool mousemove_relative -- 5 0
    sleep 0.025
    i=$((i + 1))
  done
  xdotool mouseup 1
  date +%s.%N >>"$out/releases"
  sleep 2.5
done
xdotool mousemove --window "$id" 256 256 keydown Escape sleep 0.3 keyup Escape
sleep 2
python3 - "$out" <<'PY'
import re, statistics, sys
d = sys.argv[1]
releases = [float(l) for l in open(d + "/releases")]
sent = []
for l in open(d + "/log"):
    m = re.match(r"^(\d+\.\d+) .*frame seq \d+ 512x512 .*march ([\d.]+) ms", l)
    if m and float(m.group(2)) > 0:
        sent.append(float(m.group(1)))
waits = [min((t for t in sent if t > r), default=float("nan")) - r for r in releases]
drops = sum("dropped" in l for l in open(d + "/log"))
print("release to the full-resolution frame sent, s:", " ".join(f"{w:.2f}" for w in waits))
print(f"median {statistics.median(waits):.2f} s; renders dropped: {drops}")
PY
