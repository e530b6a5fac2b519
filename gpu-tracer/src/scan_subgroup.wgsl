// The workgroup-wide exclusive prefix sum with subgroup operations: an inclusive scan inside
// each subgroup (`subgroupInclusiveAdd`), each subgroup's total through workgroup memory, and
// every invocation adding the totals of the subgroups before its own — two barriers instead of
// the portable scan's sixteen. Chosen where the device has `Features::SUBGROUP` (`scan.rs`);
// `scan_portable.wgsl` defines the same three items.
//
// The scan order is (subgroup, lane), not `local_invocation_index`: no API promises how
// invocations are grouped into subgroups, so every entry point that scans uses `wg_thread` as
// its invocation's index. That is a permutation of 0 … 255 as long as the 256 invocations form
// full subgroups, which they do on every implementation (a subgroup size is a power of two that
// divides 256).

// An invocation's identity in the workgroup, taken by every entry point that scans.
struct Wg {
    @builtin(subgroup_id) sg: u32,
    @builtin(subgroup_size) size: u32,
    @builtin(subgroup_invocation_id) lane: u32,
}

// An exclusive prefix and the workgroup's total.
struct WgScan {
    excl: vec4<u32>,
    total: vec4<u32>,
}

// The invocation's position in the scan order (0 … 255).
fn wg_thread(w: Wg) -> u32 {
    return w.sg * w.size + w.lane;
}

// One total per subgroup (subgroups have at least 4 invocations).
var<workgroup> wg_scan_sg: array<vec4<u32>, 64>;

// Exclusive prefix sum over the workgroup's 256 invocations, in `wg_thread` order, of four
// counts at once; every invocation calls it, in uniform control flow.
fn wg_exclusive_scan(v: vec4<u32>, w: Wg) -> WgScan {
    let incl = subgroupInclusiveAdd(v);
    if w.lane == w.size - 1u {
        wg_scan_sg[w.sg] = incl;
    }
    workgroupBarrier();
    var before = vec4<u32>(0u);
    var total = vec4<u32>(0u);
    let groups = 256u / w.size;
    for (var s = 0u; s < groups; s++) {
        let x = wg_scan_sg[s];
        before += select(vec4<u32>(0u), x, s < w.sg);
        total += x;
    }
    // The next call writes the totals again.
    workgroupBarrier();
    return WgScan(incl - v + before, total);
}
