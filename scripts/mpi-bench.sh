#!/usr/bin/env bash
# The server across MPI ranks: per-frame times and bytes per rank of `dump` (one timed frame per
# launch, the median over RUNS launches), beside the one-process server's frame.
#
#   scripts/mpi-bench.sh VOLUME [SIZE=1024x1024] [LAYERS=4] [RUNS=3] [RANKS="2 4 8"] [FRAMES=1]
#
# FRAMES > 1 renders the frame that many times per launch and times the last (`dump --frames`):
# the steady state of a serving server, whose buffers' memory was touched by earlier frames.
#
# Needs a release build with the feature: cargo build --release -p volwarp-server --features mpi
# Prints a Markdown table (times in ms; bytes sent per rank per frame, the largest). The frame is
# everything up to the encoded message but the encoding (which both servers do alike): for one
# process the march and the compaction, for N ranks the broadcast, the slowest rank's march, the
# band exchange, the merge (with each band's samples assembled by its owner), the gather (with
# rank 0 joining the bands' samples) and what rank 0 does after (the header: the assembly
# column). The compositing share is what of that is not the slowest march.
set -euo pipefail
cd "$(dirname "$0")/.."
vol=$1
size=${2:-1024x1024}
layers=${3:-4}
runs=${4:-3}
ranks=${5:-"2 4 8"}
frames=${6:-1}
bin="${CARGO_TARGET_DIR:-target}/release/volwarp-server"
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
median() { sort -g | awk '{a[NR]=$1} END {print (NR % 2) ? a[(NR+1)/2] : (a[NR/2] + a[NR/2+1]) / 2}'; }
field() { grep -o "$1=[0-9.]*" | cut -d= -f2; }

echo "| ranks | frame | march (slowest rank) | march (fastest rank) | exchange | merge | gather | assembly | compositing share | encode | bytes sent per rank (max) |"
echo "|---|---|---|---|---|---|---|---|---|---|---|"
for _ in $(seq "$runs"); do
  RUST_LOG=info "$bin" dump --volume "$vol" --size "$size" --layers "$layers" --encoding compact --frames "$frames" --out "$out/one.vwf" 2>&1 |
    grep -o "march [0-9.]* ms, compact [0-9.]* ms" | tail -n 1 | awk '{print $2 + $5}'
done | median | awk '{printf "| 1 process (packet marcher) | %.0f | | | | | | | | | |\n", $1}'
for n in $ranks; do
  for _ in $(seq "$runs"); do
    RUST_LOG=info mpiexec -n "$n" "$bin" dump --volume "$vol" --size "$size" --layers "$layers" \
      --encoding compact --frames "$frames" --out "$out/mpi.vwf" > "$out/log" 2>&1
    line=$(grep "mpi frame .*ranks=" "$out/log" | tail -n 1)
    asm=$(grep "assembly_ms" "$out/log")
    echo "$(echo "$line" | field total_ms) $(echo "$line" | field march_max_ms) $(echo "$line" | field march_min_ms)" \
      "$(echo "$line" | field exchange_ms) $(echo "$line" | field merge_ms) $(echo "$line" | field gather_ms)" \
      "$(echo "$asm" | field assembly_ms) $(echo "$asm" | field encode_ms) $(echo "$line" | field bytes_per_rank_max)"
  done > "$out/runs"
  cols=()
  for c in 1 2 3 4 5 6 7 8 9; do cols+=("$(awk -v c=$c '{print $c}' "$out/runs" | median)"); done
  awk -v n="$n" -v t="${cols[0]}" -v mx="${cols[1]}" -v mn="${cols[2]}" -v ex="${cols[3]}" -v me="${cols[4]}" \
    -v ga="${cols[5]}" -v as="${cols[6]}" -v en="${cols[7]}" -v by="${cols[8]}" 'BEGIN {
      frame = t + as
      printf "| %d | %.0f | %.0f | %.0f | %.1f | %.1f | %.1f | %.1f | %.1f %% | %.1f | %.2f MB |\n",
        n, frame, mx, mn, ex, me, ga, as, 100 * (frame - mx) / frame, en, by / 1e6 }'
done
