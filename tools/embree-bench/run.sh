#!/usr/bin/env bash
# Embree 3 vs volwarp's packet tracer on the same scene and rays (see README.md).
#   tools/embree-bench/run.sh            # build, export, 3 alternating rounds, summary
# Environment: ROUNDS (3), RUNS per measurement (11, ≥ 7), MODES Embree trace modes (1,8,16,8i,16i),
# WAIT_QUIET=1 waits for the 1-minute load average to drop below QUIET_LOAD (0.5) first.
set -euo pipefail
cd "$(dirname "$0")"
ROUNDS=${ROUNDS:-3}
RUNS=${RUNS:-11}
MODES=${MODES:-1,8,16,8i,16i}
OUT=out
mkdir -p "$OUT"

# Embree 3 from Debian: apt-get install -y libembree-dev (3.13.5+dfsg-2 on bookworm).
test -f /usr/include/embree3/rtcore.h || { echo "install libembree-dev first" >&2; exit 1; }
cargo build --release --quiet
gcc -O2 -march=native -ffp-contract=off -std=c11 -Wall -Wextra -o embree_bench embree_bench.c -lembree3 -lpthread -lm
BIN=target/release/volwarp-embree-bench
"$BIN" export "$OUT"

if [ "${WAIT_QUIET:-0}" = 1 ]; then
    while awk -v q="${QUIET_LOAD:-0.5}" '{exit !($1 >= q)}' /proc/loadavg; do
        echo "waiting for a quiet machine: load $(cut -d' ' -f1-3 /proc/loadavg)" >&2
        sleep 30
    done
fi

RES_FILE="$OUT/results.txt"
{
    echo "# $(date -u +%FT%TZ) $(uname -r) $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2) nproc=$(nproc)"
    echo "# embree: $(dpkg-query -W -f='${Package} ${Version}' libembree3-3 2>/dev/null || echo unknown)"
    echo "# rustc: $(rustc --version); gcc: $(gcc --version | head -1); volwarp commit $(git rev-parse --short HEAD 2>/dev/null || echo '?')"
} > "$RES_FILE"
ours() { "$BIN" time "$OUT" "$RUNS"; }
embree() {
    for m in footprint voxel; do ./embree_bench "$OUT/scene_$m.bin" "$OUT/ids_$m" "$m" "$RUNS" "$MODES"; done
}
for r in $(seq 1 "$ROUNDS"); do
    echo "# round $r, load $(cut -d' ' -f1-3 /proc/loadavg)" | tee -a "$RES_FILE" >&2
    if [ $((r % 2)) = 1 ]; then ours; embree; else embree; ours; fi | sed "s/^RESULT /RESULT round=$r /" | tee -a "$RES_FILE"
done
echo "# end, load $(cut -d' ' -f1-3 /proc/loadavg)" >> "$RES_FILE"
python3 summarize.py "$RES_FILE" | tee "$OUT/summary.md"
