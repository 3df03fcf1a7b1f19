//! # pinlab: the research lab over the pinrender path tracer
//!
//! What the renderer a user runs does not need, extending `pinrender` through its public
//! traits only:
//!
//! * research estimators: the closed forms of the cosine-noise paper ([`closed_form`]),
//!   whole-volume single scattering ([`whole_volume`]), the comb estimators `urm` and
//!   `jackknife` ([`comb`], [`comb_estimators`]), `pinurm` ([`pin_control`]), each a
//!   [`pinrender::render::TransportEstimator`] (the combs also a
//!   [`pinrender::gpu_render::ShaderKernel`] of the GPU path tracer);
//! * the path-space radiance cache ([`cache`]), a sample loop over the tracer's own walk
//!   through [`pinrender::render::VertexHook`];
//! * what the eval and the bench measure with: [`cpu_time`] (the thread's and the process's
//!   CPU clocks) and [`fractal_cloud`] (the eval's production-scale cloud, voxelised at run
//!   time);
//! * [`estimator`]: every estimator name the `pinrender` binary takes, the renderer's and the
//!   lab's, and the catalogue `pinrender estimators` prints.
//!
//! The `pinrender` binary is this crate's (`src/bin/pinrender/`): `render`, `estimators` and
//! `shaders` over the renderer, `eval`, `bench` and `plot-bias` from the lab. It lives here
//! because it is the one crate that sees both; the `pinrender` library never depends on it.

pub mod cache;
pub mod closed_form;
pub mod comb;
pub mod comb_estimators;
pub mod cpu_time;
pub mod estimator;
pub mod fractal_cloud;
pub mod pin_control;
pub mod whole_volume;

pub use cache::{CacheSettings, RadianceCache, render_cached};
pub use closed_form::{AnalyticOpticalDepth, ClosedFormTracker};
pub use comb_estimators::{
    CombKind, JACKKNIFE_DEFAULT_LOOKUPS, JackknifeMarching, URM_DEFAULT_LOOKUPS,
    UnbiasedRayMarching,
};
pub use estimator::{ESTIMATOR_SYNTAX, Estimator, EstimatorInfo, estimators};
pub use pin_control::{
    PINURM_DEFAULT_LOOKUPS, PINURM_DEFAULT_PIN_QUERIES, PINURM_MAX_PIN_QUERIES,
    PINURM_MAX_PIN_SPREAD, PinControlledUrm,
};
pub use whole_volume::{SingleScatterSampling, WholeVolumeBox, render_single_scattering};
