// First-hit ray tracing of the volwarp sphere cloud through the core LBVH.
//
// Every step mirrors `volwarp_core` operation by operation so the image equals the CPU one:
// `RayBasis::dir` (camera.rs), `Dequantizer::center/radius` (sample.rs), `sphere::intersect`
// and `sphere::intersect_box` (sphere.rs), `Lbvh::trace` with the tie rule `closer`
// (traversal.rs) and `sample::over_background`. The only freedom a GPU keeps is fusing a multiply
// and an add into an FMA (WGSL does not forbid contraction), which can move a result by one ulp.

struct Params {
    // RayBasis, the same 64 bytes as `volwarp_core::RayBasis` (eye.w = width, corner.w = height).
    eye: vec4<f32>,
    corner: vec4<f32>,
    du: vec4<f32>,
    dv: vec4<f32>,
    // Dequantizer: min.xyz, step.xyz, radius unit in step.w.
    deq_min: vec4<f32>,
    deq_step: vec4<f32>,
    width: u32,
    height: u32,
    n: u32,
    background: u32,
}

// `volwarp_core::lbvh::Node`: 32 bytes, vec3 aligned to 16.
struct Node {
    min: vec3<f32>,
    left: u32,
    max: vec3<f32>,
    right: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> nodes: array<Node>;
// Packed samples as (low word, high word) of the little-endian u64.
@group(0) @binding(2) var<storage, read> samples: array<vec2<u32>>;
@group(0) @binding(3) var<storage, read> colors: array<u32>;
@group(0) @binding(4) var<storage, read_write> out_pixels: array<u32>;

const LEAF_BIT: u32 = 0x80000000u;
const STACK_SIZE: u32 = 128u;
// Stands in for +inf as `t_max` before the first hit: `min(t_far, F32_MAX)` equals
// `min(t_far, inf)` for every finite `t_far`.
const F32_MAX: f32 = 3.40282347e38;
// `volwarp_core::sphere::BOX_T_FAR_SCALE`: the conservative widening of the slab test's far bound.
const BOX_T_FAR_SCALE: f32 = 1.0000004;
const POS_MASK: u32 = 0x3ffffu;


fn center(s: vec2<u32>) -> vec3<f32> {
    let x = s.x & POS_MASK;
    let y = (s.x >> 18u) | ((s.y & 0xfu) << 14u);
    let z = (s.y >> 4u) & POS_MASK;
    return vec3<f32>(
        params.deq_min.x + f32(x) * params.deq_step.x,
        params.deq_min.y + f32(y) * params.deq_step.y,
        params.deq_min.z + f32(z) * params.deq_step.z,
    );
}

fn radius(s: vec2<u32>) -> f32 {
    return f32(s.y >> 22u) * params.deq_step.w;
}

// `sphere::intersect`: the nearest t > 0, or -1 for a miss (valid hits are > 0).
fn intersect(o: vec3<f32>, d: vec3<f32>, c: vec3<f32>, r: f32) -> f32 {
    let ocx = c.x - o.x;
    let ocy = c.y - o.y;
    let ocz = c.z - o.z;
    let b = ocx * d.x + ocy * d.y + ocz * d.z;
    let fx = ocx - b * d.x;
    let fy = ocy - b * d.y;
    let fz = ocz - b * d.z;
    let disc = r * r - (fx * fx + fy * fy + fz * fz);
    if !(disc >= 0.0) {
        return -1.0;
    }
    let s = sqrt(disc);
    let t0 = b - s;
    let t1 = b + s;
    if t0 > 0.0 {
        return t0;
    } else if t1 > 0.0 {
        return t1;
    }
    return -1.0;
}

// `sphere::intersect_box`: whether the ray enters the box before `t_max` (entry t in `.y`).
fn intersect_box(o: vec3<f32>, inv: vec3<f32>, bmin: vec3<f32>, bmax: vec3<f32>, t_max: f32) -> vec2<f32> {
    let tx1 = (bmin.x - o.x) * inv.x;
    let tx2 = (bmax.x - o.x) * inv.x;
    let ty1 = (bmin.y - o.y) * inv.y;
    let ty2 = (bmax.y - o.y) * inv.y;
    let tz1 = (bmin.z - o.z) * inv.z;
    let tz2 = (bmax.z - o.z) * inv.z;
    let t_near = max(max(max(min(tx1, tx2), min(ty1, ty2)), min(tz1, tz2)), 0.0);
    // Core scales both far bounds by BOX_T_FAR_SCALE and takes their minimum; scaling the
    // minimum is the same number (rounding is monotonic) and cannot overflow F32_MAX first.
    let t_far = min(min(min(max(tx1, tx2), max(ty1, ty2)), max(tz1, tz2)), t_max) * BOX_T_FAR_SCALE;
    if t_near <= t_far {
        return vec2<f32>(1.0, t_near);
    }
    return vec2<f32>(0.0, 0.0);
}

// `sample::over_background`, integer for integer.
fn over_background(c: u32, bg: u32) -> u32 {
    let k = 255u - (c >> 24u);
    var out = 0xff000000u;
    for (var i = 0u; i < 3u; i++) {
        let s = (c >> (8u * i)) & 0xffu;
        let d = (bg >> (8u * i)) & 0xffu;
        out |= min(s + (k * d + 127u) / 255u, 255u) << (8u * i);
    }
    return out;
}

@compute @workgroup_size(8, 8, 1)
fn trace(@builtin(global_invocation_id) gid: vec3<u32>) {
    let x = gid.x;
    let y = gid.y;
    if x >= params.width || y >= params.height {
        return;
    }
    // `RayBasis::dir`: corner + du*px, then + dv*py, normalized by 1 / sqrt(d·d).
    let px = f32(x) + 0.5;
    let py = f32(y) + 0.5;
    let dx = params.corner.x + params.du.x * px + params.dv.x * py;
    let dy = params.corner.y + params.du.y * px + params.dv.y * py;
    let dz = params.corner.z + params.du.z * px + params.dv.z * py;
    let inv_len = 1.0 / sqrt(dx * dx + dy * dy + dz * dz);
    let d = vec3<f32>(dx * inv_len, dy * inv_len, dz * inv_len);
    let o = params.eye.xyz;

    let n = params.n;
    var best_t = F32_MAX;
    var best_prim = 0xffffffffu;
    var hit = false;

    if n == 1u {
        let s = samples[0];
        let t = intersect(o, d, center(s), radius(s));
        if t > 0.0 {
            hit = true;
            best_t = t;
            best_prim = 0u;
        }
    } else if n > 1u {
        let inv = vec3<f32>(1.0 / d.x, 1.0 / d.y, 1.0 / d.z);
        let root = nodes[0];
        if intersect_box(o, inv, root.min, root.max, F32_MAX).x > 0.0 {
            var stack: array<u32, STACK_SIZE>;
            var sp = 1u;
            stack[0] = 0u;
            // For a valid tree every internal node is popped at most once: the bound only
            // keeps a corrupt tree from hanging the GPU.
            var budget = n;
            while sp > 0u && budget > 0u {
                budget -= 1u;
                sp -= 1u;
                let node = nodes[stack[sp]];
                // Children in order (left, right), as `Lbvh::trace` visits them; leaves are
                // tested at once, internal children kept for the ordered push below.
                var c0 = 0u;
                var t0 = 0.0;
                var c1 = 0u;
                var t1 = 0.0;
                var m = 0u;
                for (var ci = 0u; ci < 2u; ci++) {
                    let child = select(node.right, node.left, ci == 0u);
                    if (child & LEAF_BIT) != 0u {
                        let k = child & ~LEAF_BIT;
                        let s = samples[k];
                        let t = intersect(o, d, center(s), radius(s));
                        // The tie rule `closer`: nearer, or equally near with a smaller index.
                        if t > 0.0 && (!hit || t < best_t || (t == best_t && k < best_prim)) {
                            hit = true;
                            best_t = t;
                            best_prim = k;
                        }
                    } else {
                        let c = nodes[child];
                        let t_max = select(F32_MAX, best_t, hit);
                        let bh = intersect_box(o, inv, c.min, c.max, t_max);
                        if bh.x > 0.0 {
                            if m == 0u {
                                c0 = child;
                                t0 = bh.y;
                            } else {
                                c1 = child;
                                t1 = bh.y;
                            }
                            m += 1u;
                        }
                    }
                }
                // Far first, so the near child is popped first (ties: the first child is near).
                if m == 2u {
                    let far_first = select(c1, c0, t1 < t0);
                    let near_second = select(c0, c1, t1 < t0);
                    if sp < STACK_SIZE {
                        stack[sp] = far_first;
                        sp += 1u;
                    }
                    if sp < STACK_SIZE {
                        stack[sp] = near_second;
                        sp += 1u;
                    }
                } else if m == 1u && sp < STACK_SIZE {
                    stack[sp] = c0;
                    sp += 1u;
                }
            }
        }
    }

    var pixel = params.background;
    if hit {
        pixel = over_background(colors[best_prim], params.background);
    }
    out_pixels[y * params.width + x] = pixel;
}
