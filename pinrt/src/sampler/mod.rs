//! Distance sampling and transmittance estimation: single queries and prefetching batches.
//!
//! A query runs in three steps, which the batch API interleaves over 32 rays at a time so that
//! all memory fetches of a batch are in flight together (docs/background.md section 4):
//!
//! 1. **prepare** (pure arithmetic): world -> unit cube, validity, chord, segment, then the
//!    draws for the pin number and jitter, the spatial and direction cells.
//! 2. **address**: the sparse cell index (if any), then the entry's index in the pin array.
//! 3. **finish**: the two partial-interval draws, the popcount, `t_min^n`, and for distance
//!    sampling the sample mask `H` and the position draw.
//!
//! ## Random draws per query (the contract the WGSL shader follows)
//!
//! Rays that are invalid, miss the box or have an empty segment draw nothing. Otherwise, in
//! this order:
//!
//! 1. one `u32` for the pin number `k = ((x >> 8) * pins_per_entry) >> 24`;
//! 2. if spatial jitter is on: three floats (x, y, z);
//! 3. if directional jitter is on: two floats;
//! 4. two floats `xi_a`, `xi_b` for the partial first and last interval (always both);
//! 5. distance only: the sample-mask words (0 to 32, see [`crate::mask`]);
//! 6. distance only, and only if a collision interval was found: one float for the position
//!    inside the covered part of that interval.
//!
//! [`Sampler::query`] computes both estimates from one lookup: its transmittance equals
//! [`Sampler::transmittance`] and its distance [`Sampler::sample_distance`] for the same
//! starting generator.
//!
//! ## Chained lookups (`SamplerOptions::chain_stride`, docs/sampling.md section 12)
//!
//! With a stride `S < 32` the segment is cut at the chord's interval boundaries `S, 2S, ...`
//! and each piece is one lookup as above (draws 1-6 in that order, piece after piece, at the
//! piece's start or, with `midpoint_lookup`, its middle; with `start_inside` a piece that
//! starts inside the box at its start without spatial jitter). Transmittance multiplies the pieces;
//! distance sampling stops at the first piece with a collision; `query` continues after a
//! collision with draws 1-4 only, for the transmittance. So `query`'s distance is
//! `sample_distance`'s, but its transmittance equals `transmittance`'s only with one piece.
//! The batch methods run one round of fetches per piece over all rays still walking.
//!
//! ## Files
//!
//! The query types ([`query`]: rays, results, status codes, [`QueryMode`]) and the lookup
//! options ([`options`]) come first; [`prepared`] is one lookup's state before its entry is
//! read and [`resolve`] the arithmetic after it, both shared by the scalar path
//! ([`scalar`]: the [`Sampler`] and its single-ray queries) and the batch's lanes ([`lanes`]:
//! the set-up and the start of the resolve for [`BATCH`] rays at once, AVX2 or AVX-512
//! chosen at run time). [`batch`] drives the lanes and the scalar finishes over many rays;
//! [`expectation`] holds the mean and closed-form expectation helpers. Imports run one way,
//! down this list: no file imports one below it.

mod batch;
mod expectation;
mod lanes;
mod options;
mod prepared;
mod query;
mod resolve;
mod scalar;

pub use lanes::BATCH;
pub use options::SamplerOptions;
pub use query::{
    GpuRay, GpuResult, NO_ENTRY, NO_INTERVAL, QueryMode, QueryResult, Ray, RayQuery, status,
};
pub use scalar::Sampler;

#[cfg(test)]
pub(crate) use prepared::{NO_CELL, Prepared, piece_of};
#[cfg(test)]
pub(crate) use resolve::{participating, resolve_entry};
