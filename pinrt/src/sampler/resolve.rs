//! The resolve of a lookup against its entry: partial-interval participation, the
//! transmittance `t_min^n` and, for distance sampling, the sample mask and the position
//! draw. [`Head`] is the part of it the lanes compute for a whole batch step.

use pin_format::PinEntry;

use crate::chord::Segment;
use crate::mask::{exact_sample_mask, interval_bit, interval_range, pow_int, sanitize_t_min};
use crate::rng::Rng;

use super::query::{NO_INTERVAL, QueryMode, QueryResult, status};

/// Resolves a segment against one entry: partial-interval participation, transmittance and
/// (depending on `mode`) the distance.
#[inline(always)]
pub(super) fn resolve(
    entry: PinEntry,
    entry_id: u32,
    reversed: bool,
    seg: &Segment,
    mut rng: Rng,
    mode: QueryMode,
) -> QueryResult {
    let xa = rng.next_f32();
    let xb = rng.next_f32();
    let t_min = sanitize_t_min(entry.t_min);
    let mask = if reversed {
        entry.mask.reverse_bits()
    } else {
        entry.mask
    };
    let part = participating(seg, xa, xb);
    let popcount = (mask & part).count_ones();
    let mut r = QueryResult {
        distance: f32::INFINITY,
        transmittance: 1.0,
        hit: 0,
        entry: entry_id,
        popcount,
        interval: NO_INTERVAL,
        status: status::OK,
        rng_state: 0,
    };
    if mode != QueryMode::Distance {
        r.transmittance = pow_int(t_min, popcount);
    }
    if mode != QueryMode::Transmittance {
        let h = exact_sample_mask(t_min, &mut rng);
        let m = mask & part & h;
        if m != 0 {
            let j = m.leading_zeros();
            r.interval = j;
            r.hit = 1;
            r.distance = position_in_interval(seg, j, rng.next_f32());
        }
    }
    r.rng_state = rng.state;
    r
}

/// The participating intervals: `a..=b`, minus a partial first/last interval whose draw
/// exceeds its covered fraction (`xi < f` participates). One interval: fraction `s1 - s0`.
#[inline(always)]
pub(crate) fn participating(seg: &Segment, xa: f32, xb: f32) -> u32 {
    let (a, b) = (seg.a, seg.b);
    let mut part = interval_range(a, b);
    if a == b {
        if !(xa < seg.s1 - seg.s0) {
            part = 0;
        }
    } else {
        if !(xa < (a + 1) as f32 - seg.s0) {
            part &= !interval_bit(a);
        }
        if !(xb < seg.s1 - b as f32) {
            part &= !interval_bit(b);
        }
    }
    part
}

/// A uniform position inside the covered part of interval `j`, clamped into `[t0, t1]`.
#[inline(always)]
pub(super) fn position_in_interval(seg: &Segment, j: u32, xi: f32) -> f32 {
    let lo = if j == seg.a { seg.s0 } else { j as f32 };
    let hi = if j == seg.b { seg.s1 } else { (j + 1) as f32 };
    let s = lo + xi * (hi - lo);
    let t = seg.t_enter + s * seg.interval_len;
    let t = if t > seg.t0 { t } else { seg.t0 };
    if t < seg.t1 { t } else { seg.t1 }
}

/// Resolves a segment against an explicit entry (for the statistical tests).
#[cfg(test)]
pub(crate) fn resolve_entry(
    entry: PinEntry,
    reversed: bool,
    seg: &Segment,
    rng: &mut Rng,
    want_distance: bool,
) -> QueryResult {
    let mode = if want_distance {
        QueryMode::Both
    } else {
        QueryMode::Transmittance
    };
    let r = resolve(entry, 0, reversed, seg, *rng, mode);
    rng.state = r.rng_state;
    r
}

/// What the lane part of the resolve leaves for each ray: the generator after the two
/// partial-interval draws, the participating set of the mask and the transmittance.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Head {
    pub(super) state: u32,
    pub(super) t_min: f32,
    /// `mask & participating`.
    pub(super) set: u32,
    pub(super) popcount: u32,
    pub(super) transmittance: f32,
}
