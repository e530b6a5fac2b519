#!/usr/bin/env python3
"""Keeps the camera path of a record file (`volwarp-client --record`, docs/record-format.md):
the magic and the camera entries (kind 2), without the frames (kind 1, megabytes each), so that
`volwarp-eval session --scenarios record:FILE` can replay the drag from a small file. A replayed
path holds each camera until the next one, so a camera equal to the one before (the display
ticking while the view rests) is dropped, except the last entry, which keeps the path's length;
a still spell before the first motion (the window starting) is cut to its last second.

    scripts/record_cameras.py IN.vwrec OUT.vwrec
"""
import struct
import sys

MAGIC = b"VWREC\0\0\x01"
ENTRY = 12  # kind, 3 reserved, u64 time in microseconds
HEADER = 12  # wire message header: magic, version, type, reserved, u32 payload length


def main(src, dst):
    data = open(src, "rb").read()
    if data[:8] != MAGIC:
        sys.exit(f"{src}: not a record file")
    out, pos, cams, frames = bytearray(MAGIC), 8, 0, 0
    last_cam, held = None, None  # the camera bytes kept last; a dropped repeat (the last entry)
    while pos < len(data):
        if pos + ENTRY + HEADER > len(data):
            sys.exit(f"{src}: truncated entry at byte {pos}")
        kind = data[pos]
        (length,) = struct.unpack_from("<I", data, pos + ENTRY + 8)
        end = pos + ENTRY + HEADER + length
        if end > len(data):
            sys.exit(f"{src}: truncated message at byte {pos}")
        if kind == 2:
            # CameraRequest payload: u64 sequence number, then the 48-byte camera.
            cam = data[pos + ENTRY + HEADER + 8 : pos + ENTRY + HEADER + 56]
            if cam != last_cam:
                out += data[pos:end]
                cams += 1
                last_cam, held = cam, None
            else:
                held = data[pos:end]
        else:
            frames += 1
        pos = end
    if held is not None:
        out += held
        cams += 1
    # The first camera: at most one second before the second one (the first motion).
    first = 8
    if cams >= 2:
        second = first + ENTRY + HEADER + struct.unpack_from("<I", out, first + ENTRY + 8)[0]
        (t0,) = struct.unpack_from("<Q", out, first + 4)
        (t1,) = struct.unpack_from("<Q", out, second + 4)
        struct.pack_into("<Q", out, first + 4, max(t0, t1 - 1_000_000))
    open(dst, "wb").write(out)
    print(f"{dst}: {cams} cameras kept, {frames} frames dropped, {len(out)} bytes")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2])
