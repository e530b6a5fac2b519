//! First-hit sphere tracing of the LBVH with 8-ray SIMD packets: the client's default renderer
//! on machines without a GPU.
//!
//! * **Packets.** A packet is a 4×2 pixel group; the image is cut into bands of
//!   [`BAND_ROWS`] rows (the unit of parallel work), each walked in 8×8 tiles of eight packets,
//!   so consecutive packets are spatially coherent.
//! * **Traversal.** One stack per packet; a node is entered for the lanes whose ray enters its
//!   box no later than their current best hit (the *active mask*). An entry remembers each
//!   lane's box entry distance, so a node popped after the whole packet has found closer hits
//!   is skipped without touching memory (*early exit*). When both children are hit, the one
//!   most active lanes enter first is visited first (*near-to-far*).
//! * **Exactness.** Rays, box slabs, sphere intersection and the tie rule mirror core's scalar
//!   code operation by operation (no fused multiply-add, IEEE `sqrt` and division, NaN-aware
//!   `min`/`max` like `f32::min`), and the tie rule makes the result independent of the visit
//!   order: the image equals [`crate::ScalarTracer`]'s bit for bit (tested).
//! * **SIMD dispatch.** The kernel is generic over its eight-lane vector type (`lanes::Lanes`)
//!   and compiled twice: with `wide::f32x8` (portable: two SSE halves on baseline x86-64,
//!   whatever `wide` was built for elsewhere) and, on x86-64, with `lanes::Avx2` (`__m256`
//!   intrinsics) inside a `#[target_feature(enable = "avx2")]` function, chosen per band by
//!   the lane level `volwarp_lanes` detected once. So one portable binary runs 256-bit ymm code where the
//!   CPU has AVX2 (`wide` alone would not: it picks its representation when it is compiled, not
//!   per function). Each `Avx2` operation reproduces the `wide` one it replaces (comparisons
//!   ordered, `min`/`max` operand order and NaN handling, blends on full-lane masks), and no
//!   fused multiply-add is formed, so both kernels give the same image (tested against each
//!   other operation by operation and against the scalar tracer).

use crate::threads::Threads;
use crate::{begin_frame, shade, NO_HIT};
use volwarp_core::lbvh::{Lbvh, LEAF_BIT};
use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::sample::Dequantizer;
use volwarp_core::sphere::BOX_T_FAR_SCALE;
use volwarp_core::traversal::STACK_SIZE;
use volwarp_core::RendererKind;
use volwarp_core::{Camera, RayBasis, Scene};

use crate::lanes::{self, ray_dirs, sphere_hits, Lanes};

/// Packet width in pixels.
pub const PACKET_W: u32 = 4;
/// Packet height in pixels.
pub const PACKET_H: u32 = 2;
/// Rows per band, the unit of parallel work.
pub const BAND_ROWS: u32 = 8;
/// Width of a tile (a band is walked tile by tile).
const TILE_W: u32 = 8;

/// Eight primary rays sharing one origin.
#[derive(Clone, Copy)]
struct Packet<L> {
    o: [f32; 3],
    d: [L; 3],
    inv: [L; 3],
    /// No lane has an infinite inverse direction, so no slab can be NaN and the plain SIMD
    /// `min`/`max` give `f32::min`/`f32::max`'s results.
    finite_inv: bool,
}

/// Lane `l` of a packet at `(x0, y0)` is pixel `(x0 + l % 4, y0 + l / 4)`.
#[inline(always)]
fn make_packet<L: Lanes>(b: &RayBasis, x0: u32, y0: u32) -> Packet<L> {
    let px = L::new(core::array::from_fn(|l| (x0 + l as u32 % PACKET_W) as f32 + 0.5));
    let py = L::new(core::array::from_fn(|l| (y0 + l as u32 / PACKET_W) as f32 + 0.5));
    let d = ray_dirs(b, px, py);
    let one = L::splat(1.0);
    // Exactly `Vec3::ONE / ray.dir` of the scalar traversal.
    let inv = [one / d[0], one / d[1], one / d[2]];
    let finite_inv = (inv[0].is_finite() & inv[1].is_finite() & inv[2].is_finite()).all();
    Packet { o: [b.eye[0], b.eye[1], b.eye[2]], d, inv, finite_inv }
}

/// All lanes set.
#[inline(always)]
fn all_lanes<L: Lanes>() -> L {
    L::splat(0.0).simd_eq(L::splat(0.0))
}

/// `sphere::intersect_box` for eight rays (same operations, far bound widened by
/// [`BOX_T_FAR_SCALE`]): the entry distances and the mask of lanes whose
/// ray enters the box before `t_max`.
#[inline(always)]
fn box_test<L: Lanes>(p: &Packet<L>, min: &[f32; 3], max: &[f32; 3], t_max: L) -> (L, L) {
    let tx1 = L::splat(min[0] - p.o[0]) * p.inv[0];
    let tx2 = L::splat(max[0] - p.o[0]) * p.inv[0];
    let ty1 = L::splat(min[1] - p.o[1]) * p.inv[1];
    let ty2 = L::splat(max[1] - p.o[1]) * p.inv[1];
    let tz1 = L::splat(min[2] - p.o[2]) * p.inv[2];
    let tz2 = L::splat(max[2] - p.o[2]) * p.inv[2];
    let scale = L::splat(BOX_T_FAR_SCALE);
    let zero = L::splat(0.0);
    let (t_near, t_far) = if p.finite_inv {
        // No NaN can occur (finite inverse times finite difference): the plain min/max are
        // exact. Only the sign of a zero may differ, which no comparison sees.
        let t_near = tx1.fast_min(tx2).fast_max(ty1.fast_min(ty2)).fast_max(tz1.fast_min(tz2)).fast_max(zero);
        let t_far =
            (tx1.fast_max(tx2).fast_min(ty1.fast_max(ty2)).fast_min(tz1.fast_max(tz2)) * scale).fast_min(t_max * scale);
        (t_near, t_far)
    } else {
        let t_near = tx1.min(tx2).max(ty1.min(ty2)).max(tz1.min(tz2)).max(zero);
        let t_far = (tx1.max(tx2).min(ty1.max(ty2)).min(tz1.max(tz2)) * scale).min(t_max * scale);
        (t_near, t_far)
    };
    (t_near, t_near.simd_le(t_far))
}

/// The per-packet best hits: distance and primitive per lane ([`NO_HIT`] and +∞ for none).
struct Best<L: Lanes> {
    t: L,
    prim: L::U,
}

/// `sphere::intersect` of sample `prim` for the `active` lanes, kept if closer by core's tie
/// rule.
#[inline(always)]
fn test_sphere<L: Lanes>(p: &Packet<L>, deq: &Dequantizer, s: u64, prim: u32, active: L, best: &mut Best<L>) {
    let Some((t, hit)) = sphere_hits(&p.o, &p.d, deq.center(s), deq.radius(s), active) else { return };
    let pv = L::splat_u(prim);
    let smaller = L::lt_u(pv, best.prim);
    let better = hit & (t.simd_lt(best.t) | (t.simd_eq(best.t) & smaller));
    best.t = better.select(t, best.t);
    best.prim = better.select_u(pv, best.prim);
}

/// A traversal stack, allocated once per band.
struct Stack<L> {
    node: [u32; STACK_SIZE],
    /// Entry distance per lane, NaN for lanes that do not enter the node.
    t: [L; STACK_SIZE],
}

impl<L: Lanes> Stack<L> {
    #[inline(always)]
    fn new() -> Box<Stack<L>> {
        Box::new(Stack { node: [0; STACK_SIZE], t: [L::splat(0.0); STACK_SIZE] })
    }
}

/// Tests child reference `child` for the `active` lanes: a leaf's sphere updates `best`; an
/// inner node gives its entry distances and the lanes that enter it, if any.
#[inline(always)]
fn visit<L: Lanes>(l: &Lbvh, p: &Packet<L>, child: u32, active: L, best: &mut Best<L>) -> Option<(L, L)> {
    if child & LEAF_BIT != 0 {
        let k = child & !LEAF_BIT;
        test_sphere(p, &l.deq, l.samples[k as usize], k, active, best);
        None
    } else {
        let c = &l.nodes[child as usize];
        let (tn, hit) = box_test(p, &c.min, &c.max, best.t);
        let hit = hit & active;
        hit.any().then_some((tn, hit))
    }
}

/// The first hit of each lane of the packet: sample ids, [`NO_HIT`] where none. Traversal
/// starts from the child references `entries` (the root's).
#[inline(always)]
fn trace_packet<L: Lanes>(l: &Lbvh, p: &Packet<L>, entries: &[u32], stack: &mut Stack<L>) -> L::U {
    let mut best = Best { t: L::splat(f32::INFINITY), prim: L::splat_u(NO_HIT) };
    let nan = L::splat(f32::NAN);
    let mut sp = 0;
    for &e in entries {
        if let Some((t, hit)) = visit(l, p, e, all_lanes(), &mut best) {
            stack.node[sp] = e;
            stack.t[sp] = hit.select(t, nan);
            sp += 1;
        }
    }
    loop {
        // Pop the next node some lane still needs. Early exit: NaN (a lane that does not
        // enter it) compares false, as do lanes whose best hit is already closer than the
        // node (with the slab test's conservative widening).
        let limit = best.t * L::splat(BOX_T_FAR_SCALE);
        // The node being visited and its active lanes; the far children wait on the stack.
        let (mut cur, mut active) = loop {
            if sp == 0 {
                return best.prim;
            }
            sp -= 1;
            let a = stack.t[sp].simd_le(limit);
            if a.any() {
                break (stack.node[sp], a);
            }
        };
        loop {
            let node = &l.nodes[cur as usize];
            let (left, right) = (node.left, node.right);
            let lh = visit(l, p, left, active, &mut best);
            let rh = visit(l, p, right, active, &mut best);
            (cur, active) = match (lh, rh) {
                (Some((lt, lm)), Some((rt, rm))) => {
                    // Near-to-far: descend into the child that most lanes hitting both enter
                    // first; the other waits with its entry distances (NaN where not entered).
                    let both = lm & rm;
                    let right_first = (rt.simd_lt(lt) & both).to_bitmask().count_ones();
                    let (near, far, far_t) = if 2 * right_first > both.to_bitmask().count_ones() {
                        ((right, rm), left, lm.select(lt, nan))
                    } else {
                        ((left, lm), right, rm.select(rt, nan))
                    };
                    if sp < STACK_SIZE {
                        stack.node[sp] = far;
                        stack.t[sp] = far_t;
                        sp += 1;
                    }
                    near
                }
                (Some((_, lm)), None) => (left, lm),
                (None, Some((_, rm))) => (right, rm),
                (None, None) => break,
            };
        }
    }
}

lanes::dispatch! {
    /// [`trace_band`] on the best lanes this CPU has (AVX2 only widens the vectors to one ymm
    /// register; no fused multiply-add is ever formed), so the same result.
    fn trace_band_dispatch / trace_band_avx2 => trace_band(
        l: &Lbvh,
        basis: &RayBasis,
        width: u32,
        band: usize,
        rows: &mut [u32],
        map: &(impl Fn(u32) -> u32 + Sync),
    )
}

/// Traces band `band` (rows `band * BAND_ROWS ..`) of a `width`-wide image into `rows`,
/// writing `map(id)` per pixel.
#[inline(always)]
fn trace_band<L: Lanes>(
    l: &Lbvh,
    basis: &RayBasis,
    width: u32,
    band: usize,
    rows: &mut [u32],
    map: &(impl Fn(u32) -> u32 + Sync),
) {
    let mut stack = Stack::<L>::new();
    let h = (rows.len() / width as usize) as u32;
    let y_base = band as u32 * BAND_ROWS;
    let root = match l.samples.len() {
        0 => None,
        1 => Some(LEAF_BIT),
        _ => Some(0),
    };
    let entries = root.as_slice();
    for tx in (0..width).step_by(TILE_W as usize) {
        for py in (0..h).step_by(PACKET_H as usize) {
            for px in (tx..(tx + TILE_W).min(width)).step_by(PACKET_W as usize) {
                let p = make_packet(basis, px, y_base + py);
                let ids = L::u_to_array(trace_packet(l, &p, entries, &mut stack));
                for (lane, &id) in ids.iter().enumerate() {
                    let (x, y) = (px + lane as u32 % PACKET_W, py + lane as u32 / PACKET_W);
                    if x < width && y < h {
                        rows[(y * width + x) as usize] = map(id);
                    }
                }
            }
        }
    }
}

/// The SIMD packet tracer (renderer name `spheres-cpu`).
#[derive(Debug)]
pub struct PacketTracer {
    threads: Threads,
}

impl PacketTracer {
    /// A tracer on `threads` threads (0: one per core; 1 runs on the caller's thread).
    pub fn new(threads: usize) -> Self {
        PacketTracer { threads: Threads::new(threads) }
    }

    /// The number of threads it renders with.
    pub fn threads(&self) -> usize {
        self.threads.count()
    }

    /// Traces `camera`'s viewport into `ids` (row-major, resized): the sorted sample index of
    /// each pixel's first hit, [`NO_HIT`] where none. Returns `false` (all [`NO_HIT`], or
    /// empty for an unusable viewport) if the camera or scene is unusable.
    pub fn trace_ids(&self, scene: &Scene, camera: &Camera, ids: &mut Vec<u32>) -> bool {
        crate::trace_ids_with(scene, camera, ids, |ids| self.draw(scene, camera, ids, |id| id))
    }

    fn draw(&self, scene: &Scene, camera: &Camera, out: &mut [u32], map: impl Fn(u32) -> u32 + Sync) {
        let l = scene.lbvh();
        let basis = camera.ray_basis();
        let width = camera.width;
        self.threads.for_each_chunk(out, (width * BAND_ROWS) as usize, |band, rows| {
            trace_band_dispatch(&l, &basis, width, band, rows, &map)
        });
    }
}

impl Default for PacketTracer {
    /// One thread per core.
    fn default() -> Self {
        PacketTracer::new(0)
    }
}

impl Renderer for PacketTracer {
    fn kind(&self) -> RendererKind {
        RendererKind::SpheresCpu
    }

    fn render(&mut self, scene: &Scene, camera: &Camera, out: &mut Image) {
        if begin_frame(scene, camera, out) {
            let colors = &scene.colors;
            self.draw(scene, camera, &mut out.pixels, |id| shade(colors, id));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::{depth_image_frame, random_cloud};
    use crate::{build_scene, ScalarTracer};
    use volwarp_core::Vec3;
    use wide::f32x8;

    /// The sample ids of every band traced by `band` (one thread).
    fn ids_by_band(scene: &Scene, cam: &Camera, band: impl Fn(&Lbvh, &RayBasis, u32, usize, &mut [u32])) -> Vec<u32> {
        let mut ids = vec![NO_HIT; (cam.width * cam.height) as usize];
        let (l, basis) = (scene.lbvh(), cam.ray_basis());
        for (i, rows) in ids.chunks_mut((cam.width * BAND_ROWS) as usize).enumerate() {
            band(&l, &basis, cam.width, i, rows);
        }
        ids
    }

    /// Whichever kernel the dispatch picks, the integration tests compare the packet tracer with
    /// the scalar one; this checks both kernels, so the portable one is covered on AVX2
    /// machines too.
    #[test]
    fn portable_and_avx2_kernels_equal_scalar() {
        let cloud = random_cloud(5000, 0.02, 7, 96);
        let depth = depth_image_frame(128, 1.0, 3);
        let axis = Camera::look_at(Vec3::new(0.5, 0.5, 4.0), Vec3::new(0.5, 0.5, 0.0), Vec3::Y, 30.0, 65, 65);
        for (frame, cams) in [
            (&cloud, vec![cloud.header.camera, cloud.header.camera.orbit(35.0, 20.0).with_viewport(61, 47), axis]),
            (&depth, vec![depth.header.camera, depth.header.camera.orbit(10.0, 0.0).with_viewport(99, 70)]),
        ] {
            let scene = build_scene(frame);
            for cam in cams {
                let mut scalar = Vec::new();
                assert!(ScalarTracer::new(1).trace_ids(&scene, &cam, &mut scalar));
                assert!(scalar.iter().any(|&i| i != NO_HIT));
                let portable =
                    ids_by_band(&scene, &cam, |l, b, w, i, rows| trace_band::<f32x8>(l, b, w, i, rows, &|id| id));
                assert!(portable == scalar, "portable kernel");
                #[cfg(target_arch = "x86_64")]
                if volwarp_lanes::Avx2Token::detected().is_some() {
                    let avx2 = ids_by_band(&scene, &cam, |l, b, w, i, rows| {
                        // SAFETY: the CPU supports AVX2 (checked just above).
                        unsafe { trace_band_avx2(l, b, w, i, rows, &|id| id) }
                    });
                    assert!(avx2 == scalar, "AVX2 kernel");
                }
            }
        }
    }
}
