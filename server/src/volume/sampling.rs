//! Reading a [`Volume`]: voxels and trilinear samples between voxel centres, clamped to the
//! volume (see the [module docs](super) for its place in world space and the normalization).

use super::Volume;
use volwarp_core::Vec3;

/// `g` clamped to `[lo, hi]` per axis, a NaN coordinate to `lo`: where the samplers of a
/// clamp range read.
#[inline(always)]
fn clamp_grid(g: Vec3, lo: Vec3, hi: Vec3) -> Vec3 {
    Vec3::new(g.x.max(lo.x).min(hi.x), g.y.max(lo.y).min(hi.y), g.z.max(lo.z).min(hi.z))
}

impl Volume {
    /// The normalized value of voxel `(i, j, k)` (clamped to the volume).
    #[inline]
    pub fn voxel(&self, i: u32, j: u32, k: u32) -> f32 {
        let [nx, ny, nz] = self.dims;
        (self.voxels.get(i.min(nx - 1), j.min(ny - 1), k.min(nz - 1)) - self.offset) * self.scale
    }

    /// Trilinear sample at continuous voxel coordinates `g` (voxel centres at integers),
    /// clamped to the volume: the stored values blended, then normalized. The packet marcher
    /// computes the same bits in lanes.
    #[inline(always)]
    pub fn sample_grid(&self, g: Vec3) -> f32 {
        let [nx, ny, nz] = self.dims;
        self.sample_grid_in(g, Vec3::ZERO, Vec3::new((nx - 1) as f32, (ny - 1) as f32, (nz - 1) as f32))
    }

    /// [`Volume::sample_grid`] with `g` clamped to `[lo, hi]` instead of the whole volume
    /// (`0 ≤ lo ≤ hi ≤ dims − 1`; a crop box's voxels): a cropped volume's sample reads no voxel
    /// outside the crop beyond what its trilinear stencil needs at a fraction of zero.
    #[inline(always)]
    pub fn sample_grid_in(&self, g: Vec3, lo: Vec3, hi: Vec3) -> f32 {
        let Vec3 { x: gx, y: gy, z: gz } = clamp_grid(g, lo, hi);
        let (x0, y0, z0) = (gx as u32, gy as u32, gz as u32);
        let (fx, fy, fz) = (gx - x0 as f32, gy - y0 as f32, gz - z0 as f32);
        let c = self.voxels.corners(x0, y0, z0);
        (trilinear(c, fx, fy, fz) - self.offset) * self.scale
    }

    /// The central-difference gradient of the trilinear field at continuous voxel coordinates
    /// `g` (clamped to `[lo, hi]` as [`Volume::sample_grid_in`] clamps), one voxel either side
    /// along each axis: per axis `(s(g + e) − s(g − e))` in normalized units (not halved), `e`
    /// the axis' unit voxel step. What the shading marchers take as the gradient; the packet
    /// marcher computes the same bits in lanes.
    ///
    /// The six shifted samples share the fractions of `g` and the voxels of its stencil: along
    /// x they are the trilinear blends of the stencils whose lowest corner is one voxel lower
    /// and one voxel higher, along y and z the blends of the stencil's own rows and slices and
    /// those one beyond, in `trilinear`'s order (x, then y, then z). Every voxel read is
    /// clamped to `floor(lo) ..= ceil(hi)`, the voxels the samples in the range read. In the
    /// volume's interior this is exactly the difference of the trilinear samples at `g ± e`
    /// (up to rounding); at the clamp range's edge, as there, the read beyond the edge repeats
    /// the edge voxel. Sharing the stencil reads 32 voxels instead of 48 and needs no second
    /// brick lookup per sample in the packet marcher.
    #[inline]
    pub fn gradient_grid_in(&self, g: Vec3, lo: Vec3, hi: Vec3) -> Vec3 {
        let Vec3 { x: gx, y: gy, z: gz } = clamp_grid(g, lo, hi);
        let (x0, y0, z0) = (gx as i32, gy as i32, gz as i32);
        let (fx, fy, fz) = (gx - x0 as f32, gy - y0 as f32, gz - z0 as f32);
        let (ilo, ihi) = (lo.floor(), hi.ceil());
        let (ilo, ihi) = ([ilo.x as i32, ilo.y as i32, ilo.z as i32], [ihi.x as i32, ihi.y as i32, ihi.z as i32]);
        let at = |x: i32, y: i32, z: i32| {
            let c = |v: i32, a: usize| v.max(ilo[a]).min(ihi[a]) as u32;
            self.voxels.get(c(x, 0), c(y, 1), c(z, 2))
        };
        let lerp = |a: f32, b: f32, f: f32| a + (b - a) * f;
        // A row along x at (y, z), blended at fx, its lowest voxel x.
        let row = |x: i32, y: i32, z: i32| lerp(at(x, y, z), at(x + 1, y, z), fx);
        // The stencil's own rows.
        let (m00, m10, m01, m11) = (row(x0, y0, z0), row(x0, y0 + 1, z0), row(x0, y0, z0 + 1), row(x0, y0 + 1, z0 + 1));
        // x: the stencils one voxel lower and higher.
        let yz = |x: i32| {
            let (r00, r10, r01, r11) = (row(x, y0, z0), row(x, y0 + 1, z0), row(x, y0, z0 + 1), row(x, y0 + 1, z0 + 1));
            lerp(lerp(r00, r10, fy), lerp(r01, r11, fy), fz)
        };
        let dx = yz(x0 + 1) - yz(x0 - 1);
        // y: the rows one below and two above the stencil's lowest.
        let (a0, a1) = (row(x0, y0 - 1, z0), row(x0, y0 - 1, z0 + 1));
        let (b0, b1) = (row(x0, y0 + 2, z0), row(x0, y0 + 2, z0 + 1));
        let ylo = lerp(lerp(a0, m00, fy), lerp(a1, m01, fy), fz);
        let yhi = lerp(lerp(m10, b0, fy), lerp(m11, b1, fy), fz);
        let dy = yhi - ylo;
        // z: the slices one below and two above the stencil's lowest.
        let e = lerp(row(x0, y0, z0 - 1), row(x0, y0 + 1, z0 - 1), fy);
        let f = lerp(row(x0, y0, z0 + 2), row(x0, y0 + 1, z0 + 2), fy);
        let (c0, c1) = (lerp(m00, m10, fy), lerp(m01, m11, fy));
        let dz = lerp(c1, f, fz) - lerp(e, c0, fz);
        Vec3::new(dx * self.scale, dy * self.scale, dz * self.scale)
    }

    /// Trilinear sample at world position `p`.
    #[inline]
    pub fn sample(&self, p: Vec3) -> f32 {
        self.sample_grid(p / self.spacing - 0.5)
    }
}

/// The eight corners `[c000, c100, c010, c110, c001, c101, c011, c111]` (x fastest) of the
/// trilinear stencil whose lowest corner is voxel `(x, y, z)`, each read with `at`.
pub(crate) fn stencil(at: impl Fn(u32, u32, u32) -> f32, x: u32, y: u32, z: u32) -> [f32; 8] {
    [
        at(x, y, z),
        at(x + 1, y, z),
        at(x, y + 1, z),
        at(x + 1, y + 1, z),
        at(x, y, z + 1),
        at(x + 1, y, z + 1),
        at(x, y + 1, z + 1),
        at(x + 1, y + 1, z + 1),
    ]
}

/// Trilinear blend of the corners `[c000, c100, c010, c110, c001, c101, c011, c111]` (x
/// fastest) at fractions `(fx, fy, fz)`: along x, then y, then z.
#[inline(always)]
pub(crate) fn trilinear(c: [f32; 8], fx: f32, fy: f32, fz: f32) -> f32 {
    let c00 = c[0] + (c[1] - c[0]) * fx;
    let c10 = c[2] + (c[3] - c[2]) * fx;
    let c01 = c[4] + (c[5] - c[4]) * fx;
    let c11 = c[6] + (c[7] - c[6]) * fx;
    let c0 = c00 + (c10 - c00) * fy;
    let c1 = c01 + (c11 - c01) * fy;
    c0 + (c1 - c0) * fz
}

/// The definition of a sample without bricks: a trilinear sample at continuous voxel coordinates
/// `g` read from `stored` (the stored values of a volume of `dims`, x fastest; see
/// [`super::Voxels::get`]) with clamped corners, blended and normalized with `(offset, scale)`
/// as [`Volume::sample_grid`] defines. The reference the bricked reads are tested against.
pub fn flat_sample(stored: &[f32], dims: [u32; 3], (offset, scale): (f32, f32), g: Vec3) -> f32 {
    let [nx, ny, nz] = dims;
    let gx = g.x.max(0.0).min((nx - 1) as f32);
    let gy = g.y.max(0.0).min((ny - 1) as f32);
    let gz = g.z.max(0.0).min((nz - 1) as f32);
    let (x0, y0, z0) = (gx as u32, gy as u32, gz as u32);
    let at = |x: u32, y: u32, z: u32| {
        let (x, y, z) = (x.min(nx - 1) as usize, y.min(ny - 1) as usize, z.min(nz - 1) as usize);
        stored[x + nx as usize * (y + ny as usize * z)]
    };
    let c = stencil(at, x0, y0, z0);
    (trilinear(c, gx - x0 as f32, gy - y0 as f32, gz - z0 as f32) - offset) * scale
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trilinear_between_centres_and_clamped_outside() {
        let v = Volume::from_values("t", [2, 1, 1], Vec3::ONE, vec![0.0, 10.0]).unwrap();
        assert_eq!(v.value_range(), (0.0, 10.0));
        assert_eq!(v.sample(Vec3::new(0.5, 0.5, 0.5)), 0.0);
        assert_eq!(v.sample(Vec3::new(1.0, 0.5, 0.5)), 0.5);
        assert_eq!(v.sample(Vec3::new(1.5, 0.5, 0.5)), 1.0);
        assert_eq!(v.sample(Vec3::new(2.0, 0.0, 0.0)), 1.0);
        assert_eq!(v.sample(Vec3::new(-5.0, 9.0, f32::NAN)), 0.0);
    }

    /// Uniform numbers in [0, 1] from a xorshift generator seeded with `seed`.
    fn xorshift(mut x: u32) -> impl FnMut() -> f32 {
        move || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x as f32 / u32::MAX as f32
        }
    }

    /// A volume of `dims` with spacing (1, 2, 0.5) stored as 8-bit (`kind` 0), 16-bit (1) or
    /// f32 (2) values.
    fn test_volume(dims: [u32; 3], kind: u32) -> Volume {
        let n = dims.iter().product::<u32>() as usize;
        let values: Vec<f32> = (0..n)
            .map(|i| match kind {
                0 => (i * 37 % 200) as f32,
                1 => (i * 4099 % 60_000) as f32,
                _ => (i as f32 * 0.37).sin(),
            })
            .collect();
        Volume::from_values("t", dims, Vec3::new(1.0, 2.0, 0.5), values).unwrap()
    }

    /// The shared-stencil gradient is the central difference of trilinear samples one voxel
    /// either side (up to rounding), inside the volume, at its edges and in a crop of whole
    /// voxels.
    #[test]
    fn gradient_is_the_central_difference_of_samples() {
        let mut r = xorshift(987654);
        for (dims, kind) in [([7, 5, 4], 0), ([33, 34, 35], 1), ([40, 3, 66], 2), ([1, 2, 1], 0)] {
            let v = test_volume(dims, kind);
            let whole = (Vec3::ZERO, Vec3::new((dims[0] - 1) as f32, (dims[1] - 1) as f32, (dims[2] - 1) as f32));
            let crop = (whole.1 * 0.25).floor();
            let crop = (crop, (whole.1 * 0.75).ceil().max(crop));
            for (lo, hi) in [whole, crop] {
                for _ in 0..5000 {
                    let g = Vec3::new(r(), r(), r()) * (hi - lo + 2.0) + lo - 1.0;
                    let d = v.gradient_grid_in(g, lo, hi);
                    let at = |e: Vec3| v.sample_grid_in(g.clamp(lo, hi) + e, lo, hi);
                    let want =
                        Vec3::new(at(Vec3::X) - at(-Vec3::X), at(Vec3::Y) - at(-Vec3::Y), at(Vec3::Z) - at(-Vec3::Z));
                    assert!((d - want).abs().max_element() <= 1e-5, "{dims:?} {g} {lo} {hi}: {d} against {want}");
                }
            }
        }
    }

    #[test]
    fn bricked_samples_equal_the_flat_reference() {
        let mut r = xorshift(12345);
        // Odd dims, brick edges, 8-bit, 16-bit and f32 storage.
        for (dims, kind) in [([7, 5, 4], 0), ([33, 2, 65], 1), ([65, 33, 1], 2), ([1, 1, 1], 0), ([2, 65, 3], 2)] {
            let n = dims.iter().product::<u32>() as usize;
            let v = test_volume(dims, kind);
            let stored: Vec<f32> = (0..n)
                .map(|i| {
                    let (nx, ny) = (dims[0] as usize, dims[1] as usize);
                    v.voxels().get((i % nx) as u32, (i / nx % ny) as u32, (i / (nx * ny)) as u32)
                })
                .collect();
            for _ in 0..20000 {
                let g = Vec3::new(
                    r() * (dims[0] + 2) as f32 - 1.5,
                    r() * (dims[1] + 2) as f32 - 1.5,
                    r() * (dims[2] + 2) as f32 - 1.5,
                );
                let want = flat_sample(&stored, dims, v.normalization(), g);
                assert_eq!(v.sample_grid(g).to_bits(), want.to_bits(), "{dims:?} {g}");
            }
            for c in [0.0, 31.0, 31.5, 32.0, 32.5, 64.0] {
                let g = Vec3::splat(c);
                assert_eq!(v.sample_grid(g).to_bits(), flat_sample(&stored, dims, v.normalization(), g).to_bits());
            }
        }
    }
}
