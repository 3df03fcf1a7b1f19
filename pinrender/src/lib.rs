//! # pinrender: the reference path tracer over pin grids
//!
//! The renderer a user runs, on the CPU ([`render`]) and the GPU ([`gpu_render`], feature
//! `gpu`), both built on the `pinrt` runtime, with the estimators a user picks: ray marching,
//! delta, ratio and residual ratio tracking over a majorant grid, pins, PinMS and pinres.
//! [`medium`] describes a medium once for both renderers; [`volume`] (feature `cli`) opens real
//! volumes through `pinbake`'s sources, and [`front`] (feature `cli`) is the front end that
//! the `pinrender` binary and the viewer share: their render flags, the estimator rule and
//! `open_medium`.
//!
//! Research estimators, the evaluation and the benchmarks live in the `pinlab` crate, which
//! extends this one through its public traits ([`render::TransportEstimator`],
//! [`render::VertexHook`], [`gpu_render::ShaderKernel`]); this crate does not depend on it.

#[cfg(feature = "cli")]
pub mod front;
#[cfg(feature = "gpu")]
pub mod gpu_render;
pub mod instance;
#[cfg(feature = "cli")]
pub mod look;
pub mod medium;
pub mod render;
#[cfg(feature = "cli")]
pub mod scene_media;
#[cfg(any(test, feature = "testing"))]
pub mod testing;
#[cfg(feature = "cli")]
pub mod volume;
