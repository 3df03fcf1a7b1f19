//! What a render is asked for: when it stops ([`Budget`]), its seed, bounces and threads
//! ([`RenderSettings`]) and the optional radiance cache's options ([`CacheSettings`]). A leaf of
//! the module: the tracer, the cache and the façade's `render` all read it, and it reads none
//! of them.

use super::RenderError;

/// Largest `capacity_log2` accepted (2^26 cells of 48 bytes: 3 GiB).
pub const MAX_CAPACITY_LOG2: u32 = 26;
/// When to stop.
#[derive(Clone, Copy, Debug)]
pub enum Budget {
    /// Exactly this many samples per pixel (>= 1).
    Spp(u32),
    /// Passes of 1 spp over the image until this much wall time is spent (checked after each
    /// pass; at least one pass runs, so the time can be overrun by one pass).
    Seconds(f64),
}

#[derive(Clone, Debug)]
pub struct RenderSettings {
    /// Maximum number of scattering events of a path (0: transmitted environment only,
    /// 1: single scattering).
    pub max_bounces: u32,
    pub seed: u64,
    pub budget: Budget,
    /// Worker threads (a private rayon pool); `None` uses rayon's global pool.
    pub threads: Option<usize>,
    /// Path-space radiance cache for multiple scattering (see [`super::cache`]); `None`
    /// renders exactly as without it.
    pub cache: Option<CacheSettings>,
}

/// Options of the radiance cache ([`RenderSettings::cache`]).
#[derive(Clone, Debug, PartialEq)]
pub struct CacheSettings {
    /// The table holds `2^capacity_log2` cells (1 ..= [`MAX_CAPACITY_LOG2`]).
    pub capacity_log2: u32,
    /// Cell edge at level 0, world units (> 0).
    pub cell_size: f32,
    /// Multiplies the footprint `path length x pixel angle` before the level of detail is
    /// taken; 0 disables the level of detail (every cell at level 0).
    pub footprint_scale: f32,
    /// Key cells also by the cube face of the propagation direction (6 bins).
    pub direction_bins: bool,
    /// Uncached training paths per pixel (>= 1).
    pub training_spp: u32,
    /// Minimum cell sample count before a path may terminate into it (>= 1).
    pub min_samples: u32,
    /// Largest standard error of the cell mean, relative to the mean, for termination.
    pub max_rel_std_err: f32,
    /// Jitter the lookup position within one cell (reduces blocky bias, adds some noise).
    pub jitter: bool,
}

impl Default for CacheSettings {
    fn default() -> Self {
        CacheSettings {
            capacity_log2: 18,
            cell_size: 0.05,
            footprint_scale: 4.0,
            direction_bins: false,
            training_spp: 4,
            min_samples: 16,
            max_rel_std_err: 0.05,
            jitter: true,
        }
    }
}

impl CacheSettings {
    /// Rejects values the cache cannot work with.
    pub fn validate(&self) -> Result<(), RenderError> {
        let bad = |why: String| {
            Err(RenderError::Invalid {
                what: "cache settings",
                why,
            })
        };
        if !(1..=MAX_CAPACITY_LOG2).contains(&self.capacity_log2) {
            return bad(format!(
                "capacity_log2 {} not in 1..=26",
                self.capacity_log2
            ));
        }
        if !(self.cell_size > 0.0 && self.cell_size.is_finite()) {
            return bad(format!("cell size {}", self.cell_size));
        }
        if !(self.footprint_scale >= 0.0 && self.footprint_scale.is_finite()) {
            return bad(format!("footprint scale {}", self.footprint_scale));
        }
        if self.training_spp == 0 || self.min_samples == 0 {
            return bad("training_spp and min_samples must be >= 1".into());
        }
        if !(self.max_rel_std_err >= 0.0) {
            return bad(format!("max_rel_std_err {}", self.max_rel_std_err));
        }
        Ok(())
    }
}
