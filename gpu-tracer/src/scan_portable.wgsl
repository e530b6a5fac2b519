// The workgroup-wide exclusive prefix sum, portable: Hillis–Steele over workgroup memory,
// barriers only (8 steps of two barriers for 256 invocations). Chosen where the device has no
// subgroup operations (`scan.rs`); `scan_subgroup.wgsl` defines the same three items.

// An invocation's identity in the workgroup, taken by every entry point that scans.
struct Wg {
    @builtin(local_invocation_index) lidx: u32,
}

// An exclusive prefix and the workgroup's total.
struct WgScan {
    excl: vec4<u32>,
    total: vec4<u32>,
}

// The invocation's position in the scan order (0 … 255).
fn wg_thread(w: Wg) -> u32 {
    return w.lidx;
}

var<workgroup> wg_scan_buf: array<vec4<u32>, 256>;

// Exclusive prefix sum over the workgroup's 256 invocations, in `wg_thread` order, of four
// counts at once; every invocation calls it, in uniform control flow.
fn wg_exclusive_scan(v: vec4<u32>, w: Wg) -> WgScan {
    let t = w.lidx;
    wg_scan_buf[t] = v;
    workgroupBarrier();
    for (var off = 1u; off < 256u; off <<= 1u) {
        var add = vec4<u32>(0u);
        if t >= off {
            add = wg_scan_buf[t - off];
        }
        workgroupBarrier();
        wg_scan_buf[t] += add;
        workgroupBarrier();
    }
    let r = WgScan(wg_scan_buf[t] - v, wg_scan_buf[255]);
    // The next call writes the buffer again.
    workgroupBarrier();
    return r;
}
