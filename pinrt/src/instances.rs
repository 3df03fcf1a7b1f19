//! Several pin grids combined additively (overlapping volumes, instanced assets).
//!
//! For densities that add, free-flight sampling can sample each component and keep the nearest
//! collision, and transmittance multiplies (thesis section 3.10). Each member is a [`Sampler`]
//! with its own placement; one grid may appear many times with different transforms.

use crate::error::Result;
use crate::loader::PinGrid;
use crate::rng::Rng;
use crate::sampler::{Ray, Sampler};

/// A set of placed grids queried together.
#[derive(Clone, Debug, Default)]
pub struct Instances<'g> {
    members: Vec<Sampler<'g>>,
}

impl<'g> Instances<'g> {
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a grid placed by its file transform or by `local_to_world` (row-major 3x4), with
    /// the default lookup ([`crate::SamplerOptions::RENDER`]; [`Self::push`] takes a sampler
    /// with other options).
    pub fn add(&mut self, grid: &'g PinGrid, local_to_world: Option<&[f64; 12]>) -> Result<()> {
        let s = match local_to_world {
            None => Sampler::new(grid)?,
            Some(m) => Sampler::with_local_to_world(grid, m)?,
        };
        self.members.push(s);
        Ok(())
    }

    /// Adds a configured sampler.
    pub fn push(&mut self, sampler: Sampler<'g>) {
        self.members.push(sampler);
    }

    pub fn len(&self) -> usize {
        self.members.len()
    }

    pub fn is_empty(&self) -> bool {
        self.members.is_empty()
    }

    pub fn members(&self) -> &[Sampler<'g>] {
        &self.members
    }

    /// Product of the members' transmittance estimates (members queried in order).
    pub fn transmittance(&self, ray: &Ray, t_max: f32, rng: &mut Rng) -> f32 {
        let mut t = 1.0f32;
        for m in &self.members {
            t *= m.transmittance(ray, t_max, rng);
            if t == 0.0 {
                break;
            }
        }
        t
    }

    /// Nearest sampled collision over the members. Each later member samples only up to the
    /// nearest collision so far, which leaves the distribution of the minimum unchanged.
    pub fn sample_distance(&self, ray: &Ray, t_max: f32, rng: &mut Rng) -> Option<f32> {
        let mut best: Option<f32> = None;
        for m in &self.members {
            let limit = best.unwrap_or(t_max);
            if let Some(d) = m.sample_distance(ray, limit, rng)
                && best.is_none_or(|b| d < b)
            {
                best = Some(d);
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::single_entry_grid;
    use pin_format::PinEntry;

    fn homogeneous(t_min: f32) -> PinGrid {
        PinGrid::from_bytes(
            single_entry_grid(PinEntry {
                mask: u32::MAX,
                t_min,
            })
            .to_bytes()
            .unwrap(),
        )
        .unwrap()
    }

    #[test]
    fn transmittance_multiplies_and_distance_is_nearest() {
        let a = homogeneous(0.9);
        let b = homogeneous(0.8);
        let shift = [1.0, 0.0, 0.0, 0.5, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0];
        let mut inst = Instances::new();
        inst.add(&a, None).unwrap();
        inst.add(&b, Some(&shift)).unwrap();
        assert_eq!(inst.len(), 2);
        // Along x through both: a covers x in [0,1], b covers [0.5,1.5]. Homogeneous masks are
        // deterministic for full chords: T = 0.9^32 * 0.8^32.
        let ray = Ray::new([-1.0, 0.5, 0.5], [1.0, 0.0, 0.0]);
        let mut rng = Rng::new(1);
        let t = inst.transmittance(&ray, f32::INFINITY, &mut rng);
        let want = 0.9f32.powi(32) * 0.8f32.powi(32);
        assert!((t - want).abs() <= want * 1e-5, "{t} vs {want}");

        // Nearest collision: P(no collision) = T; mean over many samples.
        let n = 200_000;
        let mut none = 0;
        for _ in 0..n {
            match inst.sample_distance(&ray, f32::INFINITY, &mut rng) {
                None => none += 1,
                Some(d) => assert!((1.0..=2.5).contains(&d), "{d}"),
            }
        }
        let p = f64::from(want);
        let f = none as f64 / n as f64;
        let z = (f - p) / (p * (1.0 - p) / n as f64).sqrt().max(1e-12);
        assert!(z.abs() < 4.5, "{f} vs {p}");

        let empty = Instances::new();
        assert!(empty.is_empty());
        assert_eq!(empty.transmittance(&ray, 1.0, &mut rng), 1.0);
        assert_eq!(empty.sample_distance(&ray, 1.0, &mut rng), None);
    }
}
