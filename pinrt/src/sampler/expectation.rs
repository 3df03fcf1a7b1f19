//! Expectation helpers: the mean of many seeded estimates of one ray, and the pin model's
//! expected transmittance in closed form for an unjittered lookup.

use pin_format::PinEntry;

use crate::mask::{interval_bit, interval_range, sanitize_t_min};
use crate::rng::Rng;

use super::lanes::BATCH;
use super::prepared::Prepared;
use super::query::{QueryMode, Ray, RayQuery, status};
use super::scalar::Sampler;

impl Sampler<'_> {
    /// The mean of `draws` independent transmittance estimates of one ray (query `i` seeded
    /// by `Rng::for_query(seed, i)`, as in the batch methods).
    ///
    /// A single estimate is `t_min^n` for an integer `n`: it can be far from the true
    /// transmittance even where the pin model is accurate in the mean (see the crate docs).
    /// The mean over many draws converges to the pin model's expectation for this ray,
    /// lookup jitter included; its standard error is at most `0.5 / sqrt(draws)`.
    pub fn mean_transmittance(&self, ray: &Ray, t_max: f32, draws: u32, seed: u32) -> f64 {
        if draws == 0 {
            return f64::NAN;
        }
        let rays = [RayQuery::new(ray.origin, ray.dir, t_max); BATCH];
        let mut sum = 0.0f64;
        let mut first = 0u32;
        while first < draws {
            let n = (draws - first).min(BATCH as u32) as usize;
            self.batch(&rays[..n], seed, first, QueryMode::Transmittance, |_, r| {
                sum += f64::from(r.transmittance)
            });
            first += n as u32;
        }
        sum / f64::from(draws)
    }

    /// The pin model's expected transmittance of one ray in closed form, for a sampler
    /// without lookup jitter: the average over the entry's pins of
    /// `t_min^(set bits fully inside the segment) * prod over the partial end intervals whose
    /// bit is set of (1 - f + f t_min)`, where `f` is the covered fraction (a partial
    /// interval takes part with probability `f`). This is exactly what
    /// [`Sampler::transmittance`] returns on average. `None` when the sampler jitters its
    /// lookups (then use [`Sampler::mean_transmittance`]).
    pub fn expected_transmittance(&self, ray: &Ray, t_max: f32) -> Option<f64> {
        if self.opts.spatial_on() || self.opts.directional_on() {
            return None;
        }
        let mut p = self.prepare(ray.origin, ray.dir, t_max, Rng::new(0));
        if p.status != status::OK {
            return Some(1.0);
        }
        // The pieces of a chain draw their pins independently: the expectation is the
        // product of the pieces' expectations.
        let mut product = self.piece_expectation(&p);
        while let Some(n) = self.next_piece(&p, Rng::new(0)) {
            p = n;
            product *= self.piece_expectation(&p);
        }
        Some(product)
    }

    /// The expected transmittance of one unjittered lookup over its piece `p.seg`.
    pub(crate) fn piece_expectation(&self, p: &Prepared) -> f64 {
        let ppe = u64::from(self.view.shape.pins_per_entry.max(1));
        let first_pin = p.within - p.within % ppe;
        let seg = &p.seg;
        // Covered fractions of the end intervals (one interval: the segment's length).
        let (fa, fb) = if seg.a == seg.b {
            (f64::from(seg.s1 - seg.s0), 0.0)
        } else {
            (
                f64::from((seg.a + 1) as f32 - seg.s0),
                f64::from(seg.s1 - seg.b as f32),
            )
        };
        let mut sum = 0.0f64;
        for k in 0..ppe {
            let q = Prepared {
                within: first_pin + k,
                ..*p
            };
            let entry = self
                .address(&q)
                .and_then(|i| self.view.pins.get(i as usize).copied())
                .unwrap_or(PinEntry::EMPTY);
            let t_min = f64::from(sanitize_t_min(entry.t_min));
            let mask = if p.reversed {
                entry.mask.reverse_bits()
            } else {
                entry.mask
            };
            let range = interval_range(seg.a, seg.b);
            let ends = interval_bit(seg.a) | interval_bit(seg.b);
            let full = (mask & range & !ends).count_ones();
            let mut e = t_min.powi(full as i32);
            if mask & interval_bit(seg.a) != 0 {
                e *= 1.0 - fa + fa * t_min;
            }
            if seg.b != seg.a && mask & interval_bit(seg.b) != 0 {
                e *= 1.0 - fb + fb * t_min;
            }
            sum += e;
        }
        sum / ppe as f64
    }
}
