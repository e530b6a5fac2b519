//! Axis-aligned orientations: the voxel reordering that puts a volume whose file axes point
//! along (permuted, possibly negated) patient axes into the LPS order of the volume box.
//!
//! A file's orientation is given as the world vector of one voxel step along each file axis
//! (the columns of its affine matrix, in DICOM patient space LPS: +x towards the patient's
//! left, +y posterior, +z superior). An axis-aligned orientation maps every file axis onto one
//! world axis; the volume is then reordered so that its x, y and z run along +L, +P and +S
//! with the spacing of the matching file axis. Oblique orientations (a file axis between world
//! axes) are refused: the volume box is axis-aligned and resampling is not done.

use super::VolumeError;
use volwarp_core::Vec3;

/// Largest off-axis share of a direction still taken as axis-aligned (relative to its length;
/// writers round cosines to about 6 digits).
const OFF_AXIS: f64 = 1e-4;

/// The reordering of an axis-aligned orientation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reorient {
    /// `perm[a]`: the file axis that becomes world axis `a`.
    pub perm: [usize; 3],
    /// World axis `a` runs against its file axis.
    pub flip: [bool; 3],
    /// Spacing along the world axes.
    pub spacing: Vec3,
}

impl Reorient {
    /// True where the file is already in LPS order.
    pub fn is_identity(&self) -> bool {
        self.perm == [0, 1, 2] && self.flip == [false; 3]
    }

    /// A short description: `file axes (-i, -j, +k) as LPS (x, y, z)`, or `none` (the stored
    /// order is LPS).
    pub fn describe(&self) -> String {
        if self.is_identity() {
            return "none (the stored order is LPS)".into();
        }
        let axis = |a: usize| format!("{}{}", if self.flip[a] { '-' } else { '+' }, ["i", "j", "k"][self.perm[a]]);
        format!("file axes ({}, {}, {}) as LPS (x, y, z)", axis(0), axis(1), axis(2))
    }

    /// The dims after reordering.
    pub fn dims(&self, dims: [u32; 3]) -> [u32; 3] {
        self.perm.map(|p| dims[p])
    }

    /// Reorders x-fastest `values` of a file of `dims` voxels (`values.len()` their product);
    /// the identity hands `values` back without a copy.
    pub fn apply<T: Copy>(&self, values: Vec<T>, dims: [u32; 3]) -> Vec<T> {
        if self.is_identity() {
            return values;
        }
        let stride_in = [1, dims[0] as usize, dims[0] as usize * dims[1] as usize];
        let out_dims = self.dims(dims).map(|d| d as usize);
        // For each world axis: the step in the input and the input offset of its first voxel.
        let mut step = [0isize; 3];
        let mut start = 0usize;
        for a in 0..3 {
            let s = stride_in[self.perm[a]];
            if self.flip[a] {
                start += (out_dims[a] - 1) * s;
                step[a] = -(s as isize);
            } else {
                step[a] = s as isize;
            }
        }
        let mut out = Vec::with_capacity(values.len());
        let mut pk = start as isize;
        for _ in 0..out_dims[2] {
            let mut pj = pk;
            for _ in 0..out_dims[1] {
                let mut pi = pj;
                for _ in 0..out_dims[0] {
                    out.push(values[pi as usize]);
                    pi += step[0];
                }
                pj += step[1];
            }
            pk += step[2];
        }
        out
    }
}

/// The reordering for file axes whose voxel steps are the world (LPS) vectors `cols`, or an
/// error naming the oblique axis.
pub fn axis_aligned(cols: [[f64; 3]; 3]) -> Result<Reorient, VolumeError> {
    let mut perm = [usize::MAX; 3];
    let mut flip = [false; 3];
    let mut spacing = [0f32; 3];
    for (i, c) in cols.iter().enumerate() {
        let len = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
        if !(len.is_finite() && len > 0.0) {
            return Err(VolumeError::unsupported(format!(
                "file axis {} has the direction ({}, {}, {}), not a finite non-zero vector",
                ["i", "j", "k"][i],
                c[0],
                c[1],
                c[2]
            )));
        }
        let a = (0..3).max_by(|&x, &y| c[x].abs().total_cmp(&c[y].abs())).unwrap_or(0);
        let oblique = (0..3).any(|b| b != a && c[b].abs() > OFF_AXIS * len);
        if oblique || perm[a] != usize::MAX {
            return Err(VolumeError::unsupported(format!(
                "oblique orientation: file axis {} points along ({:.4}, {:.4}, {:.4}) in LPS; only axis-aligned \
                 orientations (permutations and flips of the axes) are read, resample the volume first",
                ["i", "j", "k"][i],
                c[0] / len,
                c[1] / len,
                c[2] / len
            )));
        }
        perm[a] = i;
        flip[a] = c[a] < 0.0;
        spacing[a] = len as f32;
    }
    Ok(Reorient { perm, flip, spacing: Vec3::from(spacing) })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn permutes_and_flips() {
        // File axes: i along -y (2 mm), j along +z (3 mm), k along -x (1 mm).
        let r = axis_aligned([[0.0, -2.0, 0.0], [0.0, 0.0, 3.0], [-1.0, 0.0, 0.0]]).unwrap();
        assert_eq!(r.perm, [2, 0, 1]);
        assert_eq!(r.flip, [true, true, false]);
        assert_eq!(r.spacing, Vec3::new(1.0, 2.0, 3.0));
        let dims = [2, 3, 4];
        let values: Vec<usize> = (0..24).collect();
        let out = r.apply(values, dims);
        let od = r.dims(dims);
        assert_eq!(od, [4, 2, 3]);
        for z in 0..3 {
            for y in 0..2 {
                for x in 0..4 {
                    // world x = -k, y = -i, z = +j
                    let (i, j, k) = (1 - y, z, 3 - x);
                    assert_eq!(out[(z * 2 + y) * 4 + x], (k * 3 + j) * 2 + i);
                }
            }
        }
        // Flips alone (NRRD's negative space directions).
        let flips = Reorient { perm: [0, 1, 2], flip: [true, false, true], spacing: Vec3::ONE };
        assert_eq!(flips.apply((0..8).collect(), [2, 2, 2]), [5, 4, 7, 6, 1, 0, 3, 2]);
        assert!(axis_aligned([[1.0, 0.1, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]).is_err());
        assert!(axis_aligned([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]).is_err());
        assert!(axis_aligned([[f64::NAN, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]).is_err());
    }
}
