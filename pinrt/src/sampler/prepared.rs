//! One lookup's state between its set-up and its resolve ([`Prepared`]), and the pieces of a
//! chained lookup ([`piece_of`]). Written by both the scalar set-up and the lanes.

use crate::chord::Segment;
use crate::rng::Rng;

use super::query::status;

/// [`Prepared::local`] of a lookup point outside the grid's covered cells.
pub(crate) const NO_CELL: u64 = u64::MAX;

#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Prepared {
    pub(crate) status: u32,
    pub(crate) rng: Rng,
    /// The piece of the query segment this lookup resolves (the whole segment unless chained).
    pub(crate) seg: Segment,
    pub(crate) reversed: bool,
    /// Covered-slab cell index, or `NO_CELL` (outside this tile).
    pub(crate) local: u64,
    /// `direction * pins_per_entry + k`.
    pub(crate) within: u64,
    /// Unit-cube origin and direction, the whole segment and the piece's number: what the
    /// next lookup of a chain needs.
    pub(crate) o: [f32; 3],
    pub(crate) d: [f32; 3],
    pub(crate) full: Segment,
    pub(crate) piece: u32,
}

/// A lane no query has set up (the batch's initial value).
pub(super) const NOT_PREPARED: Prepared = Prepared {
    status: status::MISS,
    rng: Rng { state: 0 },
    seg: Segment::EMPTY,
    reversed: false,
    local: NO_CELL,
    within: 0,
    o: [0.0; 3],
    d: [0.0; 3],
    full: Segment::EMPTY,
    piece: 0,
};

impl Prepared {
    /// A query that draws nothing and reads nothing (invalid or missing).
    pub(crate) fn empty(status: u32, rng: Rng) -> Self {
        Self {
            status,
            rng,
            ..NOT_PREPARED
        }
    }
}

/// Piece `j` of `full` when the chord is cut every `stride` intervals: the intervals
/// `[j stride, (j + 1) stride)` that the segment touches. Cuts fall on interval boundaries, so
/// only the segment's own ends stay partial; with `stride = 32` piece 0 is `full` itself.
#[inline(always)]
pub(crate) fn piece_of(full: &Segment, j: u32, stride: u32) -> Segment {
    let lo = j * stride;
    let hi = (lo + stride).min(32);
    let mut p = *full;
    if full.a < lo {
        p.a = lo;
        p.s0 = lo as f32;
        let t = full.t_enter + lo as f32 * full.interval_len;
        p.t0 = if t > full.t0 { t } else { full.t0 };
    }
    if full.b >= hi {
        p.b = hi - 1;
        p.s1 = hi as f32;
        let t = full.t_enter + hi as f32 * full.interval_len;
        p.t1 = if t < full.t1 { t } else { full.t1 };
    }
    p
}
