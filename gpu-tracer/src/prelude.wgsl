// The shared prelude of every volwarp shader: the ONE WGSL definition of each layout the GPU
// shares with Rust, prepended to `trace.wgsl`, `lbvh.wgsl` and `splat.wgsl` at pipeline
// creation (`layout::shader`). `layout.rs` checks every struct here, field by field, against
// its Rust `#[repr(C)]` twin (sizes and offsets, by WGSL's own layout rules).

// `volwarp_core::lbvh::Node`: 32 bytes, vec3 aligned to 16.
struct Node {
    min: vec3<f32>,
    left: u32,
    max: vec3<f32>,
    right: u32,
}

// `volwarp_core::RayBasis`, 64 bytes (eye.w = width, corner.w = height).
struct RayBasis {
    eye: vec4<f32>,
    corner: vec4<f32>,
    du: vec4<f32>,
    dv: vec4<f32>,
}

// A packed sample (`volwarp_core::sample`, a little-endian u64) as (low word, high word): no
// SHADER_INT64 needed. 18-bit x, y, z, then the 10-bit radius code.
alias PackedSample = vec2<u32>;

// `tracer::TraceParams`: the trace (and splat) uniform.
struct TraceParams {
    basis: RayBasis,
    // Dequantizer: min.xyz (w = 0.0, see sample_center), step.xyz, radius unit in step.w.
    deq_min: vec4<f32>,
    deq_step: vec4<f32>,
    width: u32,
    height: u32,
    n: u32,
    background: u32,
}

// `lbvh::BuildParams`: the LBVH build's uniform.
struct BuildParams {
    n: u32,
    shift: u32,
    // Radix blocks (workgroups of the sort, 1024 keys each).
    blocks: u32,
    count: u32,
    deq_min: vec4<f32>,
    deq_step: vec4<f32>,
}

// `splat::SplatParams`: the splatter's uniform: the trace parameters, then the camera basis
// and the per-axis pixel scale of the screen-space bound.
struct SplatParams {
    trace: TraceParams,
    // Camera right, up, forward (w unused).
    u: vec4<f32>,
    v: vec4<f32>,
    w: vec4<f32>,
    // Pixels per unit slope along x and y, half width, half height.
    px: vec4<f32>,
    // 0: depth pass, 1: id pass.
    mode: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

const LEAF_BIT: u32 = 0x80000000u;
const POS_MASK: u32 = 0x3ffffu;
const NO_HIT: u32 = 0xffffffffu;
// Stands in for +inf as `t_max` before the first hit: `min(t_far, F32_MAX)` equals
// `min(t_far, inf)` for every finite `t_far`.
const F32_MAX: f32 = 3.40282347e38;

// The quantized coordinates of a packed sample.
fn sample_coords(s: PackedSample) -> vec3<u32> {
    let x = s.x & POS_MASK;
    let y = (s.x >> 18u) | ((s.y & 0xfu) << 14u);
    let z = (s.y >> 4u) & POS_MASK;
    return vec3<u32>(x, y, z);
}

// `Dequantizer::center`: min + q·step per component, each step rounded as the CPU rounds it.
// The product passes through its bits, xor-ed with deq_min.w's (0.0, `tracer::deq_uniforms`),
// a value the compiler cannot know: it must round the product before the add and cannot
// fuse the two into one fma.
fn sample_center(s: PackedSample, deq_min: vec4<f32>, deq_step: vec4<f32>) -> vec3<f32> {
    let q = sample_coords(s);
    let p = vec3<f32>(f32(q.x) * deq_step.x, f32(q.y) * deq_step.y, f32(q.z) * deq_step.z);
    return deq_min.xyz + as_rounded(p, bitcast<u32>(deq_min.w));
}

// `v` itself, through its bits xor-ed with `zero` (0, from a uniform the compiler cannot
// know): the compiler must round `v` as it stands, so it can neither fuse it into the next
// operation nor reassociate across it.
fn as_rounded(v: vec3<f32>, zero: u32) -> vec3<f32> {
    return bitcast<vec3<f32>>(bitcast<vec3<u32>>(v) ^ vec3<u32>(zero));
}

// `Dequantizer::radius`: code · unit.
fn sample_radius(s: PackedSample, deq_step: vec4<f32>) -> f32 {
    return f32(s.y >> 22u) * deq_step.w;
}

// `RayBasis::dir`: corner + du·px, then + dv·py, normalized by 1 / sqrt(d·d).
fn ray_dir(b: RayBasis, x: u32, y: u32) -> vec3<f32> {
    let px = f32(x) + 0.5;
    let py = f32(y) + 0.5;
    let dx = b.corner.x + b.du.x * px + b.dv.x * py;
    let dy = b.corner.y + b.du.y * px + b.dv.y * py;
    let dz = b.corner.z + b.du.z * px + b.dv.z * py;
    let inv_len = 1.0 / sqrt(dx * dx + dy * dy + dz * dz);
    return vec3<f32>(dx * inv_len, dy * inv_len, dz * inv_len);
}

// `sphere::intersect`: the nearest t > 0, or -1 for a miss (valid hits are > 0).
fn sphere_intersect(o: vec3<f32>, d: vec3<f32>, c: vec3<f32>, r: f32) -> f32 {
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

// `layer_splat::LayerParams`: the layered splatter's uniform (`layer_splat.wgsl`). Every
// per-frame constant of the CPU's `LayerSplat::draw` is computed on the host with the CPU's own
// operations and passed here, so the shader starts from the same f32 values.
struct LayerParams {
    // The drawing camera: eye, right, up, forward (w unused).
    eye: vec4<f32>,
    u: vec4<f32>,
    v: vec4<f32>,
    w: vec4<f32>,
    // The frame camera's eye and forward.
    src_eye: vec4<f32>,
    src_w: vec4<f32>,
    // Half a source pixel along the source's u and v per unit depth (world), the same in the
    // drawing camera's basis, and the source eye relative to the drawing eye in that basis.
    su: vec4<f32>,
    sv: vec4<f32>,
    bu: vec4<f32>,
    bv: vec4<f32>,
    e: vec4<f32>,
    // Pixels per unit slope along x and y, half width, half height (drawing camera).
    proj: vec4<f32>,
    deq_min: vec4<f32>,
    deq_step: vec4<f32>,
    // The drawing camera's rays (the fill's stale lookup).
    basis: RayBasis,
    // The frame camera's eye, right, up, forward (the stale lookup's projection).
    f_eye: vec4<f32>,
    f_u: vec4<f32>,
    f_v: vec4<f32>,
    f_w: vec4<f32>,
    // Its tan_x, tan_y, width, height.
    f_proj: vec4<f32>,
    // Grow ratio, edge-on factor, eye-plane epsilon, 1/255.
    k: vec4<f32>,
    // Opaque, the focal plane's numerator (plane − eye·fwd), the shared corners' area ratio,
    // 1 where the shared corners are read (else 0).
    k2: vec4<f32>,
    width: u32,
    height: u32,
    n: u32,
    min_alpha: u32,
    f_width: u32,
    f_height: u32,
    background: u32,
    // Capacity of the pixels' lists (entries, all pixels together).
    cap: u32,
    // Where the row and column spans and the scan's block sums start in the work buffer.
    off_spans: u32,
    off_sums: u32,
    // 1 when drawing an older frame (the multi-frame filling): only the pixels that
    // no earlier draw of this image covered (`count` 0) are counted, listed and composited,
    // and the spans are kept; 0 for the newest frame and the frame's own composite.
    only_empty: u32,
    // The most a sample's optical depth is scaled on its slab's shared corners (the CPU's
    // `LayerOptions::opacity_limit`; at most 1: not scaled).
    opacity_limit: f32,
}
