// The layered splatter on the GPU (`splat-layers-gpu`), mirroring
// `volwarp_cpu_tracer::layer_splat::LayerSplat` operation by operation (same formulas, same f32
// order), so it draws the CPU's image:
//
// 1. `setup`, one invocation per sample: its footprint (the source pixel's frustum cut by the
//    plane through the sample's centre facing the new eye, projected), as four edge functions,
//    its `(dist² bits, id)` key and pixel bounds; each pixel of its bounds whose centre passes
//    the CPU's edge test is counted.
// 2. `scan_blocks`, `scan_sums`, `scan_apply`: the pixels' counts to list offsets, in place
//    (the total too, for the host's capacity check).
// 3. `scatter`, one invocation per sample: the same pixels again, its id into each one's list
//    (order does not matter: each pixel keeps the LIST nearest keys, ties by id).
// 4. `raster`, one invocation per pixel: its list's nearest LIST keys (WGSL has no u64: keys are
//    (hi, lo) pairs), sorted, composited front to back, over the background; the pixel's count
//    and, for the fill, the covered row/column spans.
// 5. `fill`, one invocation per pixel: `hole_fill::block_outside_silhouette` + `stale_lookup`.
//
// Older frames (the multi-frame filling, `LayerSplat::render_set`) are drawn after the
// newest with P.only_empty = 1: passes 1–4 again on the older frame's samples, but only for the
// pixels that nothing drawn before covered (`open`), so each such pixel takes the first older
// frame that covers it; then the fill, once.
//
// LayerParams, PackedSample, RayBasis and the shared functions come from `prelude.wgsl`; LIST
// (the CPU's constant) and SCAN_BLOCK are prepended by `layer_splat.rs`.

@group(0) @binding(0) var<uniform> P: LayerParams;
@group(0) @binding(1) var<storage, read> samples: array<PackedSample>;
@group(0) @binding(2) var<storage, read> colors: array<u32>;
@group(0) @binding(3) var<storage, read_write> quads: array<Quad>;
// [0]: the largest list total of this submission (words 1–15 stay zero); then per pixel its
// count, turned by the scan into its list's offset and by the scatter into its list's end;
// the spans at P.off_spans, the scan's block sums at P.off_sums.
@group(0) @binding(4) var<storage, read_write> work: array<atomic<u32>>;
@group(0) @binding(5) var<storage, read_write> list: array<u32>;
@group(0) @binding(6) var<storage, read_write> out_pixels: array<u32>;
@group(0) @binding(7) var<storage, read_write> count: array<u32>;
// The frame's own composite (the fill's stale image; a dummy while the frame itself is drawn).
@group(0) @binding(8) var<storage, read> frame: array<u32>;
// Per sample its footprint's corners' shared source depths (NaN: not shared; the CPU's
// `SlabCorners`), read where P.k2.w = 1.
@group(0) @binding(9) var<storage, read> shared_z: array<vec4<f32>>;

// A footprint: edge functions (a·px + b·py + c ≥ 0 inside) as a, b, c over the four edges,
// the key's high word (dist² bits; its low word is the id), the sample's color as drawn (the
// CPU's `footprints::drawn_color`), the pixel bounds x0 | x1 << 16, y0 | y1 << 16.
struct Quad {
    a: vec4<f32>,
    b: vec4<f32>,
    c: vec4<f32>,
    key_hi: u32,
    color: u32,
    xb: u32,
    yb: u32,
}

// Where the pixels' counts start in `work`.
const COUNTS: u32 = 16u;

fn d3(a: vec3<f32>, b: vec3<f32>) -> f32 {
    // glam's `Vec3::dot`: (x·x + y·y) + z·z.
    return a.x * b.x + a.y * b.y + a.z * b.z;
}

fn finite(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u;
}

fn sample_index(wid: vec3<u32>, nwg: vec3<u32>, lidx: u32) -> u32 {
    return (wid.y * nwg.x + wid.x) * 64u + lidx;
}

// `Proj::image`: continuous image coordinates of a point given relative to the eye in the
// camera's basis; ok = false at or behind the eye plane or for a non-finite point.
struct Img {
    p: vec2<f32>,
    ok: bool,
}

fn image(c: vec3<f32>) -> Img {
    if !(c.z > P.k.z) {
        return Img(vec2<f32>(0.0), false);
    }
    let inv = 1.0 / c.z;
    let x = c.x * inv * P.proj.x + P.proj.z;
    let y = P.proj.w - c.y * inv * P.proj.y;
    return Img(vec2<f32>(x, y), finite(x) && finite(y));
}

fn none_quad() -> Quad {
    return Quad(vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0), 0xffffffffu, 0xffffffffu, 1u, 1u);
}

// The corner `(sx, sy)` on its ray at source depth `t`.
fn at(t: f32, ba: vec3<f32>, sx: f32, sy: f32) -> Img {
    let p = P.e.xyz + (ba + P.bu.xyz * sx + P.bv.xyz * sy) * t;
    return image(p);
}

// The corner on the plane facing the new eye.
fn corner(an: f32, un: f32, vn: f32, edge_on: f32, num: f32, ba: vec3<f32>, sx: f32, sy: f32) -> Img {
    let den = an + sx * un + sy * vn;
    if !(den > 0.0 && den * den > edge_on) {
        return Img(vec2<f32>(0.0), false);
    }
    return at(num / den, ba, sx, sy);
}

// The corner at its shared depth `z` where that is finite, else on the plane.
fn shared_corner(z: f32, an: f32, un: f32, vn: f32, edge_on: f32, num: f32, ba: vec3<f32>, sx: f32, sy: f32) -> Img {
    if finite(z) {
        return at(z, ba, sx, sy);
    }
    return corner(an, un, vn, edge_on, num, ba, sx, sy);
}

// Twice the area of the quadrilateral q0 q1 q2 q3 (absolute).
fn quad_area(q0: vec2<f32>, q1: vec2<f32>, q2: vec2<f32>, q3: vec2<f32>) -> f32 {
    let a = rounded((q2.x - q0.x) * (q3.y - q1.y)) - rounded((q3.x - q1.x) * (q2.y - q0.y));
    return max(a, -a);
}

// `footprints::log2_poly`, the same operations in the same order.
fn log2_poly(x: f32) -> f32 {
    let bits = bitcast<u32>(x);
    let e = i32((bits >> 23u) & 0xffu) - 127;
    let m = bitcast<f32>((bits & 0x007fffffu) | 0x3f800000u);
    let s = (m - 1.0) / (m + 1.0);
    let s2 = s * s;
    let p = s * (2.88539 + s2 * (0.9617967 + s2 * (0.577078 + s2 * (0.4121985 + s2 * 0.3205988))));
    return f32(e) + p;
}

// `footprints::exp2_poly`, the same operations in the same order.
fn exp2_poly(y_in: f32) -> f32 {
    if !(y_in >= -126.0) {
        return 0.0;
    }
    let y = min(y_in, 127.0);
    let n = floor(y);
    let f = y - n;
    let p = 1.0
        + f * (0.6931472
            + f * (0.2402265
                + f * (0.05550411 + f * (0.009618129 + f * (0.001333355 + f * (0.0001540353 + f * 0.00001525273))))));
    return p * bitcast<f32>(u32(i32(n) + 127) << 23u);
}

// `footprints::drawn_color`: color `c` with its optical depth scaled by `depth` (clamped to
// [1/limit, limit]), each channel rounded to the nearest level.
fn drawn_color(c: u32, depth: f32, limit: f32) -> u32 {
    let a8 = c >> 24u;
    if !(limit > 1.0) || depth == 1.0 || !finite(depth) || a8 == 0u || a8 == 255u {
        return c;
    }
    let d = clamp(depth, 1.0 / limit, limit);
    let a = f32(a8) * (1.0 / 255.0);
    let scale = (1.0 - exp2_poly(d * log2_poly(1.0 - a))) / a;
    var out = 0u;
    for (var k = 0u; k < 4u; k++) {
        let x = f32((c >> (8u * k)) & 0xffu);
        out |= u32(min(x * scale + 0.5, 255.0)) << (8u * k);
    }
    return out;
}

// The footprint of sample `id` (the CPU's step 1).
fn footprint(id: u32) -> Quad {
    let c = sample_center(samples[id], P.deq_min, P.deq_step);
    let rel = c - P.src_eye.xyz;
    let z = d3(rel, P.src_w.xyz);
    let n = c - P.eye.xyz;
    let dist2 = d3(n, n);
    if !(z > 0.0 && dist2 > 0.0) {
        return none_quad();
    }
    let axis = rel / z;
    let num = d3(n, rel);
    let an = d3(axis, n);
    let un = d3(P.su.xyz, n);
    let vn = d3(P.sv.xyz, n);
    let edge_on = P.k.y * dist2 * d3(axis, axis);
    let opaque = (colors[id] >> 24u) >= P.min_alpha;
    var r = 1.0;
    if opaque && P.k.x > 1.0 {
        r = P.k.x;
    }
    let ba = vec3<f32>(d3(axis, P.u.xyz), d3(axis, P.v.xyz), d3(axis, P.w.xyz));
    let c0 = corner(an, un, vn, edge_on, num, ba, -r, -r);
    let c1 = corner(an, un, vn, edge_on, num, ba, r, -r);
    let c2 = corner(an, un, vn, edge_on, num, ba, r, r);
    let c3 = corner(an, un, vn, edge_on, num, ba, -r, r);
    let plane_ok = c0.ok && c1.ok && c2.ok && c3.ok;
    var q0 = c0.p;
    var q1 = c1.p;
    var q2 = c2.p;
    var q3 = c3.p;
    // The slab's shared corners (the CPU's choice: where their footprint covers at least
    // P.k2.z of the plane's area, or the plane has none).
    var water_ok = false;
    var depth = 1.0;
    if P.k2.w == 1.0 && r == 1.0 {
        let z = shared_z[id];
        if finite(z.x) || finite(z.y) || finite(z.z) || finite(z.w) {
            let w0 = shared_corner(z.x, an, un, vn, edge_on, num, ba, -r, -r);
            let w1 = shared_corner(z.y, an, un, vn, edge_on, num, ba, r, -r);
            let w2 = shared_corner(z.z, an, un, vn, edge_on, num, ba, r, r);
            let w3 = shared_corner(z.w, an, un, vn, edge_on, num, ba, -r, r);
            if w0.ok && w1.ok && w2.ok && w3.ok {
                let aw = quad_area(w0.p, w1.p, w2.p, w3.p);
                let ap = quad_area(q0, q1, q2, q3);
                if !plane_ok || aw >= ap * P.k2.z {
                    water_ok = true;
                    // The slab's optical depth over its footprint's area (the plane's over
                    // the slab's; 1 where the plane has none).
                    if plane_ok {
                        depth = ap / aw;
                    }
                    q0 = w0.p;
                    q1 = w1.p;
                    q2 = w2.p;
                    q3 = w3.p;
                }
            }
        }
    }
    if !(plane_ok || water_ok) {
        return none_quad();
    }
    let x0 = min(min(min(q0.x, q1.x), q2.x), q3.x);
    let x1 = max(max(max(q0.x, q1.x), q2.x), q3.x);
    let y0 = min(min(min(q0.y, q1.y), q2.y), q3.y);
    let y1 = max(max(max(q0.y, q1.y), q2.y), q3.y);
    let xa = max(ceil(x0 - 0.5), 0.0);
    let xb = min(floor(x1 - 0.5), f32(P.width) - 1.0);
    let ya = max(ceil(y0 - 0.5), 0.0);
    let yb = min(floor(y1 - 0.5), f32(P.height) - 1.0);
    if !(xa <= xb && ya <= yb) {
        return none_quad();
    }
    // `Quad::edges`, signed by the orientation.
    let area = rounded((q1.x - q0.x) * (q2.y - q0.y)) - rounded((q2.x - q0.x) * (q1.y - q0.y));
    var sign = 1.0;
    if area < 0.0 {
        sign = -1.0;
    }
    var q = array<vec2<f32>, 4>(q0, q1, q2, q3);
    var ea = vec4<f32>(0.0);
    var eb = vec4<f32>(0.0);
    var ec = vec4<f32>(0.0);
    for (var k = 0u; k < 4u; k++) {
        let a = q[k];
        let b = q[(k + 1u) & 3u];
        let ex = (b.x - a.x) * sign;
        let ey = (b.y - a.y) * sign;
        ea[k] = -ey;
        eb[k] = ex;
        ec[k] = rounded(ey * a.x) - rounded(ex * a.y);
    }
    let bx = u32(xa) | (u32(xb) << 16u);
    let by = u32(ya) | (u32(yb) << 16u);
    return Quad(ea, eb, ec, bitcast<u32>(dist2), drawn_color(colors[id], depth, P.opacity_limit), bx, by);
}

@compute @workgroup_size(64)
fn setup(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lidx: u32,
) {
    let id = sample_index(wid, nwg, lidx);
    if id >= P.n {
        return;
    }
    let q = footprint(id);
    quads[id] = q;
    let x0 = q.xb & 0xffffu;
    let x1 = q.xb >> 16u;
    let y0 = q.yb & 0xffffu;
    let y1 = q.yb >> 16u;
    if x0 > x1 {
        return;
    }
    for (var y = y0; y <= y1; y++) {
        for (var x = x0; x <= x1; x++) {
            if covers(q, x, y) && open(x, y) {
                atomicAdd(&work[COUNTS + y * P.width + x], 1u);
            }
        }
    }
}

// Whether this draw may give pixel (x, y) a color: always, but for an older frame only where
// nothing drawn before covered it.
fn open(x: u32, y: u32) -> bool {
    return P.only_empty == 0u || count[y * P.width + x] == 0u;
}

// `x` itself, rounded as it stands (`as_rounded` of one value; P.deq_min.w is 0.0): the
// compiler can neither fuse it into the next operation nor reassociate across it. The edge
// functions, the areas and the coverage test round every product so: lavapipe fuses a
// product and an add into an fma otherwise, and on a sliver footprint (two corners of a
// slab's shared corners nearly one point) an edge's value is mostly rounding, so a pixel's
// coverage flipped (1 pixel of 7,680 in the older frames' test with footprints taking shared
// corners down to half the plane's area).
fn rounded(x: f32) -> f32 {
    return bitcast<f32>(bitcast<u32>(x) ^ bitcast<u32>(P.deq_min.w));
}

// The CPU's rasterization test: the pixel centre inside all four edges, `(A·px + B·py) + C`
// with both products rounded (`QuadRow::covers`).
fn covers(q: Quad, x: u32, y: u32) -> bool {
    let px = f32(x) + 0.5;
    let py = f32(y) + 0.5;
    for (var e = 0u; e < 4u; e++) {
        if !(rounded(rounded(q.a[e] * px) + rounded(q.b[e] * py)) + q.c[e] >= 0.0) {
            return false;
        }
    }
    return true;
}

// The scan of the pixels' counts, reduce-then-scan over blocks of SCAN_BLOCK counts (256
// invocations × 16 consecutive counts each): `scan_blocks` sums each block, `scan_sums` (one
// workgroup) turns the block sums into block offsets and the total, `scan_apply` writes each
// count's exclusive prefix in place. The workgroup prefix sums are `wg_exclusive_scan`
// (`scan.rs`), invocations numbered in its order (`wg_thread`).
// (SCAN_BLOCK is prepended by `layer_splat.rs`.)
const SCAN_PER: u32 = SCAN_BLOCK / 256u;

// Invocation `i`'s 16 counts of block `b`: their sum.
fn scan_partial(b: u32, i: u32) -> u32 {
    let t = P.width * P.height;
    let lo = min(b * SCAN_BLOCK + i * SCAN_PER, t);
    let hi = min(lo + SCAN_PER, t);
    var s = 0u;
    for (var k = lo; k < hi; k++) {
        s += atomicLoad(&work[COUNTS + k]);
    }
    return s;
}

// The exclusive prefix of `s` over the workgroup, and the workgroup's total.
fn scan_one(s: u32, w: Wg) -> vec2<u32> {
    let r = wg_exclusive_scan(vec4<u32>(s, 0u, 0u, 0u), w);
    return vec2<u32>(r.excl.x, r.total.x);
}

@compute @workgroup_size(256)
fn scan_blocks(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    w: Wg,
) {
    let i = wg_thread(w);
    let b = wid.y * nwg.x + wid.x;
    let total = scan_one(scan_partial(b, i), w).y;
    if i == 255u && b * SCAN_BLOCK < P.width * P.height {
        atomicStore(&work[P.off_sums + b], total);
    }
}

@compute @workgroup_size(256)
fn scan_sums(w: Wg) {
    let i = wg_thread(w);
    let blocks = (P.width * P.height + SCAN_BLOCK - 1u) / SCAN_BLOCK;
    let per = (blocks + 255u) / 256u;
    let lo = min(i * per, blocks);
    let hi = min(lo + per, blocks);
    var s = 0u;
    for (var k = lo; k < hi; k++) {
        s += atomicLoad(&work[P.off_sums + k]);
    }
    let scan = scan_one(s, w);
    var run = scan.x;
    if i == 255u {
        atomicMax(&work[0], scan.y);
    }
    for (var k = lo; k < hi; k++) {
        let c = atomicLoad(&work[P.off_sums + k]);
        atomicStore(&work[P.off_sums + k], run);
        run += c;
    }
}

@compute @workgroup_size(256)
fn scan_apply(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    w: Wg,
) {
    let i = wg_thread(w);
    let b = wid.y * nwg.x + wid.x;
    let prefix = scan_one(scan_partial(b, i), w).x;
    let t = P.width * P.height;
    if b * SCAN_BLOCK >= t {
        return;
    }
    // In place: each count becomes its pixel's first list entry (the scatter's cursor, which
    // ends at the next pixel's first entry).
    var run = atomicLoad(&work[P.off_sums + b]) + prefix;
    let lo = min(b * SCAN_BLOCK + i * SCAN_PER, t);
    let hi = min(lo + SCAN_PER, t);
    for (var k = lo; k < hi; k++) {
        let c = atomicLoad(&work[COUNTS + k]);
        atomicStore(&work[COUNTS + k], run);
        run += c;
    }
}

@compute @workgroup_size(64)
fn scatter(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lidx: u32,
) {
    let id = sample_index(wid, nwg, lidx);
    if id >= P.n {
        return;
    }
    let q = quads[id];
    let x0 = q.xb & 0xffffu;
    let x1 = q.xb >> 16u;
    let y0 = q.yb & 0xffffu;
    let y1 = q.yb >> 16u;
    if x0 > x1 {
        return;
    }
    for (var y = y0; y <= y1; y++) {
        for (var x = x0; x <= x1; x++) {
            if covers(q, x, y) && open(x, y) {
                let at = atomicAdd(&work[COUNTS + y * P.width + x], 1u);
                if at < P.cap {
                    list[at] = id;
                }
            }
        }
    }
}

// Key order: (hi, lo) as one u64.
fn less(a: vec2<u32>, b: vec2<u32>) -> bool {
    return a.x < b.x || (a.x == b.x && a.y < b.y);
}

// `sample::pack_color_f32`'s rounding of one channel.
fn quantize(v: f32) -> u32 {
    let f = v * 255.0 + 0.5;
    if f >= 255.0 {
        return 255u;
    } else if f > 0.0 {
        return u32(f);
    }
    return 0u;
}

@compute @workgroup_size(8, 8, 1)
fn raster(@builtin(global_invocation_id) gid: vec3<u32>) {
    let x = gid.x;
    let y = gid.y;
    let w = P.width;
    if x >= w || y >= P.height {
        return;
    }
    let p = y * w + x;
    if !open(x, y) {
        return;
    }
    // After the scatter each pixel's cursor is where its list ends and the next one's begins
    // (`work[COUNTS - 1]`, before the first pixel's, is a zero that is never written).
    let lo = min(atomicLoad(&work[COUNTS + p - 1u]), P.cap);
    let hi = min(atomicLoad(&work[COUNTS + p]), P.cap);
    var keys: array<vec2<u32>, LIST>;
    var n = 0u;
    for (var j = lo; j < hi; j++) {
        let id = list[j];
        let key = vec2<u32>(quads[id].key_hi, id);
        // `layer_splat::insert`: keep the LIST smallest keys.
        if n < LIST {
            keys[n] = key;
            n++;
        } else {
            var worst = vec2<u32>(0u, 0u);
            var at = 0u;
            for (var i = 0u; i < LIST; i++) {
                if !less(keys[i], worst) {
                    worst = keys[i];
                    at = i;
                }
            }
            if less(key, worst) {
                keys[at] = key;
            }
        }
    }
    count[p] = n;
    if n == 0u {
        out_pixels[p] = P.background;
        return;
    }
    // The covered row and column spans (for the fill): min as the max of the complement.
    atomicMax(&work[P.off_spans + 2u * y], ~x);
    atomicMax(&work[P.off_spans + 2u * y + 1u], x);
    atomicMax(&work[P.off_spans + 2u * P.height + 2u * x], ~y);
    atomicMax(&work[P.off_spans + 2u * P.height + 2u * x + 1u], y);
    // Sorted (insertion sort of at most LIST keys), composited front to back.
    for (var i = 1u; i < n; i++) {
        let k = keys[i];
        var j = i;
        while j > 0u && less(k, keys[j - 1u]) {
            keys[j] = keys[j - 1u];
            j--;
        }
        keys[j] = k;
    }
    var acc = vec4<f32>(0.0);
    for (var i = 0u; i < n; i++) {
        let c = quads[keys[i].y].color;
        let wgt = (1.0 - acc.w) * P.k.w;
        acc.x += wgt * f32(c & 0xffu);
        acc.y += wgt * f32((c >> 8u) & 0xffu);
        acc.z += wgt * f32((c >> 16u) & 0xffu);
        acc.w += wgt * f32(c >> 24u);
        if acc.w >= P.k2.x {
            break;
        }
    }
    let packed = quantize(acc.x) | (quantize(acc.y) << 8u) | (quantize(acc.z) << 16u) | (quantize(acc.w) << 24u);
    out_pixels[p] = over_background(packed, P.background);
}

@compute @workgroup_size(8, 8, 1)
fn fill(@builtin(global_invocation_id) gid: vec3<u32>) {
    let x = gid.x;
    let y = gid.y;
    let w = P.width;
    let h = P.height;
    if x >= w || y >= h {
        return;
    }
    let p = y * w + x;
    if count[p] != 0u {
        return;
    }
    // `block_outside_silhouette`: only pixels within the covered row and column spans.
    let rmin = ~atomicLoad(&work[P.off_spans + 2u * y]);
    let rmax = atomicLoad(&work[P.off_spans + 2u * y + 1u]);
    let cmin = ~atomicLoad(&work[P.off_spans + 2u * h + 2u * x]);
    let cmax = atomicLoad(&work[P.off_spans + 2u * h + 2u * x + 1u]);
    if !(rmin <= x && x <= rmax && cmin <= y && y <= cmax) {
        return;
    }
    // `stale_lookup`: where the pixel's ray crosses the frame's focal plane.
    let d = ray_dir(P.basis, x, y);
    let fwd = P.f_w.xyz;
    let denom = d3(d, fwd);
    let t = P.k2.y / denom;
    var q = P.f_eye.xyz + d;
    if denom > P.k.z && t > 0.0 {
        q = P.eye.xyz + d * t;
    }
    // `Projector::project`.
    let rel = q - P.f_eye.xyz;
    let z = d3(rel, fwd);
    if !(z > P.k.z) {
        return;
    }
    let sx = d3(rel, P.f_u.xyz) / (z * P.f_proj.x);
    let sy = d3(rel, P.f_v.xyz) / (z * P.f_proj.y);
    let fx = (sx + 1.0) * 0.5 * P.f_proj.z;
    let fy = (1.0 - sy) * 0.5 * P.f_proj.w;
    if fx >= 0.0 && fy >= 0.0 && fx < P.f_proj.z && fy < P.f_proj.w {
        let c = frame[u32(fy) * P.f_width + u32(fx)];
        if c != P.background {
            out_pixels[p] = c;
        }
    }
}
