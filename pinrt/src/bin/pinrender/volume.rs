//! Loading volumes through pinbake's sources and adapting them to the renderer, plus the
//! pin-grid estimator adapter.

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, Result, anyhow};
use clap::Args;
use glam::{DVec3, Vec3};
use pinbake::source::procedural::ProceduralKind;
use pinbake::source::{self, DensitySource, ProceduralSpec, RawOptions, SourceSpec};
use pinrt::gpu_render::{CosineWave, GpuDensity};
use pinrt::render::{DensityField, MajorantGrid, Pcg32, TransportEstimator};
use pinrt::{PinGrid, Ray, RayQuery, Rng, Sampler};

/// How to read the volume (the same flags as `pinbake bake`).
#[derive(Args, Debug, Clone)]
pub struct VolumeArgs {
    /// Volume: FILE.vdb, FILE.raw or procedural:SPEC (see `pinbake bake --help`).
    #[arg(long)]
    pub volume: Option<PathBuf>,
    /// VDB grid name (`density#1` for the second grid named density).
    #[arg(long)]
    pub grid: Option<String>,
    /// Raw: voxel counts X,Y,Z.
    #[arg(long, value_parser = parse_u32x3)]
    pub dims: Option<[u32; 3]>,
    /// Raw: u8, u16, f16, f32 or f64.
    #[arg(long = "type")]
    pub voxel_type: Option<String>,
    /// Raw: world size of a voxel (V or X,Y,Z, each in [1e-9, 1e9]); the grid occupies
    /// [origin, origin + dims * spacing].
    #[arg(long, value_parser = pinbake::limits::parse_spacing)]
    pub spacing: Option<[f64; 3]>,
    /// Raw: world position of the grid box's minimum corner (each within +-1e12).
    #[arg(long, value_parser = pinbake::limits::parse_origin)]
    pub origin: Option<[f64; 3]>,
    /// Multiply every density by this (finite, >= 0).
    #[arg(long, default_value_t = 1.0, value_parser = pinbake::limits::parse_density_scale)]
    pub density_scale: f64,
}

pub fn parse_u32x3(s: &str) -> Result<[u32; 3], String> {
    let v: Vec<u32> = s
        .split(',')
        .map(|p| p.trim().parse().map_err(|e| format!("'{p}': {e}")))
        .collect::<Result<_, String>>()?;
    match v.as_slice() {
        [n] => Ok([*n; 3]),
        [x, y, z] => Ok([*x, *y, *z]),
        _ => Err("expected N or X,Y,Z".into()),
    }
}

/// Opens a volume given as a path or `procedural:SPEC`.
pub fn open_volume(input: impl AsRef<OsStr>, a: &VolumeArgs) -> Result<Arc<dyn DensitySource>> {
    Ok(open_volume_typed(input, a)?.source())
}

/// A volume with its concrete type kept: what the GPU renderer needs to build its own copy.
#[derive(Clone)]
pub enum Opened {
    Vdb(Arc<source::VdbSource>),
    Dense(Arc<source::DenseGrid>),
    Noise(Arc<source::CosineNoise>),
    Box(source::HomogeneousBox),
    /// Sources with no GPU form (the procedural sphere).
    Other(Arc<dyn DensitySource>),
}

impl Opened {
    pub fn source(&self) -> Arc<dyn DensitySource> {
        match self {
            Opened::Vdb(v) => v.clone(),
            Opened::Dense(g) => g.clone(),
            Opened::Noise(n) => n.clone(),
            Opened::Box(b) => Arc::new(b.clone()),
            Opened::Other(s) => s.clone(),
        }
    }

    /// The GPU renderer's copy of the density, in the source's own frame, clipped to the
    /// source's bounds (what the CPU estimators march and track):
    ///
    /// * a raw grid as is (same convention);
    /// * a VDB as the dense grid of its active index box plus a border of one zero voxel on
    ///   every side, so that trilinear interpolation between voxel centres (integer index
    ///   coordinates) reproduces the sparse sampler exactly (refused above 2^28 voxels);
    /// * cosine noise as its waves, a homogeneous box as one voxel.
    pub fn gpu_density(&self) -> Result<GpuDensity> {
        let src = self.source();
        let b = src.bounds();
        let (lo, hi) = (b.min.to_array(), b.max.to_array());
        let d = match self {
            Opened::Vdb(v) => {
                // The GPU's voxel grid is axis-aligned; a rotated or sheared VDB has no such
                // copy (its pins carry the rotation, and the CPU reference samples it).
                if !v.is_axis_aligned() {
                    anyhow::bail!(
                        "the GPU density needs an axis-aligned VDB transform; this grid is rotated or sheared (bake it to pins, or use the CPU renderer)"
                    );
                }
                let (ilo, ihi) = v.index_bounds();
                let first = ilo - glam::IVec3::ONE;
                let dims = (ihi - ilo + glam::IVec3::splat(3)).to_array().map(|d| d as u32);
                let count = dims.iter().map(|&d| d as u64).product::<u64>();
                if count > 1 << 28 {
                    anyhow::bail!(
                        "the VDB's active box needs {count} dense voxels on the GPU (limit 2^28)"
                    );
                }
                let w0 = v.index_to_world(first.as_dvec3());
                let spacing = (v.index_to_world(first.as_dvec3() + DVec3::ONE) - w0).to_array();
                if !spacing.iter().all(|s| *s > 0.0) {
                    anyhow::bail!(
                        "the GPU density needs a VDB transform with a positive scale on every axis (got {spacing:?})"
                    );
                }
                let mut values = Vec::with_capacity(count as usize);
                for z in 0..dims[2] as i32 {
                    for y in 0..dims[1] as i32 {
                        for x in 0..dims[0] as i32 {
                            values.push(v.voxel(first + glam::IVec3::new(x, y, z)));
                        }
                    }
                }
                // Voxel centres at integer index coordinates: the grid box starts half a voxel
                // before the first centre.
                let origin = (w0 - DVec3::from_array(spacing) * 0.5).to_array();
                GpuDensity::voxels(dims, origin, spacing, values)
            }
            Opened::Dense(g) => GpuDensity::voxels(
                g.dims(),
                g.origin().to_array(),
                g.spacing().to_array(),
                g.data().to_vec(),
            ),
            Opened::Noise(n) => GpuDensity::cosine(
                lo,
                hi,
                n.density() as f32,
                n.waves()
                    .map(|(w, amplitude, phase)| CosineWave {
                        w: w.as_vec3().to_array(),
                        amplitude: amplitude as f32,
                        phase: phase as f32,
                    })
                    .collect(),
            ),
            Opened::Box(bx) => GpuDensity::homogeneous(&pinrt::render::HomogeneousBox {
                min: lo,
                max: hi,
                sigma_t: bx.density(),
            }),
            Opened::Other(s) => anyhow::bail!(
                "the GPU renderer has no form of '{}' (use a raw or VDB volume, cosine noise or a box)",
                s.describe()
            ),
        }
        .map_err(|e| anyhow!("{e}"))?;
        d.with_bounds(lo, hi).map_err(|e| anyhow!("{e}"))
    }
}

/// [`open_volume`] with the concrete source type kept.
///
/// Flags for another kind of input (`--grid` on a raw file, `--dims` on a VDB) are usage
/// errors, and a path must name a regular file.
pub fn open_volume_typed(input: impl AsRef<OsStr>, a: &VolumeArgs) -> Result<Opened> {
    let input = input.as_ref();
    let procedural = input.to_str().and_then(|s| s.strip_prefix("procedural:"));
    let path = PathBuf::from(input);
    let is_vdb = procedural.is_none()
        && path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("vdb"));
    let raw_flags = [
        ("--dims", a.dims.is_some()),
        ("--type", a.voxel_type.is_some()),
        ("--spacing", a.spacing.is_some()),
        ("--origin", a.origin.is_some()),
    ];
    let grid_flag = [("--grid", a.grid.is_some())];
    let (kind, wrong): (&str, Vec<&str>) = if procedural.is_some() {
        let all = raw_flags.iter().chain(&grid_flag);
        (
            "a procedural volume",
            all.filter(|f| f.1).map(|f| f.0).collect(),
        )
    } else if is_vdb {
        let raw = raw_flags.iter();
        (
            "an OpenVDB volume",
            raw.filter(|f| f.1).map(|f| f.0).collect(),
        )
    } else {
        (
            "a raw volume",
            grid_flag.iter().filter(|f| f.1).map(|f| f.0).collect(),
        )
    };
    if let Some(flag) = wrong.first() {
        // A usage error (exit 2); spelled out because tests include this file as a module.
        return Err(anyhow::Error::new(pinbake::files::UsageError(format!(
            "{flag} does not apply to {kind} ({})",
            path.display()
        ))));
    }
    if procedural.is_none() {
        pinbake::files::check_input(&path)?;
    }
    let spec = if let Some(rest) = procedural {
        let mut p: ProceduralSpec = rest.parse().map_err(|e| anyhow!("{e}"))?;
        p.density *= a.density_scale;
        SourceSpec::Procedural(p)
    } else {
        if is_vdb {
            SourceSpec::Vdb(
                path,
                source::VdbOptions {
                    grid: a.grid.clone(),
                    density_scale: a.density_scale,
                    worker_exe: std::env::current_exe().context("locating pinrender")?,
                    ..source::VdbOptions::default()
                },
            )
        } else {
            let voxel_type = match a.voxel_type.as_deref() {
                None => None,
                Some(t) => Some(
                    source::RawType::parse(t)
                        .ok_or_else(|| anyhow!("--type '{t}' is not u8, u16, f16, f32 or f64"))?,
                ),
            };
            SourceSpec::Raw(
                path,
                RawOptions {
                    dims: a.dims,
                    voxel_type,
                    spacing: a.spacing.unwrap_or([1.0; 3]),
                    origin: a.origin.unwrap_or([0.0; 3]),
                    density_scale: a.density_scale,
                    ..RawOptions::default()
                },
            )
        }
    };
    Ok(match spec {
        SourceSpec::Vdb(path, opts) => {
            Opened::Vdb(Arc::new(source::VdbSource::open(&path, &opts)?))
        }
        SourceSpec::Raw(path, opts) => {
            Opened::Dense(Arc::new(source::raw::read_raw(&path, &opts)?))
        }
        SourceSpec::Procedural(p) => match p.kind {
            ProceduralKind::Cosine | ProceduralKind::Fractal => {
                // `build` first: it reports a bad spec with the spec in the message.
                p.build()?;
                Opened::Noise(Arc::new(p.build_noise()?))
            }
            ProceduralKind::Box => Opened::Box(source::HomogeneousBox::new(
                p.world_box(),
                p.density as f32,
            )?),
            ProceduralKind::Sphere => Opened::Other(Arc::from(p.build()?)),
        },
    })
}

/// A pinbake source seen as the renderer's density field.
pub struct SourceField(pub Arc<dyn DensitySource>);

impl DensityField for SourceField {
    fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        let b = self.0.bounds();
        (b.min.to_array(), b.max.to_array())
    }
    fn extinction(&self, p: Vec3) -> f32 {
        self.0.extinction(p.as_dvec3())
    }
    fn max_extinction(&self, lo: [f64; 3], hi: [f64; 3]) -> Option<f32> {
        Some(
            self.0
                .max_extinction_in(source::Aabb::new(DVec3::from(lo), DVec3::from(hi))),
        )
    }
}

/// Majorant grid of `bricks^3` over the field's box, from the source's conservative bounds.
pub fn majorants(field: &SourceField, bricks: u32) -> Result<Arc<MajorantGrid>> {
    Ok(Arc::new(
        MajorantGrid::from_field(field, [bricks; 3]).map_err(|e| anyhow!("{e}"))?,
    ))
}

/// A pin grid as a renderer estimator. The grid is leaked: a binary renders with it until exit.
pub struct PinsEstimator {
    sampler: Sampler<'static>,
    /// The placed grid's world box (the renderer skips the estimator for rays that miss it).
    bounds: Option<([f64; 3], [f64; 3])>,
}

impl PinsEstimator {
    /// An estimator over an already placed sampler (instances, lookup options).
    pub fn from_sampler(sampler: Sampler<'static>) -> Self {
        Self {
            bounds: sampler.world_bounds(),
            sampler,
        }
    }
}

/// Leaks a pin grid so samplers over it live until the process exits (a binary renders with
/// its grids until then).
pub fn leak_grid(grid: PinGrid) -> &'static PinGrid {
    Box::leak(Box::new(grid))
}

/// The batch form of the single queries' seeding: each ray's pin generator from two draws of
/// its path generator, in the order `sample_distance` and `transmittance` draw them.
fn pin_queries(rays: &[[Vec3; 2]], t_max: f32, rngs: &mut [Pcg32]) -> (Vec<RayQuery>, Vec<Rng>) {
    let q = rays
        .iter()
        .map(|r| RayQuery::new(r[0].to_array(), r[1].to_array(), t_max))
        .collect();
    let g = rngs
        .iter_mut()
        .map(|rng| Rng::for_query(rng.next_u32(), rng.next_u32()))
        .collect();
    (q, g)
}

impl TransportEstimator for PinsEstimator {
    fn sample_distance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> Option<f32> {
        let mut r = Rng::for_query(rng.next_u32(), rng.next_u32());
        self.sampler
            .sample_distance(&Ray::new(o.to_array(), d.to_array()), t_max, &mut r)
    }
    fn transmittance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> f32 {
        let mut r = Rng::for_query(rng.next_u32(), rng.next_u32());
        self.sampler
            .transmittance(&Ray::new(o.to_array(), d.to_array()), t_max, &mut r)
    }
    fn transmittance_batch(
        &self,
        rays: &[[Vec3; 2]],
        t_max: f32,
        rngs: &mut [Pcg32],
        out: &mut [f32],
    ) {
        let (q, mut r) = pin_queries(rays, t_max, rngs);
        self.sampler.transmittance_batch_rngs(&q, &mut r, out);
    }
    fn sample_distance_batch(
        &self,
        rays: &[[Vec3; 2]],
        t_max: f32,
        rngs: &mut [Pcg32],
        out: &mut [Option<f32>],
    ) {
        let (q, mut r) = pin_queries(rays, t_max, rngs);
        self.sampler.sample_distance_batch_rngs(&q, &mut r, out);
    }
    fn name(&self) -> String {
        "pins".into()
    }
    fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        self.bounds
    }
}

/// Loads `--pins FILE`, or bakes the volume in memory with the default settings (cells: as
/// given, else `pinbake::bake::DEFAULT_MAX_CELLS` per axis capped by the voxels).
pub fn pins_for(
    pins: Option<&Path>,
    source: &dyn DensitySource,
    cells: Option<u32>,
    seed: u64,
) -> Result<PinGrid> {
    if let Some(p) = pins {
        // A FIFO would block the open, a device or directory map as nonsense.
        pinbake::files::check_input(p)?;
        let grid = PinGrid::open(p).map_err(|e| anyhow!("{}: {e}", p.display()))?;
        // A tile covers only its slab of cells: rendering with it would treat the rest of the
        // volume as empty.
        if let Some(t) = grid
            .file()
            .map_err(|e| anyhow!("{}: {e}", p.display()))?
            .tile()
        {
            anyhow::bail!(
                "{}: tile {}/{} of a farm bake, not a whole grid; join the tiles with \
                 `pinbake merge` first",
                p.display(),
                t.tile_index,
                t.tile_count
            );
        }
        return Ok(grid);
    }
    let cells = match cells {
        Some(c) => [c; 3],
        None => pinbake::bake::default_cells(source, true, pinbake::bake::DEFAULT_MAX_CELLS)?,
    };
    let opts = pinbake::BakeOptions {
        cells,
        seed,
        ..pinbake::BakeOptions::default()
    };
    let (grid, _) = pinbake::bake(source, &opts, &|_| {})?;
    PinGrid::from_bytes(grid.to_bytes()?).map_err(|e| anyhow!("{e}"))
}
