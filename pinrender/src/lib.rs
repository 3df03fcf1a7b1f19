//! # pinrender: the reference path tracer over pin grids
//!
//! A research harness, not a runtime: the CPU path tracer [`render`] (ray marching,
//! delta/ratio tracking over a majorant grid, pins, PinMS, closed-form cosine noise,
//! whole-volume box scattering, radiance cache) and its GPU twin [`gpu_render`] (feature
//! `gpu`), both built on the `pinrt` runtime. The `pinrender` binary (feature `cli`) renders,
//! benchmarks and evaluates real volumes read through `pinbake`'s sources.

#[cfg(feature = "gpu")]
pub mod gpu_render;
pub mod instance;
pub mod medium;
pub mod render;
#[cfg(feature = "cli")]
pub mod scene_media;
#[cfg(feature = "cli")]
pub mod volume;
