//! One pin: its line through the unit cube, its 32 interval optical depths, and the sampled
//! (mask, t_min) entry. This is the whole per-pin computation of a bake, in one pass.

use glam::DVec3;
use pin_format::PinEntry;

use crate::rng::CounterRng;
use crate::source::DensitySource;

/// Intervals per pin.
pub const INTERVALS: usize = 32;
const _: () = assert!(INTERVALS == pin_format::layout::BITS_PER_PIN as usize);

/// Where the grid sits in world space and how fine the bake marches.
#[derive(Clone, Copy, Debug)]
pub struct Placement {
    pub box_min: DVec3,
    pub extent: DVec3,
    /// World-space ray-marching step.
    pub step: f64,
}

impl Placement {
    pub fn to_world(&self, u: DVec3) -> DVec3 {
        self.box_min + u * self.extent
    }
}

/// Parameter range `[s0, s1]` of the line `p + s w` inside the unit cube, or `None`.
///
/// Robust to axis-parallel directions (no 0 * inf): an axis with `w == 0` constrains nothing
/// if `p` is inside that slab and empties the chord otherwise.
pub fn unit_cube_chord(p: DVec3, w: DVec3) -> Option<(f64, f64)> {
    let mut s0 = f64::NEG_INFINITY;
    let mut s1 = f64::INFINITY;
    for a in 0..3 {
        if w[a] == 0.0 {
            if !(0.0..=1.0).contains(&p[a]) {
                return None;
            }
            continue;
        }
        let inv = 1.0 / w[a];
        let (mut ta, mut tb) = ((0.0 - p[a]) * inv, (1.0 - p[a]) * inv);
        if ta > tb {
            std::mem::swap(&mut ta, &mut tb);
        }
        s0 = s0.max(ta);
        s1 = s1.min(tb);
    }
    (s0.is_finite() && s1.is_finite() && s1 >= s0).then_some((s0, s1))
}

/// Optical depth of each of the 32 equal intervals of the chord of `p + s w` (unit-cube
/// coordinates), by the midpoint rule with at most `placement.step` world units per sample.
///
/// Sums run in f64 so that long pins through dense media keep their relative precision.
/// Returns zeros for a chord of zero length.
pub fn interval_optical_depths(
    source: &dyn DensitySource,
    placement: &Placement,
    p: DVec3,
    w: DVec3,
) -> [f64; INTERVALS] {
    let mut taus = [0.0f64; INTERVALS];
    let Some((s0, s1)) = unit_cube_chord(p, w) else {
        return taus;
    };
    let ds = (s1 - s0) / INTERVALS as f64;
    let world_dir = w * placement.extent;
    let interval_len = ds * world_dir.length();
    if !(interval_len > 0.0) {
        return taus;
    }
    let steps = (interval_len / placement.step).ceil().clamp(1.0, 1e6) as usize;
    let h = ds / steps as f64;
    let weight = interval_len / steps as f64;
    let origin = placement.to_world(p);
    let world_step = world_dir * h;
    // Sample points are evenly spaced along the whole chord, so sources can step
    // incrementally (`extinction_along`); a fixed chunk keeps the working set on the stack.
    const CHUNK: usize = 256;
    let mut buf = [0.0f32; CHUNK];
    for (i, tau) in taus.iter_mut().enumerate() {
        let start = origin + world_dir * (s0 + ds * i as f64) + world_step * 0.5;
        let mut sum = 0.0f64;
        let mut j = 0;
        while j < steps {
            let n = (steps - j).min(CHUNK);
            source.extinction_along(start + world_step * j as f64, world_step, n, &mut buf[..n]);
            sum += buf[..n].iter().map(|&v| f64::from(v)).sum::<f64>();
            j += n;
        }
        *tau = sum * weight;
    }
    taus
}

/// The stored entry for a pin with interval optical depths `taus`, drawing one uniform per
/// interval from `rng`.
///
/// Uses `1 - t = -expm1(-tau)` so that the ratio `(1 - t_i) / (1 - t_min)` stays accurate for
/// optical depths down to subnormals and is never 0/0: `tau_max == 0` (or a `t_min` that
/// rounds to 1 in f32) gives the empty pin.
pub fn make_entry(taus: &[f64; INTERVALS], rng: &mut CounterRng) -> PinEntry {
    let tau_max = taus.iter().copied().fold(0.0f64, f64::max);
    let t_min = (-tau_max).exp() as f32;
    if !(tau_max > 0.0) || t_min >= 1.0 {
        return PinEntry::EMPTY;
    }
    let denom = -(-tau_max).exp_m1();
    let mut mask = 0u32;
    for (i, &tau) in taus.iter().enumerate() {
        let p = -(-tau).exp_m1() / denom;
        if rng.next_f64() < p {
            mask |= 1u32 << (31 - i);
        }
    }
    PinEntry { mask, t_min }
}
