//! What a query takes and gives: world-space rays, the full result with its debug integers,
//! the status codes, and which estimates a query computes ([`QueryMode`]).

use bytemuck::{Pod, Zeroable};

use crate::rng::Rng;

/// A world-space ray. `dir` need not be normalised: distances are in units of the ray
/// parameter (`point = origin + t * dir`), which is world distance when `|dir| = 1`.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Ray {
    pub origin: [f32; 3],
    pub dir: [f32; 3],
}

impl Ray {
    pub fn new(origin: [f32; 3], dir: [f32; 3]) -> Self {
        Self { origin, dir }
    }
}

/// A ray with its segment end, laid out for GPU storage buffers (32 bytes) and batches.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Default, Pod, Zeroable)]
pub struct RayQuery {
    pub origin: [f32; 3],
    /// End of the segment in ray-parameter units; `+inf` for the whole chord.
    pub t_max: f32,
    pub dir: [f32; 3],
    pub pad: u32,
}

impl RayQuery {
    pub fn new(origin: [f32; 3], dir: [f32; 3], t_max: f32) -> Self {
        Self {
            origin,
            t_max,
            dir,
            pad: 0,
        }
    }

    pub fn ray(&self) -> Ray {
        Ray::new(self.origin, self.dir)
    }
}

/// The same type under the name the GPU module uses.
pub type GpuRay = RayQuery;

/// Query status codes in [`QueryResult::status`].
pub mod status {
    /// The segment was resolved against an entry (possibly an empty cell).
    pub const OK: u32 = 0;
    /// No chord through the box, or an empty segment: transmittance 1, no collision.
    pub const MISS: u32 = 1;
    /// Non-finite origin or direction, zero direction, or NaN `t_max`: transmittance 1,
    /// no collision.
    pub const INVALID: u32 = 2;
}

/// [`QueryResult::entry`] when no stored entry was read (miss, invalid or empty cell).
pub const NO_ENTRY: u32 = u32::MAX;
/// [`QueryResult::interval`] when there is no collision.
pub const NO_INTERVAL: u32 = 32;

/// Everything one query produces, including the debug integers the CPU/GPU agreement tests
/// compare (32 bytes, GPU storage layout).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct QueryResult {
    /// Sampled collision distance (ray parameter), `+inf` if none.
    pub distance: f32,
    pub transmittance: f32,
    /// 1 if a collision was sampled.
    pub hit: u32,
    /// Index of the entry in the pin array, or [`NO_ENTRY`].
    pub entry: u32,
    /// Participating set ratio bits (the transmittance exponent).
    pub popcount: u32,
    /// Collision interval (0 = nearest the chord start), or [`NO_INTERVAL`].
    pub interval: u32,
    /// One of [`status`].
    pub status: u32,
    /// The generator state after the query: equal iff both sides drew the same numbers.
    pub rng_state: u32,
}

/// The same type under the name the GPU module uses.
pub type GpuResult = QueryResult;

impl QueryResult {
    /// The result of a query that read nothing (`status` is MISS or INVALID).
    pub(super) fn empty(status: u32, rng: Rng) -> Self {
        Self {
            distance: f32::INFINITY,
            transmittance: 1.0,
            hit: 0,
            entry: NO_ENTRY,
            popcount: 0,
            interval: NO_INTERVAL,
            status,
            rng_state: rng.state,
        }
    }

    /// The distance as an option.
    pub fn collision(&self) -> Option<f32> {
        (self.hit != 0).then_some(self.distance)
    }
}

/// What a query computes: the CPU's single queries ([`crate::Sampler::query`],
/// [`crate::Sampler::transmittance`], [`crate::Sampler::sample_distance`]) and their batches
/// each run one mode, and so does each entry point of `pin.wgsl`, with the same results,
/// integers and final generator included.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum QueryMode {
    /// Distance and transmittance from one lookup (`main`).
    Both,
    /// The transmittance only (`main_transmittance`): no sample-mask draws; distance `+inf`,
    /// no hit.
    Transmittance,
    /// The distance only (`main_distance`): transmittance 1, a chain stops at its collision.
    Distance,
}

impl QueryMode {
    /// The entry point of `pin.wgsl` that answers this mode.
    pub fn entry_point(self) -> &'static str {
        match self {
            QueryMode::Both => "main",
            QueryMode::Transmittance => "main_transmittance",
            QueryMode::Distance => "main_distance",
        }
    }

    /// Every mode, in the order of the GPU context's pipelines.
    #[cfg(feature = "gpu")]
    pub(crate) const ALL: [QueryMode; 3] = [
        QueryMode::Both,
        QueryMode::Transmittance,
        QueryMode::Distance,
    ];
}
