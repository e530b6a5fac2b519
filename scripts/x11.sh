# Sourced by the scripts that drive the window client under Xvfb (record-drag.sh,
# drag-release.sh).

# wait_window LOG: sets $id to the volwarp window's id once it is open (up to 30 s), or prints
# LOG and fails.
wait_window() {
  id=
  for _ in $(seq 60); do
    id=$(xdotool search --name '^volwarp' 2>/dev/null | head -n 1 || true)
    [ -n "$id" ] && break
    sleep 0.5
  done
  [ -n "$id" ] || { cat "$1"; echo "no volwarp window" >&2; exit 1; }
}
