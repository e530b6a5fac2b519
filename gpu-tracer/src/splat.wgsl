// Exact object-order sphere splatting on the GPU, mirroring `volwarp_cpu_tracer::SphereSplat`:
// one invocation per sphere tests every pixel of the sphere's conservative screen-space bound
// with the tracers' own ray (`ray_dir`) and ray–sphere test (`sphere_intersect`), and keeps
// per pixel the nearest hit with core's tie rule (equal t: the smaller sample index).
//
// WGSL has no 64-bit atomics, so the CPU's one `(t bits, id)` key becomes two 32-bit passes of
// the same entry point (`S.mode`): the depth pass keeps the nearest t per pixel (`atomicMax` of
// the complemented bits: positive floats order like their bits, and a cleared 0 means empty);
// the id pass recomputes each hit — the same code on the same inputs, so the same bits — and
// where it equals the pixel's nearest t keeps the smallest index (`atomicMax` of its
// complement). `resolve` shades each pixel.
//
// SplatParams, PackedSample and the shared functions come from `prelude.wgsl`.

@group(0) @binding(0) var<uniform> S: SplatParams;
@group(0) @binding(1) var<storage, read> samples: array<PackedSample>;
@group(0) @binding(2) var<storage, read> colors: array<u32>;
@group(0) @binding(3) var<storage, read_write> depth: array<atomic<u32>>;
@group(0) @binding(4) var<storage, read_write> ids: array<atomic<u32>>;
@group(0) @binding(5) var<storage, read_write> out_pixels: array<u32>;

// The bound is computed in f32 (WGSL has no portable f64): the radius is widened by a relative
// 1e-4 of the distance (the CPU, in f64, widens by 1e-5) and the pixel span by one pixel each
// side; a larger bound only tests more pixels, the exact test decides.
const MARGIN: f32 = 1e-4;
const PAD: f32 = 1.0;

@compute @workgroup_size(64)
fn splat(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lidx: u32,
) {
    let k = (wid.y * nwg.x + wid.x) * 64u + lidx;
    if k >= S.trace.n {
        return;
    }
    let basis = S.trace.basis;
    let s = samples[k];
    let c = sample_center(s, S.trace.deq_min, S.trace.deq_step);
    let r = sample_radius(s, S.trace.deq_step);
    let o = basis.eye.xyz;
    let w = S.trace.width;
    let h = S.trace.height;

    // Screen-space bound (`View::bound`): the tangents from the eye, per image axis.
    let rel = c - o;
    let cx = dot(rel, S.u.xyz);
    let cy = dot(rel, S.v.xyz);
    let cz = dot(rel, S.w.xyz);
    let rr = r + MARGIN * (length(rel) + r);
    if !(cz + rr >= 0.0) {
        return; // behind the eye (or not a number)
    }
    var x0 = 0u;
    var x1 = w - 1u;
    var y0 = 0u;
    var y1 = h - 1u;
    if cz > rr * 1.01 {
        let denom = cz * cz - rr * rr;
        let inv = 1.0 / denom;
        let sx = sqrt(cx * cx + denom);
        let sy = sqrt(cy * cy + denom);
        let xl = (cx * cz - rr * sx) * inv;
        let xh = (cx * cz + rr * sx) * inv;
        let yl = (cy * cz - rr * sy) * inv;
        let yh = (cy * cz + rr * sy) * inv;
        let ax = xl * S.px.x + S.px.z;
        let bx = xh * S.px.x + S.px.z;
        let ay = S.px.w - yh * S.px.y;
        let by = S.px.w - yl * S.px.y;
        let lx = max(floor(ax - 0.5 - PAD), 0.0);
        let hx = min(ceil(bx - 0.5 + PAD), f32(w) - 1.0);
        let ly = max(floor(ay - 0.5 - PAD), 0.0);
        let hy = min(ceil(by - 0.5 + PAD), f32(h) - 1.0);
        if !(lx <= hx && ly <= hy) {
            return;
        }
        x0 = u32(lx);
        x1 = u32(hx);
        y0 = u32(ly);
        y1 = u32(hy);
    } // else: the sphere touches the eye plane, its projection is unbounded: every pixel.

    let id_pass = S.mode == 1u;
    for (var y = y0; y <= y1; y++) {
        for (var x = x0; x <= x1; x++) {
            let d = ray_dir(basis, x, y);
            let t = sphere_intersect(o, d, c, r);
            if t > 0.0 {
                let p = y * w + x;
                let key = ~bitcast<u32>(t);
                if !id_pass {
                    atomicMax(&depth[p], key);
                } else if atomicLoad(&depth[p]) == key {
                    atomicMax(&ids[p], ~k);
                }
            }
        }
    }
}

@compute @workgroup_size(8, 8, 1)
fn resolve(@builtin(global_invocation_id) gid: vec3<u32>) {
    let w = S.trace.width;
    if gid.x >= w || gid.y >= S.trace.height {
        return;
    }
    let p = gid.y * w + gid.x;
    let v = atomicLoad(&ids[p]);
    var pixel = S.trace.background;
    if v != 0u {
        pixel = over_background(colors[~v], S.trace.background);
    }
    out_pixels[p] = pixel;
}
