//! The one registry of renderers: every way of drawing a scene that volwarp offers, with its
//! name (CSV files, `--renderer`, the window title), its role (the product, a baseline it is
//! compared with, or a reference oracle that tests check the others against), its number key
//! in the window (1–9, the default on 1; some have none) and what it can do. The client, the evaluation and every command line read this table; adding a renderer is
//! one entry here plus its constructor (the compiler points at the `match`es that need it).

/// What a renderer can do (its capabilities), for the client's menus and the evaluation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Capabilities {
    /// It draws the exact first-hit sphere image (the same sample id per pixel as core's scalar
    /// reference traversal, with the tie rule).
    pub exact_spheres: bool,
    /// It traverses the scene's LBVH (a client must build one before it draws).
    pub needs_lbvh: bool,
    /// It runs on a GPU (opened lazily; may be unavailable).
    pub gpu: bool,
}

/// What a renderer is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Role {
    /// What volwarp ships: the layered method and its GPU twin.
    Product,
    /// A drawing the product is measured against: what a send-image system shows, the 2.5D
    /// points of ZAL12, the exact sphere images of Zellmann 2020 (its tracers and splatters)
    /// and the earlier single-sample hole-filling warps.
    Baseline,
    /// A slow, simple drawing that tests check the fast ones against.
    Reference,
}

impl Role {
    /// Its name, in a word.
    pub const fn name(self) -> &'static str {
        match self {
            Role::Product => "product",
            Role::Baseline => "baseline",
            Role::Reference => "reference",
        }
    }
}

/// A renderer, by kind. The order of [`RendererKind::ALL`] is the registry's (CSV files list
/// renderers in it); the window's number keys are [`RendererKind::window_key`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum RendererKind {
    /// SIMD packet sphere tracer over the LBVH (`spheres-cpu`).
    SpheresCpu,
    /// ZAL12 2.5D points, 1×1 pixel (`points1`).
    Points1,
    /// ZAL12 2.5D points, 2×2 pixels (`points2`).
    Points2,
    /// ZAL12 2.5D points, 3×3 pixels (`points3`).
    Points3,
    /// Exact object-order sphere splatting, no LBVH (`splat`).
    Splat,
    /// The frame as it was rendered, not warped: what a send-image system shows (`stale`).
    Stale,
    /// The wgpu compute sphere tracer (`spheres-gpu`).
    SpheresGpu,
    /// Core's scalar reference traversal per pixel (`spheres-scalar`).
    SpheresScalar,
    /// The fastest exact sphere image: tiled splatting or the packet tracer, whichever a
    /// measured cost model predicts faster for the frame; draws unbuilt scenes (`spheres`).
    Spheres,
    /// Exact object-order sphere splatting in cache-sized screen tiles, no LBVH (`splat-tiles`).
    SplatTiles,
    /// The packet tracer with hole filling: pixels no sample covers show the stale frame for
    /// that view direction (`spheres-fill`; `volwarp_cpu_tracer::hole_fill`).
    SpheresFill,
    /// The exact splatter with the same hole filling (`splat-fill`).
    SplatFill,
    /// The exact sphere splatter as wgpu compute shaders, no LBVH (`splat-gpu`).
    SplatGpu,
    /// Layered samples: every segment a sphere hits, owned by the output ray where
    /// it passes through the segment's own source pixel, composited front to back; no LBVH
    /// (`splat-layers`).
    SplatLayers,
    /// The layered splatter as wgpu compute shaders: the same footprints, lists, compositing
    /// and fill as `splat-layers`, the same image (`splat-layers-gpu`).
    SplatLayersGpu,
    /// Layered samples drawn by multi-hit LBVH traversal: every segment sphere a pixel's ray
    /// hits where the ray passes through the segment's own source pixel, composited front to
    /// back (the reference tracer of `splat-layers`; `spheres-layers`).
    SpheresLayers,
}

/// One row of the registry.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RendererInfo {
    /// The kind.
    pub kind: RendererKind,
    /// Its name.
    pub name: &'static str,
    /// What it is, in a few words (for `--help` and docs).
    pub about: &'static str,
    /// Its capabilities.
    pub caps: Capabilities,
    /// What it is for.
    pub role: Role,
    /// Its number key in the window (1–9), if it has one.
    pub window_key: Option<u8>,
}

const fn caps(exact_spheres: bool, needs_lbvh: bool, gpu: bool) -> Capabilities {
    Capabilities { exact_spheres, needs_lbvh, gpu }
}

/// The registry, in [`RendererKind::ALL`]'s order.
pub const REGISTRY: [RendererInfo; RendererKind::COUNT] = [
    RendererInfo {
        kind: RendererKind::SpheresCpu,
        name: "spheres-cpu",
        about: "SIMD packet sphere tracer (LBVH)",
        caps: caps(true, true, false),
        role: Role::Baseline,
        window_key: None,
    },
    RendererInfo {
        kind: RendererKind::Points1,
        name: "points1",
        about: "2.5D points, 1 px",
        caps: caps(false, false, false),
        role: Role::Baseline,
        window_key: Some(3),
    },
    RendererInfo {
        kind: RendererKind::Points2,
        name: "points2",
        about: "2.5D points, 2 px",
        caps: caps(false, false, false),
        role: Role::Baseline,
        window_key: Some(4),
    },
    RendererInfo {
        kind: RendererKind::Points3,
        name: "points3",
        about: "2.5D points, 3 px",
        caps: caps(false, false, false),
        role: Role::Baseline,
        window_key: Some(5),
    },
    RendererInfo {
        kind: RendererKind::Splat,
        name: "splat",
        about: "exact sphere splatting (no LBVH)",
        caps: caps(true, false, false),
        role: Role::Baseline,
        window_key: Some(6),
    },
    RendererInfo {
        kind: RendererKind::Stale,
        name: "stale",
        about: "the frame, not warped",
        caps: caps(false, false, false),
        role: Role::Baseline,
        window_key: Some(2),
    },
    RendererInfo {
        kind: RendererKind::SpheresGpu,
        name: "spheres-gpu",
        about: "wgpu compute sphere tracer",
        caps: caps(true, true, true),
        role: Role::Baseline,
        window_key: Some(7),
    },
    RendererInfo {
        kind: RendererKind::SpheresScalar,
        name: "spheres-scalar",
        about: "scalar reference sphere tracer",
        caps: caps(true, true, false),
        role: Role::Reference,
        window_key: Some(8),
    },
    RendererInfo {
        kind: RendererKind::Spheres,
        name: "spheres",
        about: "exact spheres: tiled splatting or the packet tracer, whichever is faster",
        caps: caps(true, false, false),
        role: Role::Baseline,
        window_key: Some(9),
    },
    RendererInfo {
        kind: RendererKind::SplatTiles,
        name: "splat-tiles",
        about: "exact sphere splatting in screen tiles (no LBVH)",
        caps: caps(true, false, false),
        role: Role::Baseline,
        window_key: None,
    },
    RendererInfo {
        kind: RendererKind::SpheresFill,
        name: "spheres-fill",
        about: "SIMD sphere tracer, holes filled from the stale frame",
        caps: caps(false, true, false),
        role: Role::Baseline,
        window_key: None,
    },
    RendererInfo {
        kind: RendererKind::SplatFill,
        name: "splat-fill",
        about: "exact sphere splatting, holes filled from the stale frame",
        caps: caps(false, false, false),
        role: Role::Baseline,
        window_key: None,
    },
    RendererInfo {
        kind: RendererKind::SplatGpu,
        name: "splat-gpu",
        about: "wgpu exact sphere splatting (no LBVH)",
        caps: caps(true, false, true),
        role: Role::Baseline,
        window_key: None,
    },
    RendererInfo {
        kind: RendererKind::SplatLayers,
        name: "splat-layers",
        about: "layered samples composited front to back (no LBVH)",
        caps: caps(false, false, false),
        role: Role::Product,
        window_key: Some(1),
    },
    RendererInfo {
        kind: RendererKind::SplatLayersGpu,
        name: "splat-layers-gpu",
        about: "wgpu layered samples composited front to back (no LBVH)",
        caps: caps(false, false, true),
        role: Role::Product,
        window_key: None,
    },
    RendererInfo {
        kind: RendererKind::SpheresLayers,
        name: "spheres-layers",
        about: "layered samples by multi-hit sphere tracing (LBVH), composited front to back",
        caps: caps(false, true, false),
        role: Role::Reference,
        window_key: None,
    },
];

impl RendererKind {
    /// How many renderers the registry has.
    pub const COUNT: usize = 16;

    /// Every renderer, in the registry's order.
    pub const ALL: [RendererKind; RendererKind::COUNT] = [
        RendererKind::SpheresCpu,
        RendererKind::Points1,
        RendererKind::Points2,
        RendererKind::Points3,
        RendererKind::Splat,
        RendererKind::Stale,
        RendererKind::SpheresGpu,
        RendererKind::SpheresScalar,
        RendererKind::Spheres,
        RendererKind::SplatTiles,
        RendererKind::SpheresFill,
        RendererKind::SplatFill,
        RendererKind::SplatGpu,
        RendererKind::SplatLayers,
        RendererKind::SplatLayersGpu,
        RendererKind::SpheresLayers,
    ];

    /// The renderer a client starts with (window key 1): the layered splatter (the client then
    /// asks for 4 segments per pixel), with hole filling and, with the client's default prediction
    /// and warp-grown footprints, the most accurate method of the session results
    /// (`docs/results.md`, "The default method").
    pub const DEFAULT: RendererKind = RendererKind::SplatLayers;

    /// Whether it composites a layered frame's segments (the client then asks for
    /// `segments::DEFAULT_LAYERS` per pixel); the others draw first hits.
    pub const fn draws_layers(self) -> bool {
        matches!(self, RendererKind::SplatLayers | RendererKind::SplatLayersGpu | RendererKind::SpheresLayers)
    }

    /// Its row of [`REGISTRY`].
    pub const fn info(self) -> &'static RendererInfo {
        &REGISTRY[self.index()]
    }

    /// Its position in the registry (0-based).
    pub const fn index(self) -> usize {
        match self {
            RendererKind::SpheresCpu => 0,
            RendererKind::Points1 => 1,
            RendererKind::Points2 => 2,
            RendererKind::Points3 => 3,
            RendererKind::Splat => 4,
            RendererKind::Stale => 5,
            RendererKind::SpheresGpu => 6,
            RendererKind::SpheresScalar => 7,
            RendererKind::Spheres => 8,
            RendererKind::SplatTiles => 9,
            RendererKind::SpheresFill => 10,
            RendererKind::SplatFill => 11,
            RendererKind::SplatGpu => 12,
            RendererKind::SplatLayers => 13,
            RendererKind::SplatLayersGpu => 14,
            RendererKind::SpheresLayers => 15,
        }
    }

    /// Its name (no allocation).
    pub const fn name(self) -> &'static str {
        self.info().name
    }

    /// Its number key in the window (1–9), if it has one.
    pub const fn window_key(self) -> Option<u8> {
        self.info().window_key
    }

    /// The renderer of a window number key (1–9).
    pub fn from_window_key(key: u8) -> Option<RendererKind> {
        Self::ALL.into_iter().find(|k| k.window_key() == Some(key))
    }

    /// What it is for.
    pub const fn role(self) -> Role {
        self.info().role
    }

    /// The renderer of a name.
    pub fn from_name(name: &str) -> Option<RendererKind> {
        Self::ALL.iter().copied().find(|k| k.name() == name)
    }

    /// The 2.5D points renderer of an `n × n` footprint (`n` = 1, 2, 3).
    pub fn points(n: u32) -> Option<RendererKind> {
        match n {
            1 => Some(RendererKind::Points1),
            2 => Some(RendererKind::Points2),
            3 => Some(RendererKind::Points3),
            _ => None,
        }
    }
}

impl core::fmt::Display for RendererKind {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.name())
    }
}

impl core::str::FromStr for RendererKind {
    type Err = UnknownRenderer;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        RendererKind::from_name(s).ok_or(UnknownRenderer)
    }
}

/// A name that is not in the [`REGISTRY`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct UnknownRenderer;

impl core::fmt::Display for UnknownRenderer {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("unknown renderer (one of")?;
        for r in REGISTRY {
            write!(f, " {}", r.name)?;
        }
        f.write_str(")")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_matches_kinds_keys_and_names() {
        for (i, k) in RendererKind::ALL.iter().enumerate() {
            assert_eq!(REGISTRY[i].kind, *k, "REGISTRY and ALL are in the same order");
            assert_eq!(k.index(), i);
            assert_eq!(RendererKind::from_name(k.name()), Some(*k));
            assert_eq!(k.name().parse::<RendererKind>(), Ok(*k));
            if let Some(key) = k.window_key() {
                assert_eq!(RendererKind::from_window_key(key), Some(*k), "window keys are unique");
            }
        }
        let mut names = REGISTRY.map(|r| r.name);
        names.sort_unstable();
        assert!(names.windows(2).all(|w| w[0] != w[1]), "names are unique");
        assert_eq!(RendererKind::from_window_key(0), None);
        assert_eq!(RendererKind::from_window_key(10), None);
        assert_eq!(RendererKind::from_window_key(1), Some(RendererKind::DEFAULT), "the default is on key 1");
        assert!((1..=9).all(|k| RendererKind::from_window_key(k).is_some()), "keys 1–9 each draw");
        assert!("nope".parse::<RendererKind>().is_err());
        assert_eq!(RendererKind::points(2), Some(RendererKind::Points2));
        assert_eq!(RendererKind::points(4), None);
    }

    #[test]
    fn every_role_is_filled() {
        assert_eq!(RendererKind::DEFAULT.role(), Role::Product);
        assert_eq!(RendererKind::SpheresScalar.role(), Role::Reference, "the oracle of the exact renderers");
        assert_eq!(RendererKind::SpheresLayers.role(), Role::Reference, "the oracle of splat-layers");
        let products: usize = REGISTRY.iter().filter(|r| r.role == Role::Product).count();
        assert_eq!(products, 2);
    }
}
