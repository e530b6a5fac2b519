//! Reading a [`Volume`]: voxels and trilinear samples between voxel centres, clamped to the
//! volume (see the [module docs](super) for the volume's place in world space).

use super::Volume;
use volwarp_core::Vec3;

impl Volume {
    /// The normalized value of voxel `(i, j, k)` (clamped to the volume).
    #[inline]
    pub fn voxel(&self, i: u32, j: u32, k: u32) -> f32 {
        let [nx, ny, nz] = self.dims;
        let (i, j, k) = (i.min(nx - 1) as usize, j.min(ny - 1) as usize, k.min(nz - 1) as usize);
        self.data()[i + nx as usize * (j + ny as usize * k)]
    }

    /// Trilinear sample at continuous voxel coordinates `g` (voxel centres at integers),
    /// clamped to the volume.
    #[inline(always)]
    pub fn sample_grid(&self, g: Vec3) -> f32 {
        let [nx, ny, nz] = self.dims;
        // Fast path: strictly inside the lattice of voxel centres, all eight neighbours exist.
        if g.x >= 0.0
            && g.y >= 0.0
            && g.z >= 0.0
            && g.x < (nx - 1) as f32
            && g.y < (ny - 1) as f32
            && g.z < (nz - 1) as f32
        {
            let (x0, y0, z0) = (g.x as u32 as usize, g.y as u32 as usize, g.z as u32 as usize);
            let (fx, fy, fz) = (g.x - x0 as f32, g.y - y0 as f32, g.z - z0 as f32);
            let sy = nx as usize;
            let sz = nx as usize * ny as usize;
            let base = x0 + sy * y0 + sz * z0;
            if let Some(c) = self.data().get(base..base + sz + sy + 2) {
                let corners = [c[0], c[1], c[sy], c[sy + 1], c[sz], c[sz + 1], c[sz + sy], c[sz + sy + 1]];
                return trilinear(corners, fx, fy, fz);
            }
        }
        self.sample_grid_clamped(g)
    }

    /// [`Volume::sample_grid`] without the fast path for points strictly inside the lattice of
    /// voxel centres (same arithmetic, so the same result; the reference in tests).
    #[inline]
    pub fn sample_grid_clamped(&self, g: Vec3) -> f32 {
        let [nx, ny, nz] = self.dims;
        let gx = g.x.max(0.0).min((nx - 1) as f32); // NaN -> 0
        let gy = g.y.max(0.0).min((ny - 1) as f32); // NaN -> 0
        let gz = g.z.max(0.0).min((nz - 1) as f32); // NaN -> 0
        let (x0, y0, z0) = (gx as usize, gy as usize, gz as usize);
        let (fx, fy, fz) = (gx - x0 as f32, gy - y0 as f32, gz - z0 as f32);
        let sx = usize::from(x0 + 1 < nx as usize);
        let sy = if y0 + 1 < ny as usize { nx as usize } else { 0 };
        let sz = if z0 + 1 < nz as usize { nx as usize * ny as usize } else { 0 };
        let base = x0 + nx as usize * (y0 + ny as usize * z0);
        let d = self.data();
        let (Some(&c000), Some(&c100), Some(&c010), Some(&c110)) =
            (d.get(base), d.get(base + sx), d.get(base + sy), d.get(base + sy + sx))
        else {
            return 0.0;
        };
        let b2 = base + sz;
        let (Some(&c001), Some(&c101), Some(&c011), Some(&c111)) =
            (d.get(b2), d.get(b2 + sx), d.get(b2 + sy), d.get(b2 + sy + sx))
        else {
            return 0.0;
        };
        trilinear([c000, c100, c010, c110, c001, c101, c011, c111], fx, fy, fz)
    }

    /// Trilinear sample at world position `p`.
    #[inline]
    pub fn sample(&self, p: Vec3) -> f32 {
        self.sample_grid(p / self.spacing - 0.5)
    }
}

/// Trilinear blend of the corners `[c000, c100, c010, c110, c001, c101, c011, c111]` (x
/// fastest) at fractions `(fx, fy, fz)`: along x, then y, then z.
#[inline(always)]
fn trilinear(c: [f32; 8], fx: f32, fy: f32, fz: f32) -> f32 {
    let c00 = c[0] + (c[1] - c[0]) * fx;
    let c10 = c[2] + (c[3] - c[2]) * fx;
    let c01 = c[4] + (c[5] - c[4]) * fx;
    let c11 = c[6] + (c[7] - c[6]) * fx;
    let c0 = c00 + (c10 - c00) * fy;
    let c1 = c01 + (c11 - c01) * fy;
    c0 + (c1 - c0) * fz
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

    #[test]
    fn fast_path_equals_clamped_path() {
        let v = Volume::from_fn("t", [7, 5, 4], Vec3::new(1.0, 2.0, 0.5), |p| (p.x * 3.1 + p.y * p.z).sin()).unwrap();
        let mut x = 12345u32;
        let mut r = || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x as f32 / u32::MAX as f32
        };
        for _ in 0..20000 {
            let g = Vec3::new(r() * 8.0 - 0.5, r() * 6.0 - 0.5, r() * 5.0 - 0.5);
            assert_eq!(v.sample_grid(g).to_bits(), v.sample_grid_clamped(g).to_bits(), "{g}");
        }
        for g in [Vec3::ZERO, Vec3::new(6.0, 4.0, 3.0), Vec3::new(5.999, 3.999, 2.999), Vec3::new(0.0, 4.0, 1.5)] {
            assert_eq!(v.sample_grid(g).to_bits(), v.sample_grid_clamped(g).to_bits(), "{g}");
        }
    }
}
