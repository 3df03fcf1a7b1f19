//! What a render is asked for: when it stops ([`Budget`]), its seed, bounces and threads
//! ([`RenderSettings`]). A leaf of the module: the tracer, the wavefront loop and the façade's
//! `render` all read it, and it reads none of them.

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
}
