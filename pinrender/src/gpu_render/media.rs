//! What the GPU path tracer renders: pin grids, density fields and their placed instances,
//! and their packing into the flat records `shaders/render.wgsl` reads.
//!
//! A scene's media are [`GpuMedia`]: the distinct pin grids (concatenated into one pin and one
//! cell-index buffer), the distinct density fields ([`GpuDensity`]: a voxel grid in the
//! project's convention, dense or bricked, or closed-form cosine noise), and the instances
//! ([`GpuMedium`]), each
//! with an optional placed pin grid (what `pins` and PinMS query) and an optional placed
//! density with its world-space majorant grid (what ray marching and the trackers query).
//! An instance may have either or both; which estimators a render may use follows from that.

use std::borrow::Cow;
use std::collections::HashMap;
use std::sync::Arc;

use bytemuck::{Pod, Zeroable};

use crate::render::{
    BrickGrid, Density, EstimatorSpec, HomogeneousBox, MajorantGrid, RenderError, ResidualControl,
    VoxelGrid,
};
use pin_format::SparseValues;
use pinrt::Error;
use pinrt::PinGrid;
use pinrt::SamplerOptions;
use pinrt::UnitTransform;
pub(super) use pinrt::gpu::Params as GridParams;
use pinrt::gpu::check_binding;

/// One cosine wave of [`GpuDensityKind::Cosine`]: `amplitude * cos(w . p + phase)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CosineWave {
    pub w: [f32; 3],
    pub amplitude: f32,
    pub phase: f32,
}

/// The extinction function of a [`GpuDensity`], in its local frame.
#[derive(Clone, Debug)]
pub enum GpuDensityKind {
    /// A dense voxel grid in the convention of [`VoxelGrid`] (docs/background.md section 2): dims `N`,
    /// spacing `s`, origin `o` occupy `[o, o + N s]`, voxel centres at `o + (i + 0.5) s`,
    /// trilinear between centres, the edge voxel's value in the outer half voxel; values `x`
    /// fastest, cleaned by [`VoxelGrid::new`]. Evaluated in f32 on the GPU.
    Voxels(VoxelGrid),
    /// The same convention in bricks behind a top-level index ([`BrickGrid`]: one `u32` per
    /// brick, empty bricks read 0), for grids too large for one dense binding. The shader
    /// reads the eight voxels of a lookup through the index (no apron: a lookup across a
    /// brick border reads the neighbour brick) with the dense grid's f32 arithmetic, so a
    /// bricked grid renders the same bits as its dense expansion. Brick values live in up to
    /// [`MAX_VALUE_BINDINGS`] storage bindings, as f16 when every value is exactly an f16 (a pin
    /// file's f16 sparse section), else as f32 (`docs/gpu.md`, "Bricked densities").
    Bricks(Arc<BrickGrid>),
    /// `density * max(0, 1 + sum_k amplitude_k cos(w_k . p + phase_k))`, pinbake's cosine
    /// noise (evaluated in f32 with the phase reduced to turns before the cosine).
    Cosine {
        density: f32,
        waves: Vec<CosineWave>,
    },
}

/// A density field for the GPU estimators: an extinction function and the local box that
/// holds all of it (extinction is 0 outside `bounds`; ray marching steps are relative to its
/// longest edge, as on the CPU, where it is [`crate::render::Density::bounds`]).
#[derive(Clone, Debug)]
pub struct GpuDensity {
    pub bounds: ([f64; 3], [f64; 3]),
    pub kind: GpuDensityKind,
}

fn invalid(why: String) -> RenderError {
    RenderError::Invalid {
        what: "GPU density",
        why,
    }
}

fn check_box(lo: &[f64; 3], hi: &[f64; 3]) -> Result<(), RenderError> {
    if (0..3).all(|a| lo[a].is_finite() && hi[a].is_finite() && lo[a] < hi[a]) {
        Ok(())
    } else {
        Err(invalid(format!(
            "box {lo:?}..{hi:?} must be finite with min < max on every axis"
        )))
    }
}

impl GpuDensity {
    /// A voxel grid; `bounds` is the grid's box `[origin, origin + dims * spacing]`. Values are
    /// used as the CPU estimators use them: NaN and negatives count as 0, `+inf` as opaque
    /// (stored as `f32::MAX`).
    pub fn voxels(
        dims: [u32; 3],
        origin: [f64; 3],
        spacing: [f64; 3],
        values: Vec<f32>,
    ) -> Result<Self, RenderError> {
        Self::from_voxel_grid(VoxelGrid::new(dims, origin, spacing, values)?)
    }

    /// The GPU copy of a CPU [`VoxelGrid`] (same convention, same box). Errors only for a box
    /// that overflows (`origin + dims * spacing` not finite).
    pub fn from_voxel_grid(grid: VoxelGrid) -> Result<Self, RenderError> {
        let (lo, hi) = grid.bounds().to_arrays();
        check_box(&lo, &hi)?;
        Ok(GpuDensity {
            bounds: (lo, hi),
            kind: GpuDensityKind::Voxels(grid),
        })
    }

    /// The GPU copy of a [`BrickGrid`] (shared, not copied; same convention, same box).
    pub fn from_bricks(grid: Arc<BrickGrid>) -> Result<Self, RenderError> {
        let (lo, hi) = grid.bounds().to_arrays();
        check_box(&lo, &hi)?;
        Ok(GpuDensity {
            bounds: (lo, hi),
            kind: GpuDensityKind::Bricks(grid),
        })
    }

    /// A homogeneous box: one voxel over the box, which the convention makes constant inside.
    pub fn homogeneous(b: &HomogeneousBox) -> Result<Self, RenderError> {
        let (lo, hi) = b.bounds().to_arrays();
        check_box(&lo, &hi)?;
        let spacing = [0, 1, 2].map(|a| hi[a] - lo[a]);
        let mut d = Self::voxels([1, 1, 1], lo, spacing, vec![b.density()])?;
        // The box exactly, not origin + 1 * spacing (which may round).
        d.bounds = (lo, hi);
        Ok(d)
    }

    /// Cosine noise over the box `[lo, hi]`.
    pub fn cosine(
        lo: [f64; 3],
        hi: [f64; 3],
        density: f32,
        waves: Vec<CosineWave>,
    ) -> Result<Self, RenderError> {
        check_box(&lo, &hi)?;
        if !(density.is_finite() && density >= 0.0) {
            return Err(invalid(format!("cosine density {density}")));
        }
        if let Some(w) = waves.iter().find(|w| {
            !(w.w.iter().all(|x| x.is_finite()) && w.amplitude.is_finite() && w.phase.is_finite())
        }) {
            return Err(invalid(format!("cosine wave {w:?} is not finite")));
        }
        Ok(GpuDensity {
            bounds: (lo, hi),
            kind: GpuDensityKind::Cosine { density, waves },
        })
    }

    /// The extinction the shader computes at the density-local point `p` (in f64; the shader
    /// works in f32): 0 outside [`GpuDensity::bounds`]. For tests and tools that check a GPU
    /// copy against its source.
    pub fn extinction(&self, p: [f64; 3]) -> f64 {
        let (lo, hi) = self.bounds;
        if !(0..3).all(|a| p[a] >= lo[a] && p[a] <= hi[a]) {
            return 0.0;
        }
        match &self.kind {
            GpuDensityKind::Cosine { density, waves } => {
                let s = waves.iter().fold(1.0, |s, w| {
                    let dot = (0..3).map(|a| f64::from(w.w[a]) * p[a]).sum::<f64>();
                    s + f64::from(w.amplitude) * (dot + f64::from(w.phase)).cos()
                });
                (f64::from(*density) * s).max(0.0)
            }
            GpuDensityKind::Voxels(grid) => grid.trilinear(p),
            GpuDensityKind::Bricks(grid) => grid.trilinear(p),
        }
    }

    /// The same field clipped to a smaller box (e.g. a VDB's support box inside the voxel
    /// grid that holds it with a border of zeros).
    pub fn with_bounds(mut self, lo: [f64; 3], hi: [f64; 3]) -> Result<Self, RenderError> {
        check_box(&lo, &hi)?;
        self.bounds = (lo, hi);
        Ok(self)
    }
}

/// A pin grid of [`GpuMedia::grids`] placed for one instance.
#[derive(Clone, Debug)]
pub struct GpuPins {
    /// Index into [`GpuMedia::grids`].
    pub grid: usize,
    /// Placement (row-major 3x4 local-to-world); `None`: the file's own.
    pub local_to_world: Option<[f64; 12]>,
    /// Lookup jitter, as for [`pinrt::Sampler`].
    pub options: SamplerOptions,
}

/// A density of [`GpuMedia::densities`] placed for one instance: by a translation into the
/// world, or by a translation into an asset's frame that `placement` places in the world by
/// any invertible affine map.
///
/// Without `placement` the translation, the majorants and the controls are in the world and
/// every query is asked there. With it they are all in the asset's frame, and every density
/// query of the instance is asked in that frame as the CPU's `instance::PlacedEstimator`
/// asks it: the ray mapped (`o_l = A o + b`, `d_l = A d`, `A, b` the inverse of
/// `placement`), its direction normalised, the segment's length scaled by `|d_l|`, a sampled
/// distance mapped back by the same factor. So one asset's density, majorants and controls
/// are uploaded once for all its instances (the packing shares every `Arc` it is given).
#[derive(Clone, Debug)]
pub struct GpuPlacedDensity {
    /// Index into [`GpuMedia::densities`].
    pub density: usize,
    /// Position (world, or the asset's frame with `placement`) = density-local position +
    /// `translation`.
    pub translation: [f64; 3],
    /// Row-major 3x4 local-to-world of the asset's frame; `None`: the frame is the world.
    pub placement: Option<[f64; 12]>,
    /// Majorant grid over the placed density, in the frame of `translation` (needed by the
    /// trackers).
    pub majorants: Option<Arc<MajorantGrid>>,
    /// The residual controls of this instance, at most one per residual estimator
    /// (`residual`, `residual@min`, `pinres`: [`GpuControl::spec`]), in the frame of
    /// `translation`.
    pub controls: Vec<Arc<GpuControl>>,
}

/// What residual ratio tracking reads for one instance, in the world (as the CPU's
/// `ResidualRatioTracking` holds it): per brick of `residual`'s grid a control extinction
/// (`controls`, the grid's layout) and a residual majorant (`residual`'s values), and the
/// majorants that its distances and paired queries track. Packed into the density data
/// buffer (no binding of its own).
#[derive(Clone, Debug)]
pub struct GpuControl {
    /// The estimator that reads it: `residual@mean`, `residual@min` or `pinres`.
    pub spec: EstimatorSpec,
    pub residual: MajorantGrid,
    pub controls: Vec<f32>,
    pub majorants: Arc<MajorantGrid>,
}

/// Slots of a medium's control table, one per residual estimator.
pub(super) const CONTROL_SLOTS: usize = 3;
/// Words per slot (`RT_CONTROL_WORDS` of `render.wgsl`).
const CONTROL_WORDS: usize = 24;

/// The slot of the control table that `spec` reads, if it reads one.
pub(super) fn control_slot(spec: EstimatorSpec) -> Option<usize> {
    match spec {
        EstimatorSpec::ResidualRatioTracking {
            control: ResidualControl::Mean,
        } => Some(0),
        EstimatorSpec::ResidualRatioTracking {
            control: ResidualControl::Min,
        } => Some(1),
        EstimatorSpec::PinRes => Some(2),
        _ => None,
    }
}

/// One medium instance. Media add: distance sampling takes the nearest collision over the
/// instances, transmittance multiplies (as `Scene::media` on the CPU).
#[derive(Clone, Debug, Default)]
pub struct GpuMedium {
    pub pins: Option<GpuPins>,
    pub density: Option<GpuPlacedDensity>,
}

/// Everything a [`super::GpuRenderer`] uploads.
#[derive(Clone, Debug, Default)]
pub struct GpuMedia<'g> {
    pub grids: Vec<&'g PinGrid>,
    pub densities: Vec<GpuDensity>,
    pub media: Vec<GpuMedium>,
}

impl<'g> GpuMedia<'g> {
    /// One pin grid as the only medium (what "pins for everything" needs).
    pub fn pins_only(
        grid: &'g PinGrid,
        local_to_world: Option<&[f64; 12]>,
        options: SamplerOptions,
    ) -> Self {
        GpuMedia {
            grids: vec![grid],
            densities: Vec::new(),
            media: vec![GpuMedium {
                pins: Some(GpuPins {
                    grid: 0,
                    local_to_world: local_to_world.copied(),
                    options,
                }),
                density: None,
            }],
        }
    }
}

/// What one instance can answer (checked against the estimator at render time).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) struct Caps {
    pub pins: bool,
    pub density: bool,
    pub majorants: bool,
    /// A residual control per slot ([`control_slot`]).
    pub controls: [bool; CONTROL_SLOTS],
}

/// `RtMedium` of `render.wgsl` (288 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub(super) struct MediumRecord {
    pub ids: [u32; 4],
    pub offs: [u32; 4],
    pub vdims: [u32; 4],
    pub mdims: [u32; 4],
    pub translation: [f32; 4],
    pub clip_lo: [f32; 4],
    pub clip_hi: [f32; 4],
    pub vox_origin: [f32; 4],
    pub vox_inv: [f32; 4],
    pub maj_lo: [f32; 4],
    pub maj_hi: [f32; 4],
    pub pin_lo: [f32; 4],
    pub pin_hi: [f32; 4],
    /// Bricks: first index entry in the data buffer, bricks along x and y, first value word.
    pub bidx: [u32; 4],
    /// Bricks: log2 of the brick edge, 1 for f16 values (else f32), words per value binding,
    /// unused.
    pub bfmt: [u32; 4],
    /// World to the asset's frame, rows `(A_i0, A_i1, A_i2, b_i)` in f32 (as the CPU's
    /// `PlacedEstimator` holds them), where `FLAG_PLACED` is set.
    pub to_local: [[f32; 4]; 3],
}

pub(super) const FLAG_PINS: u32 = 1;
pub(super) const FLAG_DENSITY: u32 = 2;
pub(super) const FLAG_MAJORANTS: u32 = 4;
/// The density is queried in its asset's frame (`to_local`): the boxes, majorants and
/// controls of the record are in that frame.
pub(super) const FLAG_PLACED: u32 = 8;
/// With `FLAG_PLACED`: the linear part is exactly the identity, so a query keeps its
/// direction and lengths and only its origin moves (the CPU's `translation_only`).
pub(super) const FLAG_SHIFTED: u32 = 16;
const KIND_VOXELS: u32 = 1;
const KIND_COSINE: u32 = 2;
const KIND_BRICKS: u32 = 3;
/// The most storage bindings that hold brick values (`rt_bricks0..` of `render.wgsl`):
/// bricks that exceed one binding are split over as many as the scene needs and the device
/// binds beside the path tracer's other storage buffers ([`value_bindings`]). Lavapipe binds
/// 32 storage buffers of 128 MiB in a stage, so 26 value bindings: 3.25 GiB of bricks, which
/// holds the full-size production cloud's 3.18 GB of f16 bricks.
pub const MAX_VALUE_BINDINGS: usize = 32;
/// The path tracer's storage buffers besides the brick values: the pins and cell indices
/// (group 0), the accumulation, grid parameters, media and data (group 1).
pub const OTHER_STORAGE_BINDINGS: u32 = 6;

/// How many brick value bindings the path tracer can use on a device with `limits`: what it
/// binds in the compute stage beside the other storage buffers, at most
/// [`MAX_VALUE_BINDINGS`] (0 where it cannot bind even the others and one).
pub fn value_bindings(limits: &wgpu::Limits) -> usize {
    (limits
        .max_storage_buffers_per_shader_stage
        .saturating_sub(OTHER_STORAGE_BINDINGS) as usize)
        .min(MAX_VALUE_BINDINGS)
}

/// Floats per cosine wave in the data buffer.
const WAVE_FLOATS: usize = 8;

/// Where the brick values of a scene's bricked densities go: one address space of 32-bit
/// words, cut into value bindings of `cap_words` each. Each grid's bricks are consecutive
/// from its `base` (a multiple of its brick's words, which divide `cap_words`), so no brick
/// straddles two bindings.
pub(super) struct BrickValues {
    pub cap_words: u64,
    pub total_words: u64,
    /// Grid, first word, f16 (two values per word, the lower half first) or f32.
    pub grids: Vec<(Arc<BrickGrid>, u64, bool)>,
}

impl BrickValues {
    /// Number of value bindings in use.
    pub fn bindings(&self) -> usize {
        self.total_words.div_ceil(self.cap_words.max(1)) as usize
    }

    /// Words `first..first + out.len()` of the value space into `out`.
    pub fn fill(&self, first: u64, out: &mut [u32]) {
        let start = first;
        let end = start + out.len() as u64;
        for (grid, base, f16) in &self.grids {
            let (_, values) = grid.parts();
            let words = if *f16 { values.len() / 2 } else { values.len() } as u64;
            let (lo, hi) = ((*base).max(start), (base + words).min(end));
            if lo >= hi {
                continue;
            }
            let dst = &mut out[(lo - start) as usize..(hi - start) as usize];
            let from = (lo - base) as usize;
            match (values, *f16) {
                // Stored as f16: the bits as they are.
                (SparseValues::F16(v), true) => {
                    for (k, d) in dst.iter_mut().enumerate() {
                        let i = 2 * (from + k);
                        *d = u32::from(v[i].to_bits()) | (u32::from(v[i + 1].to_bits()) << 16);
                    }
                }
                // f32 values that are all exactly f16 (`keeps_f16`).
                (SparseValues::F32(v), true) => {
                    let h = |x: f32| u32::from(half::f16::from_f32(x).to_bits());
                    for (k, d) in dst.iter_mut().enumerate() {
                        let i = 2 * (from + k);
                        *d = h(v[i]) | (h(v[i + 1]) << 16);
                    }
                }
                (values, false) => {
                    for (k, d) in dst.iter_mut().enumerate() {
                        *d = values.get(from + k).unwrap_or(0.0).to_bits();
                    }
                }
            }
        }
    }
}

/// Whether the GPU keeps `grid`'s values as f16: every value is exactly an f16 (and a brick
/// holds whole words of them).
fn keeps_f16(grid: &BrickGrid) -> bool {
    let (_, brick, _) = grid.shape();
    brick >= 2
        && match grid.parts().1 {
            SparseValues::F16(_) => true,
            SparseValues::F32(v) => v
                .iter()
                .all(|&x| half::f16::from_f32(x).to_f32().to_bits() == x.to_bits()),
        }
}

/// The buffers of a scene's media, ready to upload.
pub(super) struct Packed<'g> {
    pub grid_params: Vec<GridParams>,
    pub records: Vec<MediumRecord>,
    /// Voxels, cosine waves, majorants (f32 bits) and brick indices (u32).
    pub data: Vec<u32>,
    pub bricks: BrickValues,
    pub pins: Cow<'g, [u8]>,
    pub index: Cow<'g, [u8]>,
    pub caps: Vec<Caps>,
    /// Where the media's hierarchy's nodes start in `data` (`RtParams.seed.w`; its node
    /// count is the word before); 0: none, the shader scans every medium.
    pub bvh: u32,
}

/// The fewest media the path tracer walks by a hierarchy (fewer: the linear scan, whose box
/// tests cost less than the walk's).
pub(super) const BVH_MIN_MEDIA: usize = 8;

/// A medium's world box for the hierarchy: the union of the boxes its queries stay in (the
/// placed pin grid, the density's clip box, the majorant grid's box), widened by a relative
/// 1e-3 so that no f32 rounding of the shader's node test misses a ray its own tests would
/// meet. `None` for a medium with none of them (it is met by every ray).
/// For a density placed in an asset's frame (`placement`), its boxes are in that frame and
/// count as the world box of their corners.
fn medium_box(r: &MediumRecord, placement: Option<&[f64; 12]>) -> Option<([f64; 3], [f64; 3])> {
    let add = |(lo, hi): &mut ([f64; 3], [f64; 3]), l: [f64; 3], h: [f64; 3]| {
        for a in 0..3 {
            lo[a] = lo[a].min(l[a]);
            hi[a] = hi[a].max(h[a]);
        }
    };
    let wide = |v: &[f32; 4]| [0, 1, 2].map(|a| f64::from(v[a]));
    let empty = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    let mut density = empty;
    if r.ids[2] & FLAG_DENSITY != 0 {
        add(&mut density, wide(&r.clip_lo), wide(&r.clip_hi));
    }
    if r.ids[2] & FLAG_MAJORANTS != 0 {
        add(&mut density, wide(&r.maj_lo), wide(&r.maj_hi));
    }
    if let Some(m) = placement
        && density != empty
    {
        if !(0..3).all(|a| density.0[a].is_finite() && density.1[a].is_finite()) {
            return None;
        }
        density = crate::instance::world_box(m, density);
    }
    let mut all = empty;
    if r.ids[2] & FLAG_PINS != 0 {
        add(&mut all, wide(&r.pin_lo), wide(&r.pin_hi));
    }
    add(&mut all, density.0, density.1);
    let (lo, hi) = all;
    if !(0..3).all(|a| lo[a].is_finite() && hi[a].is_finite() && lo[a] <= hi[a]) {
        return None;
    }
    let pad = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max) * 1e-3
        + lo.iter().chain(&hi).fold(0.0f64, |acc, v| acc.max(v.abs())) * 1e-5
        + 1e-30;
    Some((lo.map(|v| v - pad), hi.map(|v| v + pad)))
}

/// Appends the hierarchy over `records`' boxes to `data` (its node count, then its nodes:
/// `render::bvh`'s, which hand out the media a ray meets in media order, so a walk combines
/// them as the linear scan does) and returns `RtParams.seed.w` for it; 0 (no hierarchy) for
/// fewer than [`BVH_MIN_MEDIA`] media or a medium without a finite box.
fn pack_bvh(
    records: &[MediumRecord],
    placements: &[Option<[f64; 12]>],
    data: &mut Vec<u32>,
) -> u32 {
    if records.len() < BVH_MIN_MEDIA {
        return 0;
    }
    let mut lo: [Vec<f32>; 3] = Default::default();
    let mut hi: [Vec<f32>; 3] = Default::default();
    for (r, p) in records.iter().zip(placements) {
        let Some((l, h)) = medium_box(r, p.as_ref()) else {
            return 0;
        };
        // Rounding to f32 moves a bound by half an ulp, far inside the padding.
        for a in 0..3 {
            lo[a].push(l[a] as f32);
            hi[a].push(h[a] as f32);
        }
    }
    let Some(words) = crate::render::bvh::Bvh::build(&lo, &hi).and_then(|b| b.gpu_words()) else {
        return 0;
    };
    let Ok(start) = u32::try_from(data.len() + 1) else {
        return 0;
    };
    if u32::try_from(data.len() + 1 + words.len()).is_err() {
        return 0;
    }
    data.push((words.len() / 8) as u32);
    data.extend(words);
    start
}

/// Conservative world AABB of a grid's box under `local_to_world` (row-major 3x4), widened by
/// a relative 1e-4 so that f32 rounding in the query never finds a chord outside it.
fn placed_box(grid: &PinGrid, m: &[f64; 12]) -> ([f32; 4], [f32; 4]) {
    let d = grid.desc();
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for c in 0..8 {
        let p = [0, 1, 2].map(|a| {
            if c & (1 << a) == 0 {
                d.box_min[a]
            } else {
                d.box_max[a]
            }
        });
        for r in 0..3 {
            let w = m[4 * r] * p[0] + m[4 * r + 1] * p[1] + m[4 * r + 2] * p[2] + m[4 * r + 3];
            lo[r] = lo[r].min(w);
            hi[r] = hi[r].max(w);
        }
    }
    let pad = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max) * 1e-4
        + lo.iter().chain(&hi).fold(0.0f64, |acc, v| acc.max(v.abs())) * 1e-6;
    (
        [
            (lo[0] - pad) as f32,
            (lo[1] - pad) as f32,
            (lo[2] - pad) as f32,
            0.0,
        ],
        [
            (hi[0] + pad) as f32,
            (hi[1] + pad) as f32,
            (hi[2] + pad) as f32,
            0.0,
        ],
    )
}

/// The rows `(A_i0, A_i1, A_i2, b_i)` of the inverse of `local_to_world` in f32, as the
/// CPU's `instance::PlacedEstimator` makes them; why not where it is singular or its inverse
/// overflows f32.
fn to_local(local_to_world: &[f64; 12]) -> Result<[[f32; 4]; 3], String> {
    let inv = crate::instance::invert(local_to_world)
        .ok_or_else(|| "the instance transform is singular".to_string())?;
    let mut rows = [[0.0f32; 4]; 3];
    for (i, row) in rows.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = inv[4 * i + j] as f32;
            if !v.is_finite() {
                return Err("the instance transform's inverse overflows f32".into());
            }
        }
    }
    Ok(rows)
}

fn f4(v: [f64; 3], w: f32) -> [f32; 4] {
    [v[0] as f32, v[1] as f32, v[2] as f32, w]
}

fn gpu(why: String) -> Error {
    Error::Gpu(why)
}

/// Appends an instance's residual controls to `data`: the table of [`CONTROL_SLOTS`] slots
/// (`RT_CONTROL_WORDS` of `render.wgsl` says what each word holds), then each control's
/// values, residual majorants and tracked majorants.
fn pack_controls(
    r: &mut MediumRecord,
    cap: &mut Caps,
    data: &mut Vec<u32>,
    controls: &[Arc<GpuControl>],
    medium: usize,
) -> pinrt::Result<()> {
    let to_u32 = |what: &str, v: usize| {
        u32::try_from(v).map_err(|_| gpu(format!("{what} offset {v} exceeds u32")))
    };
    let table = data.len();
    r.offs[3] = to_u32("control table", table)?;
    data.resize(table + CONTROL_SLOTS * CONTROL_WORDS, 0);
    for c in controls {
        let slot = control_slot(c.spec).ok_or_else(|| {
            gpu(format!(
                "medium {medium}: {} reads no residual control",
                c.spec
            ))
        })?;
        let n = c.residual.values().len();
        if c.controls.len() != n {
            return Err(gpu(format!(
                "medium {medium}: {} controls for {n} residual bricks",
                c.controls.len()
            )));
        }
        let at = table + slot * CONTROL_WORDS;
        let f3 = |v: [f64; 3]| v.map(|x| (x as f32).to_bits());
        let (lo, hi) = c.residual.bounds();
        let (mlo, mhi) = c.majorants.bounds();
        let (rd, md) = (c.residual.dims(), c.majorants.dims());
        let control_at = to_u32("control", data.len())?;
        data.extend(c.controls.iter().map(|v| v.to_bits()));
        let residual_at = to_u32("residual majorant", data.len())?;
        data.extend(c.residual.values().iter().map(|v| v.to_bits()));
        let majorant_at = to_u32("majorant", data.len())?;
        data.extend(c.majorants.values().iter().map(|v| v.to_bits()));
        let e = &mut data[at..at + CONTROL_WORDS];
        e[0..3].copy_from_slice(&f3(lo));
        e[3] = control_at;
        e[4..7].copy_from_slice(&f3(hi));
        e[7] = residual_at;
        e[8..11].copy_from_slice(&rd);
        e[11] = majorant_at;
        e[12..15].copy_from_slice(&md);
        e[16..19].copy_from_slice(&f3(mlo));
        e[20..23].copy_from_slice(&f3(mhi));
        cap.controls[slot] = true;
    }
    Ok(())
}

/// Words of brick values one binding holds (whole bricks of `brick_words` words), for
/// `total_words` words over at most `bindings` bindings of `limit` bytes each; the one-line
/// refusal when they do not fit. Word addresses stay below 2^32 whatever the binding count.
fn brick_value_capacity(
    limit: u64,
    bindings: usize,
    total_words: u64,
    brick_words: u64,
) -> pinrt::Result<u64> {
    let per_binding = (limit / 4).min(u64::from(u32::MAX) / MAX_VALUE_BINDINGS as u64);
    let cap = per_binding
        .checked_div(brick_words)
        .map_or(0, |whole| whole * brick_words);
    if cap == 0 || total_words.div_ceil(cap) > bindings as u64 {
        return Err(gpu(format!(
            "the bricked densities need {} bytes of brick values ({} bytes per brick), \
             more than {bindings} storage bindings of {limit} bytes hold on this device; \
             use a smaller volume or a device with larger storage bindings",
            total_words.saturating_mul(4),
            brick_words * 4
        )));
    }
    Ok(cap)
}

/// Checks, before any brick is read, that `bricks` stored bricks of edge `edge` can go to a
/// device whose largest storage binding is `limit` bytes and that gives the brick values
/// `bindings` bindings ([`value_bindings`]), counting them at their smallest (f16, as a pin
/// file's bricks go): a sparse density this refuses, [`pack`] would refuse after the bricks
/// were widened and packed; one it passes may still be refused there, if its values are not
/// all f16.
pub fn check_brick_values_fit(
    limit: u64,
    bindings: usize,
    edge: u32,
    bricks: u64,
) -> pinrt::Result<()> {
    let words = u64::from(edge).pow(3) >> u32::from(edge >= 2);
    brick_value_capacity(limit, bindings, bricks.saturating_mul(words), words.max(1)).map(|_| ())
}

/// Packs `media` into the shader's records; `limit` is the largest storage binding in bytes,
/// `bindings` the most brick value bindings ([`value_bindings`]).
pub(super) fn pack<'g>(
    media: &GpuMedia<'g>,
    limit: u64,
    bindings: usize,
) -> pinrt::Result<Packed<'g>> {
    let check = |what: &str, len: usize| check_binding(limit, what, len);
    // Pin grids: concatenated (borrowed straight from the mapping when there is one).
    let mut pin_base = Vec::with_capacity(media.grids.len());
    let mut index_base = Vec::with_capacity(media.grids.len());
    let (pins, index): (Cow<'g, [u8]>, Cow<'g, [u8]>) = match media.grids.as_slice() {
        [g] => {
            pin_base.push(0);
            index_base.push(0);
            (
                Cow::Borrowed(g.pins_bytes()),
                Cow::Borrowed(g.cell_index_bytes().unwrap_or(&[])),
            )
        }
        grids => {
            let mut p = Vec::new();
            let mut x = Vec::new();
            for g in grids {
                pin_base.push(p.len() / 8);
                index_base.push(x.len() / 4);
                p.extend_from_slice(g.pins_bytes());
                x.extend_from_slice(g.cell_index_bytes().unwrap_or(&[]));
            }
            (Cow::Owned(p), Cow::Owned(x))
        }
    };
    check("the pin sections", pins.len())?;
    check("the cell indices", index.len())?;
    let to_u32 = |what: &str, v: usize| {
        u32::try_from(v).map_err(|_| gpu(format!("{what} offset {v} exceeds u32")))
    };

    // Densities: values and waves (f32 bits) and brick indices at offsets in one u32 array;
    // brick values in their own address space.
    let mut data: Vec<u32> = Vec::new();
    let mut density_off = Vec::with_capacity(media.densities.len());
    // Per density: its bricks' first value word and whether they are f16.
    let mut brick_at = vec![(0u64, false); media.densities.len()];
    let mut bricks = BrickValues {
        cap_words: 0,
        total_words: 0,
        grids: Vec::new(),
    };
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
    let mut largest_brick = 0u64;
    for (k, d) in media.densities.iter().enumerate() {
        density_off.push(data.len());
        match &d.kind {
            GpuDensityKind::Voxels(grid) => data.extend(grid.parts().3.iter().map(|v| v.to_bits())),
            GpuDensityKind::Bricks(grid) => {
                data.extend_from_slice(grid.parts().0);
                let (_, brick, slots) = grid.shape();
                let f16 = keeps_f16(grid);
                let words = u64::from(brick).pow(3) >> u32::from(f16);
                let base = bricks.total_words.next_multiple_of(words);
                brick_at[k] = (base, f16);
                bricks.total_words = base + words * slots as u64;
                largest_brick = largest_brick.max(words);
                bricks.grids.push((grid.clone(), base, f16));
            }
            GpuDensityKind::Cosine { waves, .. } => {
                for w in waves {
                    data.extend(bits(&[
                        w.w[0],
                        w.w[1],
                        w.w[2],
                        w.amplitude,
                        w.phase,
                        0.0,
                        0.0,
                        0.0,
                    ]));
                }
                debug_assert_eq!(data.len() % WAVE_FLOATS, 0);
            }
        }
    }
    if largest_brick > 0 {
        bricks.cap_words =
            brick_value_capacity(limit, bindings, bricks.total_words, largest_brick)?;
    }

    let mut params = Vec::with_capacity(media.media.len());
    let mut records = Vec::with_capacity(media.media.len());
    let mut caps = Vec::with_capacity(media.media.len());
    let mut placements = Vec::with_capacity(media.media.len());
    // Majorant grids and control tables shared between instances are packed once: where
    // each one's values start in `data`, by the `Arc`s that hold them.
    let mut majorants_at: HashMap<*const MajorantGrid, u32> = HashMap::new();
    let mut tables_at: HashMap<Vec<*const GpuControl>, u32> = HashMap::new();
    for (i, m) in media.media.iter().enumerate() {
        let mut r = MediumRecord::zeroed();
        let mut cap = Caps::default();
        let mut gp = GridParams::zeroed();
        if let Some(p) = &m.pins {
            let grid = *media.grids.get(p.grid).ok_or_else(|| {
                gpu(format!(
                    "medium {i}: pin grid {} of {}",
                    p.grid,
                    media.grids.len()
                ))
            })?;
            let placement = p.local_to_world.unwrap_or(grid.desc().local_to_world);
            let xf = UnitTransform::new(grid.desc(), Some(&placement))?;
            gp = GridParams::for_grid(grid, &xf, p.options)?;
            (r.pin_lo, r.pin_hi) = placed_box(grid, &placement);
            r.ids[0] = to_u32("pin", pin_base[p.grid])?;
            r.ids[1] = to_u32("cell index", index_base[p.grid])?;
            r.ids[2] |= FLAG_PINS;
            cap.pins = true;
        }
        if let Some(pd) = &m.density {
            let d = media.densities.get(pd.density).ok_or_else(|| {
                gpu(format!(
                    "medium {i}: density {} of {}",
                    pd.density,
                    media.densities.len()
                ))
            })?;
            let t = pd.translation;
            if !t.iter().all(|v| v.is_finite()) {
                return Err(gpu(format!("medium {i}: translation {t:?} is not finite")));
            }
            if let Some(pm) = &pd.placement {
                r.to_local = to_local(pm).map_err(|why| gpu(format!("medium {i}: {why}")))?;
                r.ids[2] |= FLAG_PLACED;
                if crate::instance::is_translation(pm) {
                    r.ids[2] |= FLAG_SHIFTED;
                }
            }
            let (lo, hi) = d.bounds;
            let wlo = [0, 1, 2].map(|a| lo[a] + t[a]);
            let whi = [0, 1, 2].map(|a| hi[a] + t[a]);
            let longest = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
            r.translation = f4(t, longest as f32);
            r.offs[0] = to_u32("density", density_off[pd.density])?;
            r.ids[2] |= FLAG_DENSITY;
            match &d.kind {
                GpuDensityKind::Voxels(grid) => {
                    let (dims, origin, spacing, _) = grid.parts();
                    r.ids[3] = KIND_VOXELS;
                    r.vdims = [dims[0], dims[1], dims[2], 0];
                    r.vox_origin = f4(origin, 0.0);
                    r.vox_inv = f4(spacing.map(|s| 1.0 / s), 0.0);
                    r.clip_lo = f4(wlo, 0.0);
                }
                GpuDensityKind::Bricks(grid) => {
                    let (dims, brick, _) = grid.shape();
                    let (origin, spacing) = grid.placement();
                    let (base, f16) = brick_at[pd.density];
                    r.ids[3] = KIND_BRICKS;
                    r.vdims = [dims[0], dims[1], dims[2], 0];
                    r.vox_origin = f4(origin, 0.0);
                    r.vox_inv = f4(spacing.map(|s| 1.0 / s), 0.0);
                    r.clip_lo = f4(wlo, 0.0);
                    r.bidx = [
                        r.offs[0],
                        dims[0].div_ceil(brick),
                        dims[1].div_ceil(brick),
                        to_u32("brick value", base as usize)?,
                    ];
                    r.bfmt = [
                        brick.trailing_zeros(),
                        u32::from(f16),
                        to_u32("brick binding", bricks.cap_words as usize)?,
                        0,
                    ];
                }
                GpuDensityKind::Cosine { density, waves } => {
                    r.ids[3] = KIND_COSINE;
                    r.offs[1] = to_u32("wave count", waves.len())?;
                    r.clip_lo = f4(wlo, *density);
                }
            }
            r.clip_hi = f4(whi, 0.0);
            cap.density = true;
            if let Some(mg) = &pd.majorants {
                let (mlo, mhi) = mg.bounds();
                let md = mg.dims();
                r.offs[2] = match majorants_at.get(&Arc::as_ptr(mg)) {
                    Some(&at) => at,
                    None => {
                        let at = to_u32("majorant", data.len())?;
                        data.extend(mg.values().iter().map(|v| v.to_bits()));
                        majorants_at.insert(Arc::as_ptr(mg), at);
                        at
                    }
                };
                r.mdims = [md[0], md[1], md[2], 0];
                r.maj_lo = f4(mlo, 0.0);
                r.maj_hi = f4(mhi, 0.0);
                r.ids[2] |= FLAG_MAJORANTS;
                cap.majorants = true;
            }
            if !pd.controls.is_empty() {
                let key: Vec<*const GpuControl> = pd.controls.iter().map(Arc::as_ptr).collect();
                match tables_at.get(&key) {
                    Some(&at) => {
                        r.offs[3] = at;
                        for c in &pd.controls {
                            if let Some(slot) = control_slot(c.spec) {
                                cap.controls[slot] = true;
                            }
                        }
                    }
                    None => {
                        pack_controls(&mut r, &mut cap, &mut data, &pd.controls, i)?;
                        tables_at.insert(key, r.offs[3]);
                    }
                }
            }
        }
        params.push(gp);
        records.push(r);
        caps.push(cap);
        placements.push(m.density.as_ref().and_then(|d| d.placement));
    }
    let bvh = pack_bvh(&records, &placements, &mut data);
    check("the density data", data.len() * 4)?;
    check(
        "the medium records",
        records.len() * size_of::<MediumRecord>(),
    )?;
    check(
        "the grid parameters",
        params.len() * size_of::<GridParams>(),
    )?;
    Ok(Packed {
        grid_params: params,
        records,
        data,
        bricks,
        pins,
        index,
        caps,
        bvh,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The early check and the packing count the same bindings: with 1 KiB bindings an
    /// 8^3 brick of f16 values (1 KiB) fills one, so 16 bricks fit 16 bindings and 17 are
    /// refused, with the packing's message; f32 bricks of edge 1 (one word) fill 256 to a
    /// binding.
    #[test]
    fn brick_values_fit_the_bindings_they_count() {
        assert!(check_brick_values_fit(1024, 16, 8, 16).is_ok());
        let e = check_brick_values_fit(1024, 16, 8, 17)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("17408 bytes of brick values (1024 bytes per brick)"),
            "{e}"
        );
        assert!(e.contains("16 storage bindings of 1024 bytes"), "{e}");
        assert!(check_brick_values_fit(1024, 26, 8, 26).is_ok());
        assert!(check_brick_values_fit(1024, 26, 8, 27).is_err());
        assert!(check_brick_values_fit(1024, 16, 1, 16 * 256).is_ok());
        assert!(check_brick_values_fit(1024, 16, 1, 16 * 256 + 1).is_err());
        // A brick larger than a binding fits in none; no binding holds anything.
        assert!(check_brick_values_fit(1024, 16, 16, 1).is_err());
        assert!(check_brick_values_fit(1024, 0, 1, 1).is_err());
        assert_eq!(brick_value_capacity(1024, 16, 10, 3).ok(), Some(255));
    }

    /// A grid stored as f16 and the same values stored as f32 go to the GPU as the same
    /// words (both kept as f16), whatever the window the fill asks for.
    #[test]
    fn f16_and_f32_storage_fill_the_same_words() {
        let halves: Vec<half::f16> = (0..2 * 64)
            .map(|i| half::f16::from_f32(i as f32 * 0.375))
            .collect();
        let wide: Vec<f32> = halves.iter().map(|h| h.to_f32()).collect();
        let index = vec![0, u32::MAX, 1];
        let grid = |f16: bool| {
            let g = if f16 {
                BrickGrid::new_f16(
                    [12, 4, 4],
                    [0.0; 3],
                    [1.0; 3],
                    4,
                    index.clone(),
                    halves.clone(),
                )
            } else {
                BrickGrid::new(
                    [12, 4, 4],
                    [0.0; 3],
                    [1.0; 3],
                    4,
                    index.clone(),
                    wide.clone(),
                )
            };
            Arc::new(g.unwrap())
        };
        let words = |g: Arc<BrickGrid>| {
            assert!(keeps_f16(&g));
            let values = BrickValues {
                cap_words: 64,
                total_words: 3 + 64,
                grids: vec![(g, 3, true)],
            };
            let mut out = vec![7u32; 70];
            values.fill(0, &mut out);
            let mut part = vec![7u32; 20];
            values.fill(40, &mut part);
            assert_eq!(part, out[40..60]);
            out
        };
        let (a, b) = (words(grid(true)), words(grid(false)));
        assert_eq!(a, b);
        assert_eq!(&a[..3], &[7, 7, 7]);
        assert_eq!(
            a[4],
            u32::from(halves[2].to_bits()) | (u32::from(halves[3].to_bits()) << 16)
        );
    }

    /// The value bindings are what the device binds beside the other storage buffers,
    /// at most the shader generator's maximum.
    #[test]
    fn value_bindings_follow_the_device() {
        let with = |n: u32| wgpu::Limits {
            max_storage_buffers_per_shader_stage: n,
            ..wgpu::Limits::default()
        };
        assert_eq!(value_bindings(&with(32)), 26);
        assert_eq!(value_bindings(&with(8)), 2);
        assert_eq!(value_bindings(&with(6)), 0);
        assert_eq!(value_bindings(&with(1 << 20)), MAX_VALUE_BINDINGS);
    }
}
