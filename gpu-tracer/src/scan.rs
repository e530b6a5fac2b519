//! The workgroup-wide prefix sum that the radix sort (`lbvh.wgsl`) and the layered splatter's
//! list scan (`layer_splat.wgsl`) share, in two forms with the same WGSL items (`Wg`,
//! `WgScan`, `wg_thread`, `wg_exclusive_scan`):
//!
//! - **subgroup** (`scan_subgroup.wgsl`): `subgroupInclusiveAdd` inside each subgroup and the
//!   subgroups' totals through workgroup memory, two barriers per scan;
//! - **portable** (`scan_portable.wgsl`): Hillis–Steele over workgroup memory, sixteen
//!   barriers per scan of 256 invocations.
//!
//! A context uses the subgroup form where the adapter offers `Features::SUBGROUP` (lavapipe
//! does, with subgroups of 8; so does every desktop GPU) and the portable one elsewhere;
//! `VOLWARP_GPU_SUBGROUPS=0` opens devices without subgroup operations. Both give the same
//! sums, so the sort stays stable and the tree byte-identical to the CPU's (tested with both).

/// Which workgroup scan a shader is compiled with.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum WgScanKind {
    /// Subgroup operations (`subgroupInclusiveAdd`); needs `Features::SUBGROUP`.
    Subgroup,
    /// Workgroup memory and barriers only; runs everywhere.
    Portable,
}

impl WgScanKind {
    /// Both kinds, the faster first.
    pub const ALL: [WgScanKind; 2] = [WgScanKind::Subgroup, WgScanKind::Portable];

    /// Its name (for logs and benchmark reports).
    pub fn name(self) -> &'static str {
        match self {
            WgScanKind::Subgroup => "subgroup",
            WgScanKind::Portable => "portable",
        }
    }

    /// Its name with the adapter's subgroup sizes where it uses them.
    pub fn describe(self, info: &wgpu::AdapterInfo) -> String {
        match self {
            WgScanKind::Subgroup => {
                format!("subgroup (subgroups of {}–{})", info.subgroup_min_size, info.subgroup_max_size)
            }
            WgScanKind::Portable => "portable".to_string(),
        }
    }

    /// The WGSL that defines `Wg`, `WgScan`, `wg_thread` and `wg_exclusive_scan`.
    pub fn source(self) -> &'static str {
        match self {
            WgScanKind::Subgroup => include_str!("scan_subgroup.wgsl"),
            WgScanKind::Portable => include_str!("scan_portable.wgsl"),
        }
    }

    /// Whether a device on `adapter` should be opened with subgroup operations: the adapter
    /// offers them, its subgroup sizes are powers of two from 4 to 256 (so a workgroup of 256
    /// is whole subgroups and the subgroup form's table of totals fits), and
    /// `VOLWARP_GPU_SUBGROUPS` is not `0`.
    pub(crate) fn subgroups_usable(adapter: &wgpu::Adapter) -> bool {
        if std::env::var("VOLWARP_GPU_SUBGROUPS").is_ok_and(|v| v == "0") {
            return false;
        }
        let info = adapter.get_info();
        let size_ok = |s: u32| s.is_power_of_two() && (4..=256).contains(&s);
        adapter.features().contains(wgpu::Features::SUBGROUP)
            && size_ok(info.subgroup_min_size)
            && size_ok(info.subgroup_max_size)
    }
}
