//! What the client shows: the methods a session compares. A method draws the newest frame it
//! holds for the camera of now. Adding a method is one entry of [`METHODS`].

use crate::ErrorBox;
use volwarp_core::renderer::Renderer;
use volwarp_core::wire::Frame;
use volwarp_core::{Camera, Image, RendererKind, Scene};

/// A frame the client holds, with its scene built once for every method.
pub struct HeldFrame {
    /// The frame as received.
    pub frame: Frame,
    /// Its sphere scene (LBVH built once).
    pub scene: Scene,
}

impl HeldFrame {
    /// Builds the scene of a frame.
    pub fn new(frame: Frame) -> HeldFrame {
        let scene = volwarp_cpu_tracer::build_scene(&frame);
        HeldFrame { frame, scene }
    }
}

/// One way of showing the frames the client holds.
pub trait Method {
    /// The method's name (CSV, charts).
    fn name(&self) -> &str;
    /// Draws the frames for `camera`; `frames` holds the received frames, newest last (a
    /// single-frame method uses the last one; multi-frame methods of later issues use more).
    fn draw(&mut self, frames: &[&HeldFrame], camera: &Camera, out: &mut Image);
}

/// A method that is one renderer of the registry drawing the newest frame.
pub struct RendererMethod {
    name: String,
    renderer: Box<dyn Renderer + Send>,
}

impl Method for RendererMethod {
    fn name(&self) -> &str {
        &self.name
    }
    fn draw(&mut self, frames: &[&HeldFrame], camera: &Camera, out: &mut Image) {
        match frames.last() {
            Some(f) => self.renderer.render(&f.scene, camera, out),
            None => out.reset_for(camera),
        }
    }
}

/// A registry entry: the name and how to make the method with `threads` threads.
pub struct MethodInfo {
    /// CSV name.
    pub name: &'static str,
    /// What it is.
    pub about: &'static str,
    /// Makes the method.
    pub make: fn(threads: usize) -> Box<dyn Method>,
}

fn renderer(kind: RendererKind, threads: usize) -> Box<dyn Method> {
    let renderer = volwarp_cpu_tracer::create(kind, threads).expect("a CPU renderer of the registry");
    Box::new(RendererMethod { name: kind.name().into(), renderer })
}

/// Every method a session can compare, in the order of the CSV.
pub const METHODS: [MethodInfo; 6] = [
    MethodInfo {
        name: "stale",
        about: "the last frame as rendered (a send-image system)",
        make: |t| renderer(RendererKind::Stale, t),
    },
    MethodInfo { name: "points1", about: "ZAL12 2.5D points, 1 px", make: |t| renderer(RendererKind::Points1, t) },
    MethodInfo { name: "points2", about: "ZAL12 2.5D points, 2 px", make: |t| renderer(RendererKind::Points2, t) },
    MethodInfo { name: "points3", about: "ZAL12 2.5D points, 3 px", make: |t| renderer(RendererKind::Points3, t) },
    MethodInfo {
        name: "spheres-cpu",
        about: "the SIMD packet sphere tracer",
        make: |t| renderer(RendererKind::SpheresCpu, t),
    },
    MethodInfo { name: "splat", about: "exact sphere splatting", make: |t| renderer(RendererKind::Splat, t) },
];

/// The methods of a comma-separated list (`all`: every one of [`METHODS`]).
pub fn make_methods(list: &str, threads: usize) -> Result<Vec<Box<dyn Method>>, ErrorBox> {
    if list == "all" {
        return Ok(METHODS.iter().map(|m| (m.make)(threads)).collect());
    }
    list.split(',')
        .map(|n| {
            let n = n.trim();
            METHODS.iter().find(|m| m.name == n).map(|m| (m.make)(threads)).ok_or_else(|| {
                let names: Vec<&str> = METHODS.iter().map(|m| m.name).collect();
                format!("unknown method {n:?}; one of {} or all", names.join(", ")).into()
            })
        })
        .collect()
}
