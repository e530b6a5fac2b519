//! One definition of every layout the shaders share with Rust: `prelude.wgsl` declares
//! `Node`, `RayBasis`, the packed sample, the uniforms and the shared functions once, and
//! [`shader`] prepends it to each shader's source at pipeline creation. The tests here parse the
//! prelude's structs, lay them out by WGSL's rules (alignment and size of each type, struct
//! alignment = largest member's, size rounded up to it) and compare every field's offset and
//! every struct's size with the Rust `#[repr(C)]` types (`offset_of!`, `size_of`).

/// The shared WGSL prelude.
pub const PRELUDE: &str = include_str!("prelude.wgsl");

/// `body` with the prelude in front: the source of a pipeline's shader module.
pub fn shader(body: &str) -> String {
    let mut s = String::with_capacity(PRELUDE.len() + body.len() + 1);
    s.push_str(PRELUDE);
    s.push('\n');
    s.push_str(body);
    s
}

/// A shader that scans across its workgroup: the prelude, then the workgroup scan of `scan`
/// (`crate::scan`), then `body`.
pub fn shader_with_scan(body: &str, scan: crate::WgScanKind) -> String {
    shader(&format!("{}\n{body}", scan.source()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layer_splat::LayerParams;
    use crate::lbvh::BuildParams;
    use crate::splat::SplatParams;
    use crate::tracer::TraceParams;
    use std::collections::HashMap;
    use std::mem::{offset_of, size_of};
    use volwarp_core::lbvh::Node;
    use volwarp_core::RayBasis;

    /// A struct as WGSL lays it out: `(field, offset)` in order, its alignment and size.
    #[derive(Debug, Clone)]
    struct WgslStruct {
        fields: Vec<(String, usize)>,
        align: usize,
        size: usize,
    }

    /// (alignment, size) of a WGSL type, structs looked up in `known`.
    fn type_layout(ty: &str, known: &HashMap<String, WgslStruct>, aliases: &HashMap<String, String>) -> (usize, usize) {
        if let Some(t) = aliases.get(ty) {
            return type_layout(t, known, aliases);
        }
        match ty {
            "u32" | "i32" | "f32" => (4, 4),
            "vec2<u32>" | "vec2<i32>" | "vec2<f32>" => (8, 8),
            "vec3<u32>" | "vec3<i32>" | "vec3<f32>" => (16, 12),
            "vec4<u32>" | "vec4<i32>" | "vec4<f32>" => (16, 16),
            other => {
                let s = known.get(other).unwrap_or_else(|| panic!("unknown WGSL type {other}"));
                (s.align, s.size)
            }
        }
    }

    /// Every struct of `src`, laid out.
    fn parse(src: &str) -> HashMap<String, WgslStruct> {
        let mut known = HashMap::new();
        let mut aliases = HashMap::new();
        let mut lines = src.lines().map(|l| l.split("//").next().unwrap_or("").trim());
        while let Some(line) = lines.next() {
            if let Some(rest) = line.strip_prefix("alias ") {
                let (name, ty) = rest.trim_end_matches(';').split_once('=').expect("alias = type");
                aliases.insert(name.trim().to_string(), ty.trim().to_string());
                continue;
            }
            let Some(name) = line.strip_prefix("struct ") else { continue };
            let name = name.trim_end_matches('{').trim().to_string();
            let (mut fields, mut offset, mut align) = (Vec::new(), 0usize, 1usize);
            for line in lines.by_ref() {
                if line.starts_with('}') {
                    break;
                }
                if line.is_empty() {
                    continue;
                }
                let (field, ty) = line.trim_end_matches(',').split_once(':').expect("field: type");
                let (a, s) = type_layout(ty.trim(), &known, &aliases);
                offset = offset.next_multiple_of(a);
                fields.push((field.trim().to_string(), offset));
                offset += s;
                align = align.max(a);
            }
            known.insert(name, WgslStruct { fields, align, size: offset.next_multiple_of(align) });
        }
        known
    }

    /// Asserts that WGSL struct `name` has exactly `fields` (name, Rust offset) and `size`.
    fn check(structs: &HashMap<String, WgslStruct>, name: &str, size: usize, fields: &[(&str, usize)]) {
        let s = structs.get(name).unwrap_or_else(|| panic!("the prelude declares {name}"));
        let got: Vec<(&str, usize)> = s.fields.iter().map(|(f, o)| (f.as_str(), *o)).collect();
        assert_eq!(got, fields, "{name}: WGSL field offsets vs the Rust #[repr(C)] type");
        assert_eq!(s.size, size, "{name}: WGSL size vs the Rust size");
    }

    macro_rules! fields {
        ($t:ty: $($f:ident),*) => { &[$((stringify!($f), offset_of!($t, $f))),*] };
    }

    #[test]
    fn prelude_layouts_match_the_rust_types() {
        let s = parse(PRELUDE);
        check(&s, "Node", size_of::<Node>(), fields!(Node: min, left, max, right));
        check(&s, "RayBasis", size_of::<RayBasis>(), fields!(RayBasis: eye, corner, du, dv));
        check(
            &s,
            "TraceParams",
            size_of::<TraceParams>(),
            fields!(TraceParams: basis, deq_min, deq_step, width, height, n, background),
        );
        check(
            &s,
            "BuildParams",
            size_of::<BuildParams>(),
            fields!(BuildParams: n, shift, blocks, count, deq_min, deq_step),
        );
        check(
            &s,
            "SplatParams",
            size_of::<SplatParams>(),
            fields!(SplatParams: trace, u, v, w, px, mode, pad0, pad1, pad2),
        );
        check(
            &s,
            "LayerParams",
            size_of::<LayerParams>(),
            fields!(LayerParams: eye, u, v, w, src_eye, src_w, su, sv, bu, bv, e, proj, deq_min, deq_step, basis,
                f_eye, f_u, f_v, f_w, f_proj, k, k2, width, height, n, min_alpha, f_width, f_height, background, cap,
                off_spans, off_sums, only_empty, opacity_limit),
        );
        // The packed sample: one little-endian u64 read as two u32 words.
        let aliases: Vec<&str> = PRELUDE.lines().filter(|l| l.starts_with("alias PackedSample")).collect();
        assert_eq!(aliases, ["alias PackedSample = vec2<u32>;"]);
        assert_eq!(size_of::<u64>(), 8);
    }

    #[test]
    fn the_parser_applies_wgsl_alignment_rules() {
        // vec3 aligns to 16 but is 12 long, so a following u32 packs in after it; a struct's
        // size rounds up to its alignment; a nested struct aligns as its largest member.
        let s = parse(
            "struct A {\n    a: u32,\n    b: vec3<f32>, // comment\n    c: u32,\n}\n\n\
             struct B {\n    x: u32,\n    y: A,\n    z: vec2<u32>,\n}\n",
        );
        let a = &s["A"];
        assert_eq!(a.fields, vec![("a".into(), 0), ("b".into(), 16), ("c".into(), 28)]);
        assert_eq!((a.align, a.size), (16, 32));
        let b = &s["B"];
        assert_eq!(b.fields, vec![("x".into(), 0), ("y".into(), 16), ("z".into(), 48)]);
        assert_eq!((b.align, b.size), (16, 64));
    }

    #[test]
    fn every_shader_is_built_on_the_prelude() {
        for body in [
            include_str!("trace.wgsl"),
            include_str!("lbvh.wgsl"),
            include_str!("splat.wgsl"),
            include_str!("layer_splat.wgsl"),
        ] {
            for s in [
                "struct Node",
                "struct RayBasis",
                "struct TraceParams",
                "struct BuildParams",
                "struct SplatParams",
                "struct LayerParams",
                "alias ",
            ] {
                assert!(!body.contains(s), "a shader redeclares `{s}`: it belongs in prelude.wgsl only");
            }
            assert!(shader(body).starts_with(PRELUDE));
        }
    }
}
