#!/usr/bin/env bash
# The real client, headless over loopback, against the server on 3 MPI ranks: it must receive
# and draw frames. Usage: scripts/mpi-client.sh SERVER_BIN CLIENT_BIN
set -euo pipefail
cd "$(dirname "$0")/.."
server=$1
client=$2
dir=$(mktemp -d)
log="$dir/server.log"
mpiexec -n 3 "$server" --volume data/neghip_64x64x64_uint8.raw --listen 127.0.0.1:0 --rank-timeout 60 \
  > "$dir/addr" 2> "$log" &
pid=$!
cleanup() { kill "$pid" 2>/dev/null || true; wait "$pid" 2>/dev/null || true; rm -rf "$dir"; }
trap cleanup EXIT
for _ in $(seq 300); do
  grep -q "listening on" "$dir/addr" 2>/dev/null && break
  sleep 0.1
done
addr=$(sed -n 's/^listening on //p' "$dir/addr")
[ -n "$addr" ] || { cat "$log"; echo "mpi-client: the server did not start"; exit 1; }
"$client" --connect "$addr" --no-reconnect --headless --frames 10 --orbit 30 --size 256x256 --out "$dir/frames"
n=$(ls "$dir/frames"/frame_*.png | wc -l)
[ "$n" -ge 10 ] || { echo "mpi-client: $n frames written"; exit 1; }
# 256² at rest, 128² (adaptive resolution's coarse grid) while the orbit moves.
grep -qE "mpi frame (256x256|128x128) " "$log" || { cat "$log"; echo "mpi-client: no frame composited on the ranks"; exit 1; }
echo "mpi-client: $n frames drawn from 3 ranks"
