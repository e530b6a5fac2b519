//! The interchangeable renderers of the client and their live switching (keys 1–8). Every
//! renderer draws the same scene for the same camera; the GPU tracer is opened lazily the first
//! time it is chosen, and if no adapter can be opened the client says so and keeps the current
//! renderer.

use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::{Camera, Scene};

/// Renderer names in key order: key 1 selects `NAMES[0]`, …, key 8 `NAMES[7]`.
pub const NAMES: [&str; 8] =
    ["spheres-cpu", "points1", "points2", "points3", "splat", "stale", "spheres-gpu", "spheres-scalar"];

/// The name of the GPU tracer.
pub const GPU: &str = "spheres-gpu";

/// All renderers of a client, created on first use.
pub struct Renderers {
    threads: usize,
    slots: Vec<Option<Box<dyn Renderer>>>,
    current: usize,
    gpu_error: Option<String>,
}

fn create(name: &str, threads: usize) -> Result<Box<dyn Renderer>, String> {
    if name == GPU {
        return create_gpu();
    }
    match volwarp_cpu_tracer::renderer_by_name(name, threads) {
        Some(r) => Ok(r),
        None => Err(format!("unknown renderer `{name}`")),
    }
}

#[cfg(feature = "gpu")]
fn create_gpu() -> Result<Box<dyn Renderer>, String> {
    log::info!("opening the GPU tracer ...");
    let t = std::time::Instant::now();
    let tracer = volwarp_gpu_tracer::GpuTracer::new().map_err(|e| e.to_string())?;
    log::info!("GPU tracer ready on {} ({:.0} ms)", tracer.context().describe(), t.elapsed().as_secs_f64() * 1e3);
    Ok(Box::new(tracer))
}

#[cfg(not(feature = "gpu"))]
fn create_gpu() -> Result<Box<dyn Renderer>, String> {
    Err("this client was built without the `gpu` feature".into())
}

impl Renderers {
    /// The renderers, starting with `name` (created now: an unusable GPU is an error here).
    pub fn new(name: &str, threads: usize) -> Result<Renderers, String> {
        let current = NAMES.iter().position(|n| *n == name).ok_or_else(|| format!("unknown renderer `{name}`"))?;
        let mut slots: Vec<Option<Box<dyn Renderer>>> = NAMES.iter().map(|_| None).collect();
        slots[current] = Some(create(name, threads)?);
        Ok(Renderers { threads, slots, current, gpu_error: None })
    }

    /// Switches to `name`, creating it on first use. On failure (no GPU adapter) the current
    /// renderer stays and the reason is returned (and logged once).
    pub fn select(&mut self, name: &str) -> Result<(), String> {
        let i = NAMES.iter().position(|n| *n == name).ok_or_else(|| format!("unknown renderer `{name}`"))?;
        if self.slots[i].is_none() {
            if name == GPU {
                if let Some(e) = &self.gpu_error {
                    return Err(e.clone());
                }
            }
            match create(name, self.threads) {
                Ok(r) => self.slots[i] = Some(r),
                Err(e) => {
                    let e = format!("{name} unavailable: {e}; staying on {}", self.name());
                    log::warn!("{e}");
                    if name == GPU {
                        self.gpu_error = Some(e.clone());
                    }
                    return Err(e);
                }
            }
        }
        if i != self.current {
            log::info!("renderer: {name}");
        }
        self.current = i;
        Ok(())
    }

    /// Switches to the renderer of key `1..=8`.
    pub fn select_key(&mut self, key: usize) -> Result<(), String> {
        match key.checked_sub(1).and_then(|i| NAMES.get(i)) {
            Some(name) => self.select(name),
            None => Err(format!("no renderer on key {key}")),
        }
    }

    /// The current renderer's name.
    pub fn name(&self) -> &'static str {
        NAMES[self.current]
    }

    /// Draws `scene` for `camera` with the current renderer.
    pub fn render(&mut self, scene: &Scene, camera: &Camera, out: &mut Image) {
        match self.slots[self.current].as_mut() {
            Some(r) => r.render(scene, camera, out),
            None => out.reset_for(camera),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use volwarp_cpu_tracer::synthetic::depth_image_frame;

    #[test]
    fn switching_keeps_names_and_draws_the_same_spheres() {
        let frame = depth_image_frame(48, 1.0, 7);
        let scene = Scene::build(&frame);
        let cam = frame.header.camera.orbit(8.0, 4.0);
        let mut r = Renderers::new("spheres-cpu", 1).unwrap();
        let mut a = Image::new(1, 1);
        r.render(&scene, &cam, &mut a);
        r.select_key(8).unwrap();
        assert_eq!(r.name(), "spheres-scalar");
        let mut b = Image::new(1, 1);
        r.render(&scene, &cam, &mut b);
        assert_eq!(a, b, "packet and scalar tracers draw the same image");
        assert!(a.pixels.iter().any(|&p| p != volwarp_core::BACKGROUND));
        for k in 1..=6 {
            r.select_key(k).unwrap();
            assert_eq!(r.name(), NAMES[k - 1]);
        }
        assert!(r.select_key(9).is_err());
        assert!(r.select("nope").is_err());
    }
}
