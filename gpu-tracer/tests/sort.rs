//! The GPU radix sort and LBVH build against the CPU: the sort equals a CPU stable sort, the
//! tree equals `Scene::build` byte for byte. They run on whatever adapter there is (lavapipe in
//! CI) and FAIL when there is none, unless `VOLWARP_SKIP_GPU=1` is set explicitly.

use volwarp_core::Scene;
use volwarp_gpu_tracer::synthetic::bumpy_surface;
use volwarp_gpu_tracer::{GpuTracer, WgScanKind};

fn tracer() -> Option<GpuTracer> {
    if std::env::var("VOLWARP_SKIP_GPU").is_ok_and(|v| v == "1") {
        eprintln!("VOLWARP_SKIP_GPU=1: GPU test skipped");
        return None;
    }
    match GpuTracer::new() {
        Ok(t) => Some(t),
        Err(e) => panic!("{e} (set VOLWARP_SKIP_GPU=1 to skip the GPU tests explicitly)"),
    }
}

/// The workgroup scans to test on this adapter: both where it has subgroup operations (lavapipe
/// does), else the portable one, saying so. Leaves `gpu` on the first.
fn scans(gpu: &mut GpuTracer) -> Vec<WgScanKind> {
    let mut v = Vec::new();
    for kind in WgScanKind::ALL {
        match gpu.set_scan(kind) {
            Ok(()) => v.push(kind),
            Err(e) => {
                let offered = gpu.context().adapter.features().contains(wgpu::Features::SUBGROUP);
                let disabled = std::env::var("VOLWARP_GPU_SUBGROUPS").is_ok_and(|v| v == "0");
                assert!(!offered || disabled, "the adapter offers subgroups but the {kind:?} scan is refused: {e}");
                eprintln!("{kind:?} scan not tested: {e}");
            }
        }
    }
    gpu.set_scan(v[0]).unwrap();
    v
}

/// A small deterministic generator (xorshift64*).
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
}

/// Keys laid out like `morton::SortKey` (code lo, code hi, payload, 0) with payload = index.
fn keys(codes: &[u64]) -> Vec<[u32; 4]> {
    codes.iter().enumerate().map(|(i, &c)| [c as u32, (c >> 32) as u32, i as u32, 0]).collect()
}

/// The reference: a CPU stable sort by code.
fn cpu_sort(k: &[[u32; 4]]) -> Vec<[u32; 4]> {
    let mut v = k.to_vec();
    v.sort_by_key(|k| (k[1] as u64) << 32 | k[0] as u64);
    v
}

#[test]
fn gpu_sort_equals_a_cpu_stable_sort() {
    let Some(mut gpu) = tracer() else { return };
    for scan in scans(&mut gpu) {
        gpu.set_scan(scan).unwrap();
        sort_cases(&mut gpu, scan);
    }
}

fn sort_cases(gpu: &mut GpuTracer, scan: WgScanKind) {
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    const CODE: u64 = (1 << 54) - 1;
    // Counts around the block (1024 keys), the workgroup (256) and the scan block (2048
    // histogram entries: 9 blocks) sizes, and not multiples; 300,001 keys make 294 blocks, a
    // histogram of 75,264 entries and a scan of three levels.
    for n in [0usize, 1, 2, 3, 255, 256, 257, 1023, 1024, 1025, 3001, 9 * 1024 + 1, 70_001, 300_001] {
        let random: Vec<u64> = (0..n).map(|_| rng.next() & CODE).collect();
        let few: Vec<u64> = (0..n).map(|_| [0, 7, 1 << 40, CODE][(rng.next() % 4) as usize]).collect();
        let equal = vec![0x0012_3456_789a_bcde_u64 & CODE; n];
        for (what, codes) in [("random", random), ("duplicate-heavy", few), ("all equal", equal)] {
            let k = keys(&codes);
            let got = gpu.sort_keys(&k).unwrap_or_else(|e| panic!("{scan:?} {what} n = {n}: {e}"));
            assert_eq!(got.len(), n, "{scan:?} {what} n = {n}");
            assert!(got == cpu_sort(&k), "{scan:?} {what} n = {n}: the GPU sort differs from a stable CPU sort");
        }
    }
}

#[test]
fn gpu_sort_of_sort_keys_matches_the_build_order() {
    let Some(mut gpu) = tracer() else { return };
    // Real Morton keys of a frame: the sorted payloads are the CPU build's leaf order.
    let frame = bumpy_surface(97, 1.5, 5);
    let codes: Vec<u64> = frame.samples.iter().map(|&s| volwarp_core::morton::code_of_sample(s)).collect();
    let k = keys(&codes);
    for scan in scans(&mut gpu) {
        gpu.set_scan(scan).unwrap();
        let got = gpu.sort_keys(&k).unwrap();
        assert!(got == cpu_sort(&k), "{scan:?}");
    }
}

#[test]
fn gpu_tree_equals_the_cpu_tree_byte_for_byte() {
    let Some(mut gpu) = tracer() else { return };
    let base = bumpy_surface(120, 1.5, 9);
    for scan in scans(&mut gpu) {
        gpu.set_scan(scan).unwrap();
        tree_cases(&mut gpu, &base, scan);
    }
}

fn tree_cases(gpu: &mut GpuTracer, base: &volwarp_core::wire::Frame, scan: WgScanKind) {
    for n in [2usize, 3, 1023, 1024, 1025, 5000, base.samples.len()] {
        let mut frame = base.clone();
        frame.samples.truncate(n);
        frame.colors.truncate(n);
        frame.header.count = n as u32;
        if n == 5000 {
            // Heavy duplicates: the index tie-break decides.
            for i in (0..n).step_by(2) {
                frame.samples[i] = frame.samples[7];
            }
        }
        let cpu = Scene::build(&frame);
        let g = gpu.build_scene(&frame).unwrap();
        assert_eq!(g.samples, cpu.samples, "{scan:?} n = {n}");
        assert_eq!(g.colors, cpu.colors, "{scan:?} n = {n}");
        let bytes = |s: &Scene| bytemuck::cast_slice::<_, u8>(&s.nodes).to_vec();
        assert!(bytes(&g) == bytes(&cpu), "{scan:?} n = {n}: GPU nodes differ from the CPU nodes");
    }
}
