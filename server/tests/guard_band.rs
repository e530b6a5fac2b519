//! Guard bands: the displayed region of a frame rendered for a guard-band camera is
//! the frame rendered for the display camera (the rays agree up to float rounding), and the
//! guard frame costs more samples.

use volwarp_core::guard::GuardBand;
use volwarp_core::wire::CameraRequest;
use volwarp_core::{Heuristic, Image};
use volwarp_server::{Dataset, Marcher};

fn crop(img: &Image, x0: u32, y0: u32, w: u32, h: u32) -> Image {
    let pixels = (0..h).flat_map(|y| (0..w).map(move |x| img.get(x0 + x, y0 + y))).collect();
    Image { width: w, height: h, pixels }
}

#[test]
fn displayed_region_of_a_guard_frame_is_the_plain_frame() {
    let m = Marcher::from_dataset(&Dataset::default_bundled());
    for (size, g) in [(64u32, 0.1f32), (96, 0.25)] {
        let c = m.default_camera(size, size).orbit(20.0, 10.0);
        let gb = GuardBand::new(&c, g, 8192).unwrap();
        let plain = m.render_image(&c);
        let wide = m.render_image(&gb.camera);
        let d = crop(&wide, gb.x0, gb.y0, c.width, c.height).diff(&plain).unwrap();
        // Rays equal to ~1e-7 radians: the same marched samples except where a ray grazes a
        // voxel boundary at the step's rounding.
        assert!(d.identical_share() > 0.99, "{size}² g={g}: {d:?}");
        assert!(d.max_channel_diff <= 8, "{size}² g={g}: {d:?}");
        let req =
            |camera| CameraRequest { seq: 1, camera, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 };
        let (n_plain, n_wide) =
            (m.render_frame(&req(c)).0.samples.len(), m.render_frame(&req(gb.camera)).0.samples.len());
        assert!(n_wide >= n_plain, "{n_wide} < {n_plain}");
    }
}
