// The LBVH build on the GPU, step for step the one of `volwarp_core::lbvh::build`:
//
// 1. `make_keys`: Morton code of each packed sample (all 54 bits, as two u32 words) and its
//    index, laid out exactly like `volwarp_core::morton::SortKey` (code lo, code hi, index, 0);
// 2. a stable LSD radix sort over 7 passes of 8 bits, reduce-then-scan (`radix_upsweep`,
//    `scan_blocks`/`scan_add`, `radix_downsweep`), so keys end up ordered by (code, index),
//    exactly the CPU order;
// 3. `reorder`: samples and colors into leaf order;
// 4. `karras`: children and parent links of every internal node (Karras 2012), the same
//    δ with the index tie-break as `lbvh::karras_node`;
// 5. `fit`: bottom-up boxes, one thread per leaf, the second arrival at a node fits it
//    (`lbvh::fit_from_leaf`), counted with atomics.
//
// 1-D kernels may be dispatched as a 2-D grid (to stay under the 65535 workgroups-per-dimension
// limit); `linear_id` folds it back.

// Node, BuildParams, PackedSample and the shared functions come from `prelude.wgsl`.

@group(0) @binding(0) var<uniform> P: BuildParams;
@group(0) @binding(1) var<storage, read> samples_in: array<PackedSample>;
@group(0) @binding(2) var<storage, read> colors_in: array<u32>;
@group(0) @binding(3) var<storage, read> keys_src: array<vec4<u32>>;
@group(0) @binding(4) var<storage, read_write> keys_dst: array<vec4<u32>>;
@group(0) @binding(5) var<storage, read_write> hist: array<u32>;
@group(0) @binding(6) var<storage, read_write> scan_data: array<u32>;
@group(0) @binding(7) var<storage, read_write> scan_sums: array<u32>;
@group(0) @binding(8) var<storage, read_write> samples_out: array<PackedSample>;
@group(0) @binding(9) var<storage, read_write> colors_out: array<u32>;
@group(0) @binding(10) var<storage, read_write> nodes: array<Node>;
@group(0) @binding(11) var<storage, read_write> parents: array<u32>;
@group(0) @binding(12) var<storage, read_write> flags: array<atomic<u32>>;
// Fitted boxes, 6 words per node (min.xyz, max.xyz as f32 bits + 1), cleared to 0 before the
// fit and read and written only with atomics. WGSL atomics are relaxed (no release/acquire),
// so seeing a sibling's arrival count does not order its box stores before our loads; instead
// a reader waits for each word to leave 0, which no finite float's bits + 1 can be. Per-location
// coherence then guarantees it reads the one value stored there.
@group(0) @binding(13) var<storage, read_write> boxes: array<atomic<u32>>;

const NO_PARENT: u32 = 0xffffffffu;
// The radix sort's workgroups: 256 invocations × 4 keys = a block of 1024 keys.
const SORT_WG: u32 = 256u;
const SORT_ITEMS: u32 = 4u;
const SORT_BLOCK: u32 = 1024u;
const BUCKETS: u32 = 256u;
const SCAN_ITEMS: u32 = 8u;
const SCAN_BLOCK: u32 = 2048u;

fn linear_id(wid: vec3<u32>, nwg: vec3<u32>, lidx: u32, wg_size: u32) -> u32 {
    return (wid.y * nwg.x + wid.x) * wg_size + lidx;
}

// ---- 1. Morton keys --------------------------------------------------------------------------

fn coords(s: PackedSample) -> vec3<u32> {
    return sample_coords(s);
}

@compute @workgroup_size(64)
fn make_keys(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lidx: u32,
) {
    let i = linear_id(wid, nwg, lidx, 64u);
    if i >= P.n {
        return;
    }
    var q = coords(samples_in[i]);
    // Bit b of axis a goes to code bit 3b + a (`morton::encode`), 54 bits over two words.
    var lo = 0u;
    var hi = 0u;
    for (var b = 0u; b < 18u; b++) {
        for (var a = 0u; a < 3u; a++) {
            let bit = (q[a] >> b) & 1u;
            let pos = 3u * b + a;
            if pos < 32u {
                lo |= bit << pos;
            } else {
                hi |= bit << (pos - 32u);
            }
        }
    }
    keys_dst[i] = vec4<u32>(lo, hi, i, 0u);
}

// ---- 2. radix sort: reduce-then-scan, 8-bit digits ---------------------------------------------
//
// Per pass (8 bits of the code, 7 passes): `radix_upsweep` counts each block's digits in a
// workgroup-shared histogram and stores column `block` of the digit-major histogram
// (`hist[digit * blocks + block]`); a device-wide exclusive scan (`scan_blocks`/`scan_add`)
// turns it into every (digit, block)'s first output position; `radix_downsweep` sorts its block
// locally and stably by the digit (four 2-bit splits, each a workgroup-wide prefix sum in shared
// memory: portable, no subgroup operations) and scatters each key to its digit's position plus
// its rank among the block's keys of that digit. Stable, so keys end up ordered by
// (code, index), the CPU's order. Every workgroup prefix sum is `wg_exclusive_scan` (`scan.rs`:
// subgroup operations where the device has them, workgroup memory and barriers where not), and
// invocations are numbered by `wg_thread` (the scan's order).

fn digit(k: vec4<u32>, shift: u32) -> u32 {
    var v: u32;
    if shift == 0u {
        v = k.x;
    } else if shift < 32u {
        v = (k.x >> shift) | (k.y << (32u - shift));
    } else {
        v = k.y >> (shift - 32u);
    }
    return v & (BUCKETS - 1u);
}

// The block's digit counts (both kernels); in `radix_downsweep` only the keys that exist.
var<workgroup> wg_hist: array<atomic<u32>, 256>;
// The digit of each slot of the block, and the block's slots in their (partly) sorted order.
var<workgroup> wg_digit: array<u32, 1024>;
var<workgroup> wg_order: array<u32, 1024>;
// Each digit's first local position, and its first global position.
var<workgroup> wg_start: array<u32, 256>;
var<workgroup> wg_base: array<u32, 256>;

@compute @workgroup_size(256)
fn radix_upsweep(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lidx: u32,
) {
    let block = wid.y * nwg.x + wid.x;
    atomicStore(&wg_hist[lidx], 0u);
    workgroupBarrier();
    let live = block < P.blocks;
    if live {
        let base = block * SORT_BLOCK;
        for (var j = 0u; j < SORT_ITEMS; j++) {
            let i = base + j * SORT_WG + lidx;
            if i < P.n {
                atomicAdd(&wg_hist[digit(keys_src[i], P.shift)], 1u);
            }
        }
    }
    workgroupBarrier();
    if live {
        hist[lidx * P.blocks + block] = atomicLoad(&wg_hist[lidx]);
    }
}

@compute @workgroup_size(256)
fn radix_downsweep(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    w: Wg,
) {
    let lidx = wg_thread(w);
    let block = wid.y * nwg.x + wid.x;
    let live = block < P.blocks;
    let base = block * SORT_BLOCK;
    atomicStore(&wg_hist[lidx], 0u);
    workgroupBarrier();
    // Invocation `lidx` owns slots 4·lidx … 4·lidx + 3. Slots past the end get digit 255: being
    // the last slots, a stable sort keeps them after every real key.
    for (var j = 0u; j < SORT_ITEMS; j++) {
        let slot = lidx * SORT_ITEMS + j;
        let i = base + slot;
        var d = BUCKETS - 1u;
        if live && i < P.n {
            d = digit(keys_src[i], P.shift);
            atomicAdd(&wg_hist[d], 1u);
        }
        wg_digit[slot] = d;
        wg_order[slot] = slot;
    }
    workgroupBarrier();
    // Four stable splits by 2 bits of the digit, least significant first (a local LSD sort).
    for (var r = 0u; r < 8u; r += 2u) {
        var mine: array<u32, 4>;
        var bits: array<u32, 4>;
        var count = vec4<u32>(0u);
        for (var j = 0u; j < SORT_ITEMS; j++) {
            let slot = wg_order[lidx * SORT_ITEMS + j];
            let b = (wg_digit[slot] >> r) & 3u;
            mine[j] = slot;
            bits[j] = b;
            count[b] += 1u;
        }
        let scan = wg_exclusive_scan(count, w);
        let total = scan.total;
        var pos = scan.excl + vec4<u32>(0u, total.x, total.x + total.y, total.x + total.y + total.z);
        // Everyone has read `wg_order` before it is overwritten (the scan ends with a barrier).
        for (var j = 0u; j < SORT_ITEMS; j++) {
            let b = bits[j];
            wg_order[pos[b]] = mine[j];
            pos[b] += 1u;
        }
        workgroupBarrier();
    }
    // Each digit's first local position: an exclusive scan of the block's digit counts.
    let c = atomicLoad(&wg_hist[lidx]);
    wg_start[lidx] = wg_exclusive_scan(vec4<u32>(c, 0u, 0u, 0u), w).excl.x;
    if live {
        wg_base[lidx] = hist[lidx * P.blocks + block];
    }
    workgroupBarrier();
    // Scatter, neighbouring invocations taking neighbouring positions.
    for (var j = 0u; j < SORT_ITEMS; j++) {
        let p = j * SORT_WG + lidx;
        let slot = wg_order[p];
        let i = base + slot;
        if live && i < P.n {
            let d = wg_digit[slot];
            keys_dst[wg_base[d] + p - wg_start[d]] = keys_src[i];
        }
    }
}

// Exclusive prefix sum of each block of `SCAN_BLOCK` (2048) values of `scan_data` (the first
// `P.count`), in place: each of 256 invocations sums 8 consecutive values serially, a
// workgroup scan combines the 256 partial sums. The block's total goes to `scan_sums[block]`.
@compute @workgroup_size(256)
fn scan_blocks(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    w: Wg,
) {
    let lidx = wg_thread(w);
    let block = wid.y * nwg.x + wid.x;
    let base = block * SCAN_BLOCK + lidx * SCAN_ITEMS;
    var sum = 0u;
    for (var k = 0u; k < SCAN_ITEMS; k++) {
        if base + k < P.count {
            sum += scan_data[base + k];
        }
    }
    let scan = wg_exclusive_scan(vec4<u32>(sum, 0u, 0u, 0u), w);
    var run = scan.excl.x;
    for (var k = 0u; k < SCAN_ITEMS; k++) {
        if base + k < P.count {
            let v = scan_data[base + k];
            scan_data[base + k] = run;
            run += v;
        }
    }
    let blocks = (P.count + SCAN_BLOCK - 1u) / SCAN_BLOCK;
    if lidx == 255u && block < blocks {
        scan_sums[block] = scan.total.x;
    }
}

// Adds each block's offset (the scanned block totals) to its values.
@compute @workgroup_size(256)
fn scan_add(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lidx: u32,
) {
    let i = linear_id(wid, nwg, lidx, 256u);
    if i < P.count {
        scan_data[i] += scan_sums[i / SCAN_BLOCK];
    }
}

// ---- 3. samples and colors into leaf order ---------------------------------------------------

@compute @workgroup_size(64)
fn reorder(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lidx: u32,
) {
    let k = linear_id(wid, nwg, lidx, 64u);
    if k >= P.n {
        return;
    }
    let src = keys_src[k].z;
    samples_out[k] = samples_in[src];
    colors_out[k] = colors_in[src];
}

// ---- 4. Karras hierarchy ---------------------------------------------------------------------

// δ(i, j): common prefix length of keys i and j (64-bit codes), 64 + clz(i ^ j) on equal codes,
// -1 outside 0..n.
fn delta(i: i32, j: i32) -> i32 {
    if j < 0 || j >= i32(P.n) {
        return -1;
    }
    let a = keys_src[i].xy;
    let b = keys_src[j].xy;
    if a.x == b.x && a.y == b.y {
        return 64 + i32(countLeadingZeros(u32(i) ^ u32(j)));
    }
    if a.y != b.y {
        return i32(countLeadingZeros(a.y ^ b.y));
    }
    return 32 + i32(countLeadingZeros(a.x ^ b.x));
}

fn parent_slot(child: u32) -> u32 {
    if (child & LEAF_BIT) != 0u {
        return P.n - 1u + (child & ~LEAF_BIT);
    }
    return child;
}

@compute @workgroup_size(64)
fn karras(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lidx: u32,
) {
    let iu = linear_id(wid, nwg, lidx, 64u);
    if iu + 1u >= P.n {
        return;
    }
    let i = i32(iu);
    var d = -1;
    if delta(i, i + 1) - delta(i, i - 1) >= 0 {
        d = 1;
    }
    let d_min = delta(i, i - d);
    var l_max = 2;
    while delta(i, i + l_max * d) > d_min {
        l_max *= 2;
    }
    var l = 0;
    var t = l_max / 2;
    while t >= 1 {
        if delta(i, i + (l + t) * d) > d_min {
            l += t;
        }
        t /= 2;
    }
    let j = i + l * d;
    let d_node = delta(i, j);
    var s = 0;
    var div = 2;
    loop {
        let tt = (l + div - 1) / div;
        if delta(i, i + (s + tt) * d) > d_node {
            s += tt;
        }
        if tt <= 1 {
            break;
        }
        div *= 2;
    }
    let gamma = i + s * d + min(d, 0);
    var left = u32(gamma);
    if min(i, j) == gamma {
        left |= LEAF_BIT;
    }
    var right = u32(gamma + 1);
    if max(i, j) == gamma + 1 {
        right |= LEAF_BIT;
    }
    nodes[iu].left = left;
    nodes[iu].right = right;
    parents[parent_slot(left)] = iu;
    parents[parent_slot(right)] = iu;
    if iu == 0u {
        parents[0] = NO_PARENT;
    }
}

// ---- 5. bottom-up fit ------------------------------------------------------------------------

fn center(s: PackedSample) -> vec3<f32> {
    return sample_center(s, P.deq_min, P.deq_step);
}

fn rounded(v: vec3<f32>) -> vec3<f32> {
    return as_rounded(v, bitcast<u32>(P.deq_min.w));
}

struct Box {
    lo: vec3<f32>,
    hi: vec3<f32>,
}

// `sphere::sphere_box`: [c − r, c + r] widened by a relative 2⁻²⁰, each step rounded as the
// CPU rounds it: `rounded` keeps the compiler from fusing the radius's product into the sums
// (NVIDIA's does) or reassociating them.
fn leaf_box(k: u32) -> Box {
    let s = samples_out[k];
    let c = center(s);
    let r = rounded(vec3<f32>(sample_radius(s, P.deq_step))).x;
    let k20 = 1.0 / 1048576.0;
    let pad = rounded(abs(c) + vec3<f32>(r)) * k20;
    return Box(rounded(c - vec3<f32>(r)) - pad, rounded(c + vec3<f32>(r)) + pad);
}

fn child_box(child: u32) -> Box {
    if (child & LEAF_BIT) != 0u {
        return leaf_box(child & ~LEAF_BIT);
    }
    let b = child * 6u;
    return Box(
        vec3<f32>(load_box_word(b), load_box_word(b + 1u), load_box_word(b + 2u)),
        vec3<f32>(load_box_word(b + 3u), load_box_word(b + 4u), load_box_word(b + 5u)),
    );
}

// Waits (boundedly) until word i of `boxes` has been stored, then decodes it.
fn load_box_word(i: u32) -> f32 {
    var v = atomicLoad(&boxes[i]);
    for (var spin = 0u; v == 0u && spin < 1000000u; spin++) {
        v = atomicLoad(&boxes[i]);
    }
    return bitcast<f32>(v - 1u);
}

fn store_box_word(i: u32, f: f32) {
    atomicStore(&boxes[i], bitcast<u32>(f) + 1u);
}

@compute @workgroup_size(64)
fn fit(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lidx: u32,
) {
    let k = linear_id(wid, nwg, lidx, 64u);
    if k >= P.n {
        return;
    }
    var p = parents[P.n - 1u + k];
    // At most one walk per level; the bound only guards against a corrupt tree.
    for (var guard = 0u; guard < 256u; guard++) {
        if p == NO_PARENT {
            return;
        }
        if atomicAdd(&flags[p], 1u) == 0u {
            return; // first arrival: the sibling's walk fits this node
        }
        let a = child_box(nodes[p].left);
        let b = child_box(nodes[p].right);
        let lo = min(a.lo, b.lo);
        let hi = max(a.hi, b.hi);
        let o = p * 6u;
        store_box_word(o, lo.x);
        store_box_word(o + 1u, lo.y);
        store_box_word(o + 2u, lo.z);
        store_box_word(o + 3u, hi.x);
        store_box_word(o + 4u, hi.y);
        store_box_word(o + 5u, hi.z);
        nodes[p].min = lo;
        nodes[p].max = hi;
        p = parents[p];
    }
}
