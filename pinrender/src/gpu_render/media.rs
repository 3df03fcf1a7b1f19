//! What the GPU path tracer renders: pin grids, density fields and their placed instances,
//! and their packing into the flat records `shaders/render.wgsl` reads.
//!
//! A scene's media are [`GpuMedia`]: the distinct pin grids (concatenated into one pin and one
//! cell-index buffer), the distinct density fields ([`GpuDensity`]: a voxel grid in the
//! project's convention or closed-form cosine noise), and the instances ([`GpuMedium`]), each
//! with an optional placed pin grid (what `pins` and PinMS query) and an optional placed
//! density with its world-space majorant grid (what ray marching and the trackers query).
//! An instance may have either or both; which estimators a render may use follows from that.

use std::borrow::Cow;
use std::sync::Arc;

use bytemuck::{Pod, Zeroable};

use crate::render::{DensitySource, HomogeneousBox, MajorantGrid, RenderError, VoxelGrid};
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
    /// `density * max(0, 1 + sum_k amplitude_k cos(w_k . p + phase_k))`, pinbake's cosine
    /// noise (evaluated in f32 with the phase reduced to turns before the cosine).
    Cosine {
        density: f32,
        waves: Vec<CosineWave>,
    },
}

/// A density field for the GPU estimators: an extinction function and the local box that
/// holds all of it (extinction is 0 outside `bounds`; ray marching steps are relative to its
/// longest edge, as on the CPU, where it is [`crate::render::DensitySource::bounds`]).
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

/// A density of [`GpuMedia::densities`] placed for one instance by a translation.
#[derive(Clone, Debug)]
pub struct GpuPlacedDensity {
    /// Index into [`GpuMedia::densities`].
    pub density: usize,
    /// World position = density-local position + `translation`.
    pub translation: [f64; 3],
    /// World-space majorant grid over the placed density (needed by the trackers).
    pub majorants: Option<Arc<MajorantGrid>>,
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
}

/// `RtMedium` of `render.wgsl` (208 bytes).
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
}

pub(super) const FLAG_PINS: u32 = 1;
pub(super) const FLAG_DENSITY: u32 = 2;
pub(super) const FLAG_MAJORANTS: u32 = 4;
const KIND_VOXELS: u32 = 1;
const KIND_COSINE: u32 = 2;
/// Floats per cosine wave in the data buffer.
const WAVE_FLOATS: usize = 8;

/// The buffers of a scene's media, ready to upload.
pub(super) struct Packed<'g> {
    pub grid_params: Vec<GridParams>,
    pub records: Vec<MediumRecord>,
    pub data: Vec<f32>,
    pub pins: Cow<'g, [u8]>,
    pub index: Cow<'g, [u8]>,
    pub caps: Vec<Caps>,
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

fn f4(v: [f64; 3], w: f32) -> [f32; 4] {
    [v[0] as f32, v[1] as f32, v[2] as f32, w]
}

fn gpu(why: String) -> Error {
    Error::Gpu(why)
}

/// Packs `media` into the shader's records; `limit` is the largest storage binding in bytes.
pub(super) fn pack<'g>(media: &GpuMedia<'g>, limit: u64) -> pinrt::Result<Packed<'g>> {
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

    // Densities: values and waves at offsets in one f32 array.
    let mut data: Vec<f32> = Vec::new();
    let mut density_off = Vec::with_capacity(media.densities.len());
    for d in &media.densities {
        density_off.push(data.len());
        match &d.kind {
            GpuDensityKind::Voxels(grid) => data.extend_from_slice(grid.parts().3),
            GpuDensityKind::Cosine { waves, .. } => {
                for w in waves {
                    data.extend_from_slice(&[
                        w.w[0],
                        w.w[1],
                        w.w[2],
                        w.amplitude,
                        w.phase,
                        0.0,
                        0.0,
                        0.0,
                    ]);
                }
                debug_assert_eq!(data.len() % WAVE_FLOATS, 0);
            }
        }
    }

    let mut params = Vec::with_capacity(media.media.len());
    let mut records = Vec::with_capacity(media.media.len());
    let mut caps = Vec::with_capacity(media.media.len());
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
                r.offs[2] = to_u32("majorant", data.len())?;
                data.extend_from_slice(mg.values());
                r.mdims = [md[0], md[1], md[2], 0];
                r.maj_lo = f4(mlo, 0.0);
                r.maj_hi = f4(mhi, 0.0);
                r.ids[2] |= FLAG_MAJORANTS;
                cap.majorants = true;
            }
        }
        params.push(gp);
        records.push(r);
        caps.push(cap);
    }
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
        pins,
        index,
        caps,
    })
}
