#!/usr/bin/env bash
# VTK's CPU ray caster vs volwarp's marcher on the same scenes (see README.md).
#   tools/vtk-bench/run.sh [NAME...]     # venv + vtk wheel once, then the side-by-side bench
# Environment: VTK_BENCH_THREADS (2), VTK_BENCH_RUNS (5), VTK_BENCH_VENV (tools/vtk-bench/.venv),
# WAIT_QUIET=1 waits for the 1-minute load average to drop below QUIET_LOAD (1.0) first.
set -euo pipefail
HERE="$(cd "$(dirname "$0")" && pwd)"
VENV=${VTK_BENCH_VENV:-$HERE/.venv}
if [ ! -x "$VENV/bin/python" ]; then
    python3 -m venv "$VENV"
    "$VENV/bin/pip" install --quiet 'vtk>=9.3' numpy
fi
"$VENV/bin/python" -c 'import vtk; print("vtk", vtk.vtkVersion.GetVTKVersion())'
if [ "${WAIT_QUIET:-0}" = 1 ]; then
    while awk -v q="${QUIET_LOAD:-1.0}" '{exit !($1 >= q)}' /proc/loadavg; do
        echo "waiting for a quiet machine: load $(cut -d' ' -f1-3 /proc/loadavg)" >&2
        sleep 30
    done
fi
cd "$HERE/../.."
VTK_BENCH_PYTHON="$VENV/bin/python" cargo bench -p volwarp-server --bench vs_vtk -- "$@"
