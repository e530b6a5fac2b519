// First-hit ray tracing of the volwarp sphere cloud through the core LBVH.
//
// Every step mirrors `volwarp_core` operation by operation so the image equals the CPU one:
// `RayBasis::dir` (camera.rs), `Dequantizer::center/radius` (sample.rs), `sphere::intersect`
// and `sphere::intersect_box` (sphere.rs), `Lbvh::trace` with the tie rule `closer`
// (traversal.rs) and `sample::over_background`. The only freedom a GPU keeps is fusing a multiply
// and an add into an FMA (WGSL does not forbid contraction), which can move a result by one ulp.

// Node, RayBasis, TraceParams, PackedSample and the shared functions come from `prelude.wgsl`.

@group(0) @binding(0) var<uniform> params: TraceParams;
@group(0) @binding(1) var<storage, read> nodes: array<Node>;
// Packed samples as (low word, high word) of the little-endian u64.
@group(0) @binding(2) var<storage, read> samples: array<PackedSample>;
@group(0) @binding(3) var<storage, read> colors: array<u32>;
@group(0) @binding(4) var<storage, read_write> out_pixels: array<u32>;

const STACK_SIZE: u32 = 128u;
// `volwarp_core::sphere::BOX_T_FAR_SCALE`: the conservative widening of the slab test's far bound.
const BOX_T_FAR_SCALE: f32 = 1.0000004;

fn center(s: PackedSample) -> vec3<f32> {
    return sample_center(s, params.deq_min, params.deq_step);
}

fn radius(s: PackedSample) -> f32 {
    return sample_radius(s, params.deq_step);
}

fn intersect(o: vec3<f32>, d: vec3<f32>, c: vec3<f32>, r: f32) -> f32 {
    return sphere_intersect(o, d, c, r);
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

@compute @workgroup_size(8, 8, 1)
fn trace(@builtin(global_invocation_id) gid: vec3<u32>) {
    let x = gid.x;
    let y = gid.y;
    if x >= params.width || y >= params.height {
        return;
    }
    let d = ray_dir(params.basis, x, y);
    let o = params.basis.eye.xyz;

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
