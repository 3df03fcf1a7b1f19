//! Fixtures of the renderer's statistical tests, shared with the crates that extend it
//! (feature `testing`; the lab's tests compare their estimators on the same fields).

use crate::render::{Aabb, Density, Pcg32};
use glam::DVec3;

/// `sin(x) / x`, stable at 0 (the series is exact to f64 below |x| = 1e-4).
fn sinc(x: f64) -> f64 {
    if x.abs() < 1e-4 {
        1.0 - x * x / 6.0
    } else {
        x.sin() / x
    }
}

/// `density * (1 + sum a_k cos(w_k . x + phi_k))` on a box, `sum a_k = 1` (so >= 0).
pub struct CosNoise {
    pub density: f64,
    pub waves: Vec<(DVec3, f64, f64)>,
    pub lo: [f64; 3],
    pub hi: [f64; 3],
}

impl CosNoise {
    /// `k` waves with directions uniform on the sphere and `|w|` in `[0.8, 1.2] * freq`
    /// (the paper's recipe), weights random and normalised to sum 1, fixed seed.
    pub fn new(k: usize, freq: f64, density: f64, seed: u64) -> Self {
        let mut rng = Pcg32::new(seed, 7);
        let mut waves = Vec::new();
        for _ in 0..k {
            let z = 2.0 * rng.next_f64() - 1.0;
            let phi = std::f64::consts::TAU * rng.next_f64();
            let r = (1.0 - z * z).sqrt();
            let len = freq * (0.8 + 0.4 * rng.next_f64());
            let w = DVec3::new(r * phi.cos(), r * phi.sin(), z) * len;
            waves.push((
                w,
                0.2 + rng.next_f64(),
                std::f64::consts::TAU * rng.next_f64(),
            ));
        }
        let s: f64 = waves.iter().map(|w| w.1).sum();
        for w in &mut waves {
            w.1 /= s;
        }
        CosNoise {
            density,
            waves,
            lo: [0.0; 3],
            hi: [1.0; 3],
        }
    }
    pub fn sigma(&self, p: DVec3) -> f64 {
        let s: f64 = self
            .waves
            .iter()
            .map(|(w, a, ph)| a * (w.dot(p) + ph).cos())
            .sum();
        self.density * (1.0 + s)
    }
    /// `integral_0^t cos(a + b s) ds = t cos(a + b t / 2) sinc(b t / 2)`: no division by
    /// `b = w . d`, so directions perpendicular to a wave are not special.
    pub fn optical_depth(&self, o: DVec3, d: DVec3, t: f64) -> f64 {
        let mut acc = t;
        for (w, a, ph) in &self.waves {
            let (a0, b) = (w.dot(o) + ph, w.dot(d));
            acc += a * t * (a0 + 0.5 * b * t).cos() * sinc(0.5 * b * t);
        }
        self.density * acc
    }
}

impl Density for CosNoise {
    fn bounds(&self) -> Aabb {
        Aabb::from_arrays(self.lo, self.hi)
    }
    fn extinction(&self, q: DVec3) -> f32 {
        if (0..3).all(|a| q[a] >= self.lo[a] && q[a] <= self.hi[a]) {
            self.sigma(q) as f32
        } else {
            0.0
        }
    }
    /// `sum a_k = 1` bounds the field by `2 density` everywhere (no tighter local bound
    /// is cheap for a sum of plane waves).
    fn max_extinction_in(&self, _region: Aabb) -> f32 {
        (2.0 * self.density) as f32 * (1.0 + 1e-6)
    }
}

/// Mean and standard error of `n` draws (shared by the estimators' statistical tests).
pub fn mean_se(n: usize, mut f: impl FnMut() -> f64) -> (f64, f64) {
    let (mut s, mut s2) = (0.0, 0.0);
    for _ in 0..n {
        let x = f();
        s += x;
        s2 += x * x;
    }
    let m = s / n as f64;
    let var = (s2 / n as f64 - m * m).max(0.0) * n as f64 / (n as f64 - 1.0);
    (m, (var / n as f64).sqrt())
}
