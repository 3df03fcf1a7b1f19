//! # pinrt: the pin grid runtime
//!
//! Loads pin files (memory-mapped in O(1), or read into memory) and answers two queries along
//! world-space rays through a baked participating medium, on the CPU and (feature `gpu`,
//! default) in WGSL through wgpu with the same numbers:
//!
//! * **transmittance** over a segment: an unbiased estimate (for the pin model) of
//!   `exp(-optical depth)`;
//! * **distance sampling**: a free-flight distance, or none if the ray passes.
//!
//! Build with `--no-default-features` for a CPU-only runtime without wgpu.
//!
//! ## The query model (the contract; details and proofs in `docs/sampling.md`)
//!
//! A grid covers the box `[box_min, box_max]` of the volume's local space, placed in the world
//! by the row-major 3x4 `local_to_world` affine. The box is normalised to the unit cube.
//!
//! 1. **Ray to unit cube.** `o_u = A o + b`, `d_u = A d` with `A`, `b` precomputed in f64 and
//!    stored in f32 ([`UnitTransform`]). `d_u` is not renormalised: the ray parameter `t` is
//!    the same in every space (world distance for unit `d`).
//! 2. **Chord.** Slab intersection with `[0, 1]^3` gives `[t_enter, t_exit]`
//!    (`chord::unit_cube_chord`); no chord (miss, corner graze) means transmittance 1 and no
//!    collision.
//! 3. **Lookup.** Direction cell of `d_u` (of `-d_u` with the mask bits reversed when
//!    `d_u.z < 0`; `-0.0` counts as `>= 0`), spatial cell of the lookup point (the segment
//!    start in the thesis' lookup, its middle in the default one) clamped into the grid, pin
//!    `k` uniform among the entry's pins. Jitter, the lookup point and the nearest-line
//!    search are options ([`SamplerOptions`]).
//! 4. **Intervals.** The chord is cut into 32 equal intervals; after the reversal bit 31 is
//!    the interval nearest `t_enter`. The segment is `[max(0, t_enter), min(t_max, t_exit)]`.
//! 5. **Partial intervals.** An interval the segment covers by a fraction `f < 1` takes part
//!    with probability `f`. Transmittance is `t_min ^ popcount(I & participating)`; distance
//!    sampling takes the first set bit of `I & H & participating` from the segment start and a
//!    uniform point in the covered part of that interval. Hence
//!    `P(no collision) = E[transmittance] = prod_full t_i * prod_partial (1 - f (1 - t_i))`.
//! 6. **Sample mask `H`.** Each bit independently set with probability `Q / 2^32`,
//!    `Q = round((1 - t_min) 2^32)`, exactly, by a bit-sliced comparison (`mask.rs`); bias at
//!    most 2^-32 per bit. The thesis' 5-round version is `mask::thesis_sample_mask`.
//! 7. **Numerics.** `t_min = 1` gives `T = 1`; `0^0 = 1`; no shift by 32; invalid input (NaN
//!    or infinite origin or direction, zero direction, NaN `t_max`) gives `T = 1`, no
//!    collision and [`status::INVALID`]; `t_max = 0` or a segment behind the origin gives
//!    `T = 1` and [`status::MISS`]. Never NaN out.
//!
//! The random draws of a query follow a fixed order (`docs/sampling.md` section 7) with the
//! 32-bit generator [`Rng`], so the GPU reproduces the CPU bit for bit (`docs/gpu.md`).
//!
//! ## Accuracy: one estimate is not the transmittance
//!
//! A single transmittance estimate is `t_min^n` for a whole number `n` of set mask bits, from
//! one pin that runs near, not along, the query ray. It is right *on average* over the pin
//! model's random draws, not per call: one ray's estimate can be 0 where the true
//! transmittance is 0.8, or the other way round. Average many draws
//! ([`Sampler::mean_transmittance`]) or take the model's expectation in closed form
//! ([`Sampler::expected_transmittance`], without lookup jitter) when a single ray's value
//! matters. The model itself has a bias against the true transmittance, which depends on the
//! bake (spatial cells, direction set, pins per entry) and the lookup jitter; how large it is
//! on real volumes, and at which file size, is measured in `docs/evaluation.md`. Renderers
//! average millions of estimates per image, which is the use the model is built for.
//!
//! The default lookup ([`SamplerOptions::default`], what [`PinGrid::sampler`] and
//! `gpu::GpuPinGrid::upload` use) is [`SamplerOptions::RENDER`]: one cell of jitter, the
//! middle of the segment, rays from inside the medium looked up at their start, and the
//! nearest-line search, measured the least biased on volumes nobody tuned for. The thesis'
//! lookup (no jitter, the segment start) is [`SamplerOptions::THESIS`]
//! (`sampler.with_options(SamplerOptions::THESIS)`); [`Sampler::expected_transmittance`] has
//! a closed form only for unjittered lookups such as that one.
//!
//! ## Performance
//!
//! A single query is dominated by one cache miss for its entry. The batch methods
//! ([`Sampler::transmittance_batch`], [`Sampler::sample_distance_batch`]) compute 32 lookups,
//! prefetch all their entries, then resolve them, overlapping the misses. Hot paths have no
//! trigonometry and only the divisions of the slab test and the direction binning.
//!
//! ## Example
//!
//! ```
//! use pin_format::{Directions, OwnedPinGrid, PinEntry, grid_desc};
//! use pinrt::{PinGrid, Ray, RayQuery, Rng};
//!
//! // A tiny 2x2x2 grid with 16x4 polar direction cells, one pin per entry: every pin has
//! // all 32 ratio bits set and t_min = 0.97 (a homogeneous medium).
//! let dirs = Directions::THESIS_DEFAULT;
//! let owned = OwnedPinGrid {
//!     desc: grid_desc([2, 2, 2], dirs, 1, 8),
//!     tile: None,
//!     cell_index: None,
//!     pins: vec![PinEntry { mask: u32::MAX, t_min: 0.97 }; 8 * 64],
//!     majorant: None,
//!     density: None,
//!     sparse_density: None,
//!     control: None,
//!     metadata: None,
//! };
//! let dir = tempfile::tempdir()?;
//! let path = dir.path().join("tiny.pin");
//! owned.write_atomic(&path)?;
//!
//! // Open: O(1), memory-mapped, no copy of the pin array.
//! let grid = PinGrid::open(&path)?;
//! let sampler = grid.sampler()?;
//!
//! // One ray through the unit box along +x; t_max = inf: to the box exit.
//! let ray = Ray::new([-1.0, 0.5, 0.5], [1.0, 0.0, 0.0]);
//! let mut rng = Rng::for_query(1234, 0);
//! let t = sampler.transmittance(&ray, f32::INFINITY, &mut rng);
//! assert!((t - 0.97f32.powi(32)).abs() < 1e-6);
//! if let Some(d) = sampler.sample_distance(&ray, f32::INFINITY, &mut rng) {
//!     assert!((1.0..=2.0).contains(&d)); // the box spans t in [1, 2]
//! }
//!
//! // Batches: query i uses Rng::for_query(seed, first_index + i), like the GPU.
//! let rays = vec![RayQuery::new([0.5, 0.5, -1.0], [0.0, 0.0, 1.0], 1.5); 100];
//! let mut out = vec![0.0f32; rays.len()];
//! sampler.transmittance_batch(&rays, 7, 0, &mut out);
//! let mean = out.iter().sum::<f32>() / out.len() as f32;
//! assert!(mean > 0.0 && mean <= 1.0);
//!
//! // The same queries on the GPU (feature `gpu`), if an adapter is present.
//! #[cfg(feature = "gpu")]
//! match pinrt::gpu::GpuContext::new() {
//!     Ok(ctx) => {
//!         let gpu_grid = pinrt::gpu::GpuPinGrid::upload(&ctx, &grid)?;
//!         let results = gpu_grid.run_queries(&rays, 7, 0)?;
//!         let mut cpu = vec![bytemuck::Zeroable::zeroed(); rays.len()];
//!         sampler.query_batch(&rays, 7, 0, &mut cpu);
//!         assert_eq!(results[0].popcount, cpu[0].popcount);
//!     }
//!     Err(e) => eprintln!("no GPU here: {e}"),
//! }
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

// The public surface is the root: the types below, `gpu`, `march` and `status`. The modules
// behind it are private, except three that the statistical tests in `tests/` and the bias
// examples (`pinrt/examples/mask_bias.rs`, `pinrender/examples/pin_bias_parts.rs`) need in
// order to test the model's pieces one at a time (the chord and segment, the spatial and
// direction cells, the sample mask): they are public but hidden from the docs, not an API.
#[doc(hidden)]
pub mod chord;
mod error;
#[cfg(feature = "gpu")]
pub mod gpu;
mod instances;
mod loader;
#[doc(hidden)]
pub mod lookup;
pub mod march;
#[doc(hidden)]
pub mod mask;
mod rng;
mod sampler;
mod sections;
mod sparse;
#[cfg(any(test, feature = "testing"))]
pub mod testing;
#[cfg(test)]
mod tests;

pub use chord::UnitTransform;
pub use error::{Error, Result};
pub use instances::Instances;
pub use loader::PinGrid;
pub use lookup::MAX_NEAREST_LINE_STEPS;
pub use rng::Rng;
pub use sampler::{
    BATCH, GpuRay, GpuResult, NO_ENTRY, NO_INTERVAL, QueryMode, QueryResult, Ray, RayQuery,
    Sampler, SamplerOptions, status,
};
pub use sections::{Control, Density, Majorants};
pub use sparse::SparseDensity;

/// The WGSL source of the GPU path (`shaders/pin.wgsl`).
pub const PIN_WGSL: &str = include_str!("../../shaders/pin.wgsl");

// Re-exported so users need not depend on the format crate for the basic types.
/// The vector library of the public API (`march::MarchBox`, the renderer's scenes), so users
/// name the same version of its types without a direct dependency.
pub use glam;
pub use pin_format::{Directions, GridDesc, PinEntry};
