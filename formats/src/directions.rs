//! Direction parametrisations of the pin hemisphere (z >= 0).
//!
//! A query direction with z < 0 is looked up as its negation with the mask reversed, so only
//! the upper hemisphere needs cells. This module is the single definition of which direction
//! lands in which cell; bakers and samplers (CPU and WGSL) must follow it to the letter,
//! including [`atan2_turns`], a polynomial that uses only `+ - * /` so the GPU can reproduce it
//! bit for bit.

use crate::error::{FormatError, Result};
use crate::layout::{DIRECTIONS_OCTAHEDRAL, DIRECTIONS_POLAR};

/// Largest direction count a file may declare.
pub const MAX_DIRECTIONS: u32 = 1 << 16;

/// How the hemisphere is cut into direction cells.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Directions {
    /// `n_phi` azimuth bins times `n_theta` bins equal in `z = cos(theta)` (equal solid angle).
    /// Cell index = `theta_bin * n_phi + phi_bin`; theta bin 0 touches the pole.
    Polar { n_phi: u32, n_theta: u32 },
    /// `n x n` cells of the hemi-octahedral square. Cell index = `v_bin * n + u_bin`.
    Octahedral { n: u32 },
}

impl Directions {
    /// The thesis' default: 16 azimuth x 4 polar cells.
    pub const THESIS_DEFAULT: Directions = Directions::Polar {
        n_phi: 16,
        n_theta: 4,
    };

    pub fn count(&self) -> u32 {
        match *self {
            Directions::Polar { n_phi, n_theta } => n_phi * n_theta,
            Directions::Octahedral { n } => n * n,
        }
    }

    /// `(direction_kind, direction_res)` as stored in the grid description.
    pub fn to_desc(&self) -> (u32, [u32; 2]) {
        match *self {
            Directions::Polar { n_phi, n_theta } => (DIRECTIONS_POLAR, [n_phi, n_theta]),
            Directions::Octahedral { n } => (DIRECTIONS_OCTAHEDRAL, [n, n]),
        }
    }

    /// Parses and validates the stored form.
    pub fn from_desc(kind: u32, res: [u32; 2]) -> Result<Self> {
        let d = match kind {
            DIRECTIONS_POLAR => Directions::Polar {
                n_phi: res[0],
                n_theta: res[1],
            },
            DIRECTIONS_OCTAHEDRAL => {
                if res[0] != res[1] {
                    return Err(FormatError::BadGrid(format!(
                        "octahedral resolution must be square, got {}x{}",
                        res[0], res[1]
                    )));
                }
                Directions::Octahedral { n: res[0] }
            }
            other => {
                return Err(FormatError::BadGrid(format!(
                    "unknown direction parametrisation {other}"
                )));
            }
        };
        if res[0] == 0 || res[1] == 0 {
            return Err(FormatError::BadGrid("zero direction resolution".into()));
        }
        let count = u64::from(res[0]) * u64::from(res[1]);
        if count > u64::from(MAX_DIRECTIONS) {
            return Err(FormatError::BadGrid(format!(
                "{count} directions exceed the limit of {MAX_DIRECTIONS}"
            )));
        }
        Ok(d)
    }

    /// Cell of a direction with `d.z >= 0` (need not be normalised; must be finite and non-zero).
    #[inline]
    pub fn index_of(&self, d: [f32; 3]) -> u32 {
        match *self {
            Directions::Polar { n_phi, n_theta } => {
                let len2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
                let z = d[2] / len2.sqrt();
                let t = bin((1.0 - z) * n_theta as f32, n_theta);
                let p = bin(atan2_turns(d[1], d[0]) * n_phi as f32, n_phi);
                t * n_phi + p
            }
            Directions::Octahedral { n } => {
                let (u, v) = octahedral_uv(d);
                bin(v * n as f32, n) * n + bin(u * n as f32, n)
            }
        }
    }

    /// A direction inside cell `index` at cell-local coordinates `(a, b)` in `[0, 1]^2`
    /// (`(0.5, 0.5)` is the cell centre). Uniform `(a, b)` give uniform solid angle for polar
    /// cells. Used by bakers, so it is in f64 and may use trigonometry.
    pub fn direction_in_cell(&self, index: u32, a: f64, b: f64) -> [f64; 3] {
        match *self {
            Directions::Polar { n_phi, n_theta } => {
                let (t, p) = (index / n_phi, index % n_phi);
                let z = 1.0 - (f64::from(t) + a) / f64::from(n_theta);
                let phi = (f64::from(p) + b) / f64::from(n_phi) * std::f64::consts::TAU;
                let r = (1.0 - z * z).max(0.0).sqrt();
                [r * phi.cos(), r * phi.sin(), z]
            }
            Directions::Octahedral { n } => {
                let (vb, ub) = (index / n, index % n);
                let u = (f64::from(ub) + a) / f64::from(n);
                let v = (f64::from(vb) + b) / f64::from(n);
                let px = u + v - 1.0;
                let py = u - v;
                let z = (1.0 - px.abs() - py.abs()).max(0.0);
                let len = (px * px + py * py + z * z).sqrt();
                [px / len, py / len, z / len]
            }
        }
    }

    pub fn cell_center(&self, index: u32) -> [f64; 3] {
        self.direction_in_cell(index, 0.5, 0.5)
    }
}

/// `floor(x)` clamped to `[0, n - 1]`; NaN goes to 0.
#[inline]
fn bin(x: f32, n: u32) -> u32 {
    // `as` saturates and maps NaN to 0, so no branch is needed for the low side.
    (x as u32).min(n - 1)
}

/// Hemi-octahedral square coordinates in `[0, 1]^2` of a direction with `z >= 0`.
#[inline]
pub fn octahedral_uv(d: [f32; 3]) -> (f32, f32) {
    let s = d[0].abs() + d[1].abs() + d[2];
    let (px, py) = (d[0] / s, d[1] / s);
    ((px + py + 1.0) * 0.5, (px - py + 1.0) * 0.5)
}

/// Azimuth of `(x, y)` in turns, `[0, 1)`, by a degree-9 odd polynomial (max error about
/// 1e-5 radians). Only `+ - * /`, compare and select, so that WGSL reproduces it exactly.
#[inline]
pub fn atan2_turns(y: f32, x: f32) -> f32 {
    let ax = x.abs();
    let ay = y.abs();
    let mx = ax.max(ay);
    let mn = ax.min(ay);
    if mx == 0.0 {
        return 0.0;
    }
    let a = mn / mx;
    let s = a * a;
    // Abramowitz & Stegun 4.4.49: |error| <= 1e-5 rad on [0, 1].
    let mut r =
        a * (0.999_866 + s * (-0.330_299_5 + s * (0.180_141 + s * (-0.085_133 + s * 0.020_835_1))));
    if ay > ax {
        r = std::f32::consts::FRAC_PI_2 - r;
    }
    if x < 0.0 {
        r = std::f32::consts::PI - r;
    }
    if y < 0.0 {
        r = -r;
    }
    let mut turns = r * (1.0 / std::f32::consts::TAU);
    if turns < 0.0 {
        turns += 1.0;
    }
    if turns >= 1.0 { 0.0 } else { turns }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn atan2_turns_close_to_libm() {
        let mut worst = 0.0f64;
        for i in 0..10_000 {
            let ang = i as f64 / 10_000.0 * std::f64::consts::TAU;
            let (y, x) = (ang.sin() as f32, ang.cos() as f32);
            let want = (f64::from(y).atan2(f64::from(x)) / std::f64::consts::TAU).rem_euclid(1.0);
            let got = f64::from(atan2_turns(y, x));
            let mut diff = (got - want).abs();
            diff = diff.min(1.0 - diff);
            worst = worst.max(diff);
        }
        assert!(worst < 1.5e-5 / std::f64::consts::TAU, "worst {worst}");
        assert_eq!(atan2_turns(0.0, 0.0), 0.0);
    }

    #[test]
    fn centres_map_back_to_their_cell() {
        for dirs in [
            Directions::THESIS_DEFAULT,
            Directions::Polar {
                n_phi: 7,
                n_theta: 3,
            },
            Directions::Octahedral { n: 8 },
            Directions::Octahedral { n: 1 },
            Directions::Octahedral { n: 5 },
        ] {
            for i in 0..dirs.count() {
                let c = dirs.cell_center(i);
                let len = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
                assert!((len - 1.0).abs() < 1e-12);
                assert!(c[2] >= 0.0);
                let f = [c[0] as f32, c[1] as f32, c[2] as f32];
                assert_eq!(dirs.index_of(f), i, "{dirs:?} cell {i}");
            }
        }
    }

    #[test]
    fn extreme_directions_stay_in_range() {
        let dirs = [Directions::THESIS_DEFAULT, Directions::Octahedral { n: 16 }];
        let cases = [
            [0.0, 0.0, 1.0],
            [1.0, 0.0, 0.0],
            [-1.0, 0.0, 0.0],
            [0.0, -1.0, 0.0],
            [0.0, 1.0, 0.0],
            [1e-30, -1e-30, 1.0],
            [1.0, 1.0, 0.0],
            [-1.0, -1.0, 0.0],
            [f32::MIN_POSITIVE, 0.0, 0.0],
            [0.0, 0.0, -0.0],
        ];
        for d in dirs {
            for c in cases {
                assert!(d.index_of(c) < d.count(), "{d:?} {c:?}");
            }
        }
    }

    #[test]
    fn desc_validation() {
        assert!(Directions::from_desc(0, [16, 4]).is_ok());
        assert!(Directions::from_desc(1, [8, 8]).is_ok());
        assert!(Directions::from_desc(1, [8, 7]).is_err());
        assert!(Directions::from_desc(2, [8, 8]).is_err());
        assert!(Directions::from_desc(0, [0, 4]).is_err());
        assert!(Directions::from_desc(0, [1 << 16, 2]).is_err());
    }
}
