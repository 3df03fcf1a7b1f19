//! The runtime lookup options of a [`crate::Sampler`] and the named lookups.

/// Runtime lookup options (thesis fig. 4.4). Strengths are in cells; 0 turns the jitter off
/// and draws no random numbers for it.
///
/// The default ([`SamplerOptions::default`], and every sampler that is not given options) is
/// [`SamplerOptions::RENDER`], the measured-best lookup. The thesis' lookup (no jitter, one
/// lookup per query at the segment start) is [`SamplerOptions::THESIS`]; ask for it by name.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SamplerOptions {
    /// The lookup point moves by `(xi - 0.5) * strength` cells per axis.
    pub spatial_jitter: f32,
    /// The direction's continuous cell coordinates move by `(xi - 0.5) * strength` cells.
    pub directional_jitter: f32,
    /// Chained lookups (`docs/sampling.md` section 12): the query segment is cut at every
    /// `chain_stride`-th interval boundary of its chord and each piece is looked up at its own
    /// point. 0 or 32 and above: one lookup (the thesis' model).
    pub chain_stride: u32,
    /// Look each piece up at its midpoint instead of its start (section 12).
    pub midpoint_lookup: bool,
    /// A piece that starts inside the box (`s0 > 0`: the ray leaves a point in the medium,
    /// such as a shadow ray from a collision) is looked up at its start and without spatial
    /// jitter, whatever `midpoint_lookup` says (section 14). The jitter's draws are still
    /// made, so the draw order does not change. With chaining every piece after the first
    /// starts inside the box.
    pub start_inside: bool,
    /// The nearest-line lookup (`docs/sampling.md` section 15): instead of the cell that
    /// holds the lookup point, read the cell whose pin line passes nearest it, searching this
    /// many one-cell steps each side along the direction cell's axis (at most
    /// [`crate::MAX_NEAREST_LINE_STEPS`]). The spatial jitter is then not applied (its
    /// draws are still made). 0: off. Octahedral direction sets only (polar ones read the
    /// cell that holds the point); meant for pins through their cells' centres, the default
    /// bake.
    pub nearest_line: u32,
}

impl SamplerOptions {
    /// The lookup `pinrender render` and `pinrender eval` use, chosen by measurement on
    /// volumes nobody tuned for (`docs/evaluation.md`): one cell of spatial and directional
    /// jitter (`docs/sampling.md` section 11), one lookup per query at the middle of the
    /// segment (section 12), and a ray that starts inside the box looked up at its start
    /// without spatial jitter (section 14), and the nearest-line search over 8 steps
    /// (section 15). The lowest bias this library offers, and the default.
    pub const RENDER: SamplerOptions = SamplerOptions {
        spatial_jitter: 1.0,
        directional_jitter: 1.0,
        chain_stride: 32,
        midpoint_lookup: true,
        start_inside: true,
        nearest_line: 8,
    };

    /// The thesis' lookup: no jitter, one lookup per query at the segment start, in the cell
    /// that holds that point (`docs/sampling.md` section 3). The model as published, with its
    /// closed-form expectation ([`crate::Sampler::expected_transmittance`]); callers that
    /// need its answers ask for it by this name.
    pub const THESIS: SamplerOptions = SamplerOptions {
        spatial_jitter: 0.0,
        directional_jitter: 0.0,
        chain_stride: 0,
        midpoint_lookup: false,
        start_inside: false,
        nearest_line: 0,
    };

    /// The shaders' lookup mode (`Params.jitter.w` in `shaders/pin.wgsl`, `docs/gpu.md`): bit 0
    /// `midpoint_lookup`, bit 1 `start_inside`, bits 2 and up `nearest_line` (clamped to
    /// [`crate::MAX_NEAREST_LINE_STEPS`]); a small integer, exact in f32.
    pub fn lookup_mode(&self) -> f32 {
        let steps = self.nearest_line.min(crate::lookup::MAX_NEAREST_LINE_STEPS);
        (u32::from(self.midpoint_lookup) | (u32::from(self.start_inside) << 1) | (steps << 2))
            as f32
    }

    /// Intervals per lookup, in `1..=32`.
    pub fn stride(&self) -> u32 {
        if self.chain_stride == 0 || self.chain_stride > 32 {
            32
        } else {
            self.chain_stride
        }
    }

    pub(crate) fn spatial_on(&self) -> bool {
        self.spatial_jitter > 0.0 && self.spatial_jitter.is_finite()
    }
    pub(crate) fn directional_on(&self) -> bool {
        self.directional_jitter > 0.0 && self.directional_jitter.is_finite()
    }
}

impl Default for SamplerOptions {
    /// [`SamplerOptions::RENDER`], the measured-best lookup.
    fn default() -> Self {
        Self::RENDER
    }
}
