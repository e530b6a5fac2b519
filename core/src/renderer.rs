//! The one interface every way of drawing a scene implements (feature `alloc`): the SIMD and
//! scalar sphere tracers, the point and splat baselines, the stale image and the GPU tracer.
//! Scene + camera + framebuffer in, image out.

use crate::camera::Camera;
use crate::renderer_kind::RendererKind;
use crate::scene::Scene;
use alloc::vec;
use alloc::vec::Vec;

pub use crate::sample::BACKGROUND;

/// An RGBA8 image: pixels packed like sample colors (R in the low byte), row-major, row 0 at
/// the top.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Image {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width × height` packed RGBA8 pixels.
    pub pixels: Vec<u32>,
}

impl Image {
    /// An image filled with [`BACKGROUND`].
    pub fn new(width: u32, height: u32) -> Self {
        Image { width, height, pixels: vec![BACKGROUND; width as usize * height as usize] }
    }

    /// Resizes to the camera's viewport (if needed) and fills with [`BACKGROUND`].
    pub fn reset_for(&mut self, camera: &Camera) {
        self.pixels.clear();
        self.size_for(camera);
    }

    /// Sizes the image to `camera`'s viewport *without* clearing it (pixels it keeps hold
    /// whatever they held, new ones the background): for a renderer that writes every pixel,
    /// which then need not clear ([`Image::reset_for`]) first.
    pub fn size_for(&mut self, camera: &Camera) {
        self.width = camera.width;
        self.height = camera.height;
        self.pixels.resize(camera.width as usize * camera.height as usize, BACKGROUND);
    }

    /// What a renderer draws for a camera it cannot use: the background at the camera's
    /// viewport if that is within `1..=max_viewport` on both axes, otherwise an empty (0×0)
    /// image, so a bad camera never makes a renderer allocate.
    pub fn reset_for_unusable(&mut self, camera: &Camera, max_viewport: u32) {
        if (1..=max_viewport).contains(&camera.width) && (1..=max_viewport).contains(&camera.height) {
            self.reset_for(camera);
        } else {
            self.width = 0;
            self.height = 0;
            self.pixels.clear();
        }
    }

    /// The pixel at `(x, y)`.
    pub fn get(&self, x: u32, y: u32) -> u32 {
        self.pixels[(y * self.width + x) as usize]
    }

    /// The pixels as RGBA bytes (for PNG encoders).
    pub fn as_rgba_bytes(&self) -> &[u8] {
        bytemuck::cast_slice(&self.pixels)
    }
}

/// A way of drawing a [`Scene`] for a camera.
pub trait Renderer {
    /// Which renderer of the [`RendererKind`] registry this is.
    fn kind(&self) -> RendererKind;

    /// Its name, as used in CSV files and the client's title bar (e.g. `spheres-cpu`).
    fn name(&self) -> &'static str {
        self.kind().name()
    }

    /// Draws `scene` as seen from `camera` into `out`, which it first resizes to the camera's
    /// viewport and clears to [`BACKGROUND`].
    fn render(&mut self, scene: &Scene, camera: &Camera, out: &mut Image);

    /// Draws the newest of `scenes` (newest first) for `camera` and, where this renderer keeps
    /// frames ([`Renderer::keeps_frames`]), fills what it leaves uncovered from the older ones
    /// (the multi-frame filling). By default it draws the newest alone; with no scene
    /// `out` is left empty (0×0).
    fn render_set(&mut self, scenes: &[&Scene], camera: &Camera, out: &mut Image) {
        match scenes.first() {
            Some(s) => self.render(s, camera, out),
            None => out.reset_for_unusable(camera, 0),
        }
    }

    /// Whether [`Renderer::render_set`] uses the older frames (by default it does not).
    fn keeps_frames(&self) -> bool {
        false
    }

    /// Sizes spheres by the warp (core's [`crate::warp_radius`]: half the footprint at the
    /// frame's own camera, the frame's radius from a 10° turn on) when `on`. Returns whether
    /// this renderer can (by default it cannot and draws the frame's radii).
    fn set_adaptive_radius(&mut self, on: bool) -> bool {
        let _ = on;
        false
    }
}
