//! The production-scale eval scene: a fractal cloud voxelised at run time to
//! `CLOUD_VOXELS^3` f32 voxels (512^3 = 512 MiB, far beyond any CPU cache, so a tracker pays a
//! memory miss per density fetch), deterministic and never stored in git.
//!
//! The field: an ellipsoidal falloff plus five octaves of value noise (lattice values from
//! splitmix64, trilinear with smoothstep weights, frequencies 4 to 64 across the box, each
//! octave half the weight of the one before), thresholded so that the cloud has empty space
//! around it and sharp, billowy edges, then scaled to `CLOUD_DENSITY` at its densest.

use glam::DVec3;
use pin_volume::DenseGrid;
use pinrender::render::splitmix64;
use rayon::prelude::*;

/// Voxels per axis.
pub const CLOUD_VOXELS: u32 = 512;
/// Peak extinction (per unit length; the cloud's box is the unit cube).
pub const CLOUD_DENSITY: f64 = 40.0;
const OCTAVES: [u32; 5] = [4, 8, 16, 32, 64];
const SEED: u64 = 0xC10D;

/// One octave's lattice of `(f + 1)^3` values in [-1, 1].
struct Lattice {
    f: usize,
    v: Vec<f32>,
}

impl Lattice {
    fn new(f: u32, seed: u64) -> Self {
        let f = f as usize;
        let n = f + 1;
        let v = (0..n * n * n)
            .map(|i| {
                let h = splitmix64(seed ^ splitmix64(i as u64));
                ((h >> 40) as f64 / (1u64 << 24) as f64 * 2.0 - 1.0) as f32
            })
            .collect();
        Lattice { f, v }
    }

    /// Value noise at `p` in the unit cube.
    fn at(&self, p: DVec3) -> f64 {
        let n = self.f + 1;
        let q = p * self.f as f64;
        let i = q
            .floor()
            .clamp(DVec3::ZERO, DVec3::splat(self.f as f64 - 1.0));
        let t = q - i;
        // Smoothstep weights: the noise has continuous gradients across lattice cells.
        let s = t * t * (DVec3::splat(3.0) - 2.0 * t);
        let (x, y, z) = (i.x as usize, i.y as usize, i.z as usize);
        let v = |dx: usize, dy: usize, dz: usize| {
            f64::from(self.v[(x + dx) + n * ((y + dy) + n * (z + dz))])
        };
        let lerp = |a: f64, b: f64, t: f64| a + (b - a) * t;
        let x00 = lerp(v(0, 0, 0), v(1, 0, 0), s.x);
        let x10 = lerp(v(0, 1, 0), v(1, 1, 0), s.x);
        let x01 = lerp(v(0, 0, 1), v(1, 0, 1), s.x);
        let x11 = lerp(v(0, 1, 1), v(1, 1, 1), s.x);
        lerp(lerp(x00, x10, s.y), lerp(x01, x11, s.y), s.z)
    }
}

/// The cloud's density at `p` in the unit cube (before scaling to the peak).
fn shape(lattices: &[Lattice], p: DVec3) -> f64 {
    // An ellipsoid flattened in y, 1 at the centre and 0 on its surface.
    let r = (p - DVec3::new(0.5, 0.45, 0.5)) / DVec3::new(0.42, 0.3, 0.42);
    let base = 1.0 - r.length();
    let mut noise = 0.0;
    let mut w = 0.5;
    for l in lattices {
        noise += w * l.at(p);
        w *= 0.5;
    }
    ((base + 0.7 * noise - 0.15) * 2.5).clamp(0.0, 1.0)
}

/// The cloud voxelised to `n^3` voxels over the unit cube (deterministic: the same bytes for
/// any thread count).
pub fn cloud(n: u32) -> anyhow::Result<DenseGrid> {
    voxelise(
        [n; 3],
        1.0 / f64::from(n),
        DVec3::ZERO,
        CLOUD_DENSITY,
        "fractal cloud",
    )
}

/// The same cloud stretched over `dims` voxels of one spacing, `length` units along the
/// longest axis and centred on the origin (the shape fills the box, squeezed along the
/// shorter axes), peak extinction `peak` per unit: a cloud of the cloudscape eval scene, as
/// the production generator's clouds span 10 units whatever their voxel counts.
/// Deterministic.
pub fn stretched_cloud(dims: [u32; 3], length: f64, peak: f64) -> anyhow::Result<DenseGrid> {
    let longest = dims.iter().copied().max().unwrap_or(1).max(1);
    let h = length / f64::from(longest);
    let origin = -DVec3::new(f64::from(dims[0]), f64::from(dims[1]), f64::from(dims[2])) * h * 0.5;
    voxelise(dims, h, origin, peak, "stretched fractal cloud")
}

/// `dims` voxels of edge `h` from `origin`; voxel `i`'s value is the shape at its centre
/// mapped into the unit cube, `(i + 0.5) / dims`, times `peak`.
fn voxelise(
    dims: [u32; 3],
    h: f64,
    origin: DVec3,
    peak: f64,
    what: &str,
) -> anyhow::Result<DenseGrid> {
    let lattices: Vec<Lattice> = OCTAVES
        .iter()
        .enumerate()
        .map(|(k, &f)| Lattice::new(f, splitmix64(SEED + k as u64)))
        .collect();
    let [nx, ny, nz] = dims.map(|d| d as usize);
    // The unit cube's coordinates of a voxel: for a cube, exactly the centre times `h`.
    let inv = DVec3::new(
        1.0 / f64::from(dims[0]),
        1.0 / f64::from(dims[1]),
        1.0 / f64::from(dims[2]),
    );
    let mut data = vec![0.0f32; nx * ny * nz];
    data.par_chunks_mut(nx * ny)
        .enumerate()
        .for_each(|(z, slab)| {
            for (i, v) in slab.iter_mut().enumerate() {
                let p =
                    DVec3::new((i % nx) as f64 + 0.5, (i / nx) as f64 + 0.5, z as f64 + 0.5) * inv;
                *v = (peak * shape(&lattices, p)) as f32;
            }
        });
    Ok(DenseGrid::new(dims, data, DVec3::splat(h), origin, what)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use pin_volume::{Density, DensitySource};

    #[test]
    fn cloud_is_deterministic_bounded_and_has_empty_space() {
        let a = cloud(24).unwrap();
        let b = cloud(24).unwrap();
        assert_eq!(a.data(), b.data());
        let d = a.data();
        assert!(d.iter().all(|v| (0.0..=CLOUD_DENSITY as f32).contains(v)));
        let empty = d.iter().filter(|v| **v == 0.0).count();
        let full = d
            .iter()
            .filter(|v| **v > 0.5 * CLOUD_DENSITY as f32)
            .count();
        // Both empty space around the cloud and a dense core.
        assert!(empty > d.len() / 4, "{empty} of {}", d.len());
        assert!(full > d.len() / 100, "{full} of {}", d.len());
        assert!(a.occupied_bounds().is_some());
    }

    /// A stretched cloud is the cube's shape over its own box, centred on the origin, its
    /// longest axis `length` long; a cube of the unit length and peak holds the cube's values.
    #[test]
    fn stretched_clouds_fill_their_box() {
        let c = stretched_cloud([12, 8, 16], 10.0, 1.5).unwrap();
        assert_eq!(c.dims(), [12, 8, 16]);
        let b = c.bounds();
        let want = [0.5 * 12.0 / 16.0 * 10.0, 0.5 * 8.0 / 16.0 * 10.0, 5.0];
        for (k, w) in want.iter().enumerate() {
            assert!((b.max[k] - w).abs() < 1e-12 && (b.min[k] + w).abs() < 1e-12);
        }
        assert!(c.data().iter().all(|v| (0.0..=1.5).contains(v)));
        assert!(c.data().iter().any(|v| *v > 0.75));
        assert_eq!(
            c.data(),
            stretched_cloud([12, 8, 16], 10.0, 1.5).unwrap().data()
        );
        let cube = stretched_cloud([24; 3], 1.0, CLOUD_DENSITY).unwrap();
        assert_eq!(cube.data(), cloud(24).unwrap().data());
    }
}
