//! The density scale a viewer opens a volume at when no `--density-scale` is given, so that
//! its first image reads: the power of two at which the volume's median optical depth along
//! the view, over the rays that cross any density, comes nearest [`TARGET_DEPTH`].
//!
//! A volume's own values are whatever its exporter wrote (the bundled smoke at scale 1 is a
//! faint haze under the default sky, a raw scan a black block), and an exposure change cannot
//! help: a thin medium scatters the sky's light back at about the sky's brightness, so its
//! image has little contrast at any exposure (docs/viewer.md, "The first look"). The scale is
//! chosen once, from the file, and then is an ordinary `--density-scale`: the viewer's copied
//! command carries it, so the batch render has the window's bits. A power of two keeps the
//! number a user reads and types short.

use glam::DVec3;
use pin_volume::Density;

use crate::render::clip_box;

/// The median optical depth along the view, over the columns that cross density, that the
/// chosen scale gives. Measured on the six bundled volumes (docs/viewer.md, "The first look"):
/// the volume's contrast against the sky and within itself grows with the depth up to 32
/// and beyond, while from 16 on the denser fields turn into uniform dark blocks that hide
/// their inside; 8 keeps the shape, the self-shadowing and the inside.
pub const TARGET_DEPTH: f64 = 8.0;
/// Rays per side of the square of parallel rays sent through the box along the view.
const RAYS: usize = 48;
/// Midpoint samples along each ray, between its entry into the box and its exit.
const STEPS: usize = 96;
/// The scales the rule may choose, as powers of two.
const MIN_EXPONENT: i32 = -12;
const MAX_EXPONENT: i32 = 12;

/// What the rule found for one volume.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FirstLook {
    /// The density scale to open the volume at (a power of two, 1 where the volume already
    /// reads).
    pub scale: f64,
    /// The median optical depth along the view at scale 1, over the rays that cross density.
    pub median_depth: f64,
}

/// The first look of `density` seen along `view` (any length, not zero): `None` when no ray
/// through its box crosses any density (nothing to scale).
pub fn first_look(density: &dyn Density, view: [f64; 3]) -> Option<FirstLook> {
    let d = DVec3::from(view).try_normalize()?;
    let b = density.bounds();
    let (lo, hi) = (b.min, b.max);
    if !(lo.cmplt(hi).all()) {
        return None;
    }
    // Two axes across the view, and the box's extent along them.
    let (u, v) = d.any_orthonormal_pair();
    let corners = (0..8).map(|k| {
        DVec3::new(
            if k & 1 == 0 { lo.x } else { hi.x },
            if k & 2 == 0 { lo.y } else { hi.y },
            if k & 4 == 0 { lo.z } else { hi.z },
        )
    });
    let (mut umin, mut umax, mut vmin, mut vmax) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    let mut dmin = f64::MAX;
    for c in corners {
        umin = umin.min(c.dot(u));
        umax = umax.max(c.dot(u));
        vmin = vmin.min(c.dot(v));
        vmax = vmax.max(c.dot(v));
        dmin = dmin.min(c.dot(d));
    }
    let mut depths = Vec::with_capacity(RAYS * RAYS);
    for i in 0..RAYS {
        for j in 0..RAYS {
            let a = umin + (umax - umin) * (i as f64 + 0.5) / RAYS as f64;
            let c = vmin + (vmax - vmin) * (j as f64 + 0.5) / RAYS as f64;
            let origin = u * a + v * c + d * (dmin - 1.0);
            let Some((t0, t1)) = clip_box(
                origin,
                d,
                &lo.to_array(),
                &hi.to_array(),
                f64::MIN,
                f64::MAX,
            ) else {
                continue;
            };
            let dt = (t1 - t0) / STEPS as f64;
            let depth: f64 = (0..STEPS)
                .map(|k| f64::from(density.extinction(origin + d * (t0 + (k as f64 + 0.5) * dt))))
                .filter(|x| x.is_finite() && *x > 0.0)
                .sum::<f64>()
                * dt;
            if depth > 0.0 {
                depths.push(depth);
            }
        }
    }
    if depths.is_empty() {
        return None;
    }
    depths.sort_by(f64::total_cmp);
    let median_depth = depths[depths.len() / 2];
    let exponent = (TARGET_DEPTH / median_depth).log2().round();
    let exponent = (exponent as i32).clamp(MIN_EXPONENT, MAX_EXPONENT);
    Some(FirstLook {
        scale: 2f64.powi(exponent),
        median_depth,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use pin_volume::Aabb;

    /// A box of constant extinction `sigma`, 1 unit on a side, with an empty half along x.
    struct HalfBox {
        sigma: f32,
    }

    impl Density for HalfBox {
        fn bounds(&self) -> Aabb {
            Aabb {
                min: DVec3::ZERO,
                max: DVec3::ONE,
            }
        }
        fn extinction(&self, p: DVec3) -> f32 {
            if p.x < 0.5 { self.sigma } else { 0.0 }
        }
        fn max_extinction_in(&self, _: Aabb) -> f32 {
            self.sigma
        }
    }

    #[test]
    fn the_scale_brings_the_median_depth_along_the_view_to_the_target() {
        // Along z every occupied column is 1 unit of sigma: depth sigma; the empty half
        // does not count.
        for (sigma, scale) in [(8.0, 1.0), (0.25, 32.0), (0.3, 32.0), (64.0, 1.0 / 8.0)] {
            let look = first_look(&HalfBox { sigma }, [0.0, 0.0, -1.0]).unwrap();
            assert!(
                (look.median_depth - f64::from(sigma)).abs() < 1e-9,
                "{sigma}: {look:?}"
            );
            assert_eq!(look.scale, scale, "{sigma}: {look:?}");
        }
        // Along x each column crosses the occupied half only: depth sigma / 2.
        let look = first_look(&HalfBox { sigma: 1.0 }, [1.0, 0.0, 0.0]).unwrap();
        assert!((look.median_depth - 0.5).abs() < 1e-9, "{look:?}");
        assert_eq!(look.scale, 16.0);
        // An oblique view meets every column, corners included, at its own length.
        let look = first_look(&HalfBox { sigma: 1.0 }, [0.3, 0.25, -1.6]).unwrap();
        assert!(
            look.median_depth > 0.3 && look.median_depth < 1.2,
            "{look:?}"
        );
    }

    #[test]
    fn an_empty_field_or_a_zero_view_has_no_first_look() {
        assert_eq!(first_look(&HalfBox { sigma: 0.0 }, [0.0, 0.0, 1.0]), None);
        assert_eq!(first_look(&HalfBox { sigma: 1.0 }, [0.0, 0.0, 0.0]), None);
        // The clamp: an absurdly thin field gets the largest scale, no more.
        let thin = first_look(&HalfBox { sigma: 1e-9 }, [0.0, 0.0, 1.0]).unwrap();
        assert_eq!(thin.scale, 2f64.powi(MAX_EXPONENT));
    }
}
