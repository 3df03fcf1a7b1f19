//! Loading volumes through pinbake's sources and adapting them to the renderer (feature
//! `cli`): the `pinrender` binary's half that its tests link against. Errors are `anyhow`,
//! as in `pinbake::cli_args`: every caller reports them to a user and exits.

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

use crate::gpu_render::{CosineWave, GpuDensity};
use crate::render::{BrickGrid, DenseMap, DenseView, MajorantGrid, SharedHalves, VoxelGrid};
use anyhow::{Context, Result, anyhow};
use clap::Args;
use glam::DVec3;
use pin_volume::procedural::ProceduralKind;
use pin_volume::{self as source, Density, DensityScale, DensitySource, SourceSpec};
use pinrt::PinGrid;

/// The volume and how to read it (the flags shared with `pinbake bake`).
#[derive(Args, Debug, Clone, Default)]
pub struct VolumeArgs {
    /// Volume: FILE.vdb, FILE.raw or procedural:SPEC (see `pinbake bake --help`).
    #[arg(long)]
    pub volume: Option<PathBuf>,
    #[command(flatten)]
    pub read: pinbake::cli_args::SourceArgs,
}

impl VolumeArgs {
    /// No volume, the default reading flags but this density scale (the eval's scenes).
    pub fn scaled(density_scale: DensityScale) -> Self {
        Self {
            volume: None,
            read: pinbake::cli_args::SourceArgs {
                density_scale,
                ..Default::default()
            },
        }
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
    ///   coordinates) reproduces the sparse sampler exactly (refused above
    ///   [`GPU_DENSE_VOXELS`]; [`Opened::gpu_density_or_bricks`] bricks it instead);
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
                if count > GPU_DENSE_VOXELS {
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
            Opened::Box(bx) => GpuDensity::homogeneous(bx),
            Opened::Other(s) => anyhow::bail!(
                "the GPU renderer has no form of '{}' (use a raw or VDB volume, cosine noise or a box)",
                s.describe()
            ),
        }
        .map_err(|e| anyhow!("{e}"))?;
        d.with_bounds(lo, hi).map_err(|e| anyhow!("{e}"))
    }

    /// [`Opened::gpu_density`], except that an axis-aligned VDB whose dense copy would exceed
    /// `max_dense` voxels ([`GPU_DENSE_VOXELS`] for a render) goes to the GPU as `field`'s
    /// bricks: the [`BrickGrid`] the CPU trackers read ([`TrackedSource::bricked`]), shared, so
    /// both renderers track the same field (or, where the field has a dense copy instead,
    /// [`bricks_of`] its source). Smaller volumes keep their dense copy (and their images).
    pub fn gpu_density_or_bricks(
        &self,
        field: &TrackedSource,
        max_dense: u64,
    ) -> Result<GpuDensity> {
        let Opened::Vdb(v) = self else {
            return self.gpu_density();
        };
        let (ilo, ihi) = v.index_bounds();
        let count = (ihi - ilo + glam::IVec3::splat(3))
            .to_array()
            .iter()
            .map(|&d| d.max(0) as u64)
            .product::<u64>();
        if !v.is_axis_aligned() || count <= max_dense {
            return self.gpu_density();
        }
        let bricks = field
            .bricked_shared()
            .or_else(|| bricks_of(&**field.source(), field.bricks_budget()).map(Arc::new));
        let Some(bricks) = bricks else {
            anyhow::bail!(
                "the VDB's active box needs {count} voxels on the GPU, more than a dense copy \
                 takes ({max_dense}), and its bricks do not fit in half the memory budget"
            );
        };
        let b = v.bounds();
        GpuDensity::from_bricks(bricks)
            .and_then(|d| d.with_bounds(b.min.to_array(), b.max.to_array()))
            .map_err(|e| anyhow!("{e}"))
    }
}

/// The most voxels a VDB's dense GPU copy may have; a larger one is bricked
/// ([`Opened::gpu_density_or_bricks`]).
pub const GPU_DENSE_VOXELS: u64 = 1 << 28;

/// [`open_volume`] with the concrete source type kept.
///
/// Flags for another kind of input (`--grid` on a raw file, `--dims` on a VDB) are usage
/// errors, and a path must name a regular file ([`pinbake::cli_args::SourceArgs::source_spec`]).
pub fn open_volume_typed(input: impl AsRef<OsStr>, a: &VolumeArgs) -> Result<Opened> {
    open_volume_within(input, a, &pin_volume::files::MemoryBudget::new(None))
}

/// [`open_volume_typed`] within a command's memory budget: a VDB's dense copy for the
/// trackers takes at most a quarter of it.
pub fn open_volume_within(
    input: impl AsRef<OsStr>,
    a: &VolumeArgs,
    budget: &pin_volume::files::MemoryBudget,
) -> Result<Opened> {
    let spec = a
        .read
        .source_spec(Path::new(input.as_ref()), "volume", || {
            std::env::current_exe().context("locating pinrender")
        })?;
    let scale = a.read.density_scale;
    if let SourceSpec::Procedural(p) = spec {
        return procedural(p, scale);
    }
    // Every file goes through pinbake's one dispatch (`open_source_typed`): what it reads,
    // the renderer and the viewer read, NanoVDB included.
    Ok(match source::open_source_typed(&spec, scale)? {
        // The trackers sample the density point by point; a dense copy of the active box
        // answers them without the tree's hash lookups, with the same bits (the images do
        // not change), when it takes at most 1 GiB and a quarter of the memory budget.
        source::OpenedSource::Vdb(v) => Opened::Vdb(Arc::new(
            (*v).with_dense_cache(pinbake::bake::DEFAULT_DENSE_COPY_BYTES.min(budget.limit / 4)),
        )),
        source::OpenedSource::Raw(g) => Opened::Dense(Arc::new(*g)),
        source::OpenedSource::Procedural(p) => Opened::Other(Arc::from(p)),
    })
}

/// A procedural field with its GPU form kept: cosine noise as its waves, a box as itself,
/// the sphere (no GPU form) as a source.
fn procedural(p: source::ProceduralSpec, scale: DensityScale) -> Result<Opened> {
    // The field itself, its density scaled (what `build` makes with the scale).
    let p = p.scaled(scale);
    Ok(match p.kind {
        ProceduralKind::Cosine | ProceduralKind::Fractal => {
            // `build` first: it reports a bad spec with the spec in the message.
            p.build(DensityScale::ONE)?;
            Opened::Noise(Arc::new(p.build_noise()?))
        }
        ProceduralKind::Box => Opened::Box(source::HomogeneousBox::new(
            p.world_box(),
            p.density as f32,
        )?),
        ProceduralKind::Sphere => Opened::Other(Arc::from(p.build(DensityScale::ONE)?)),
    })
}

/// A baker's source as the renderer's trackers read it: the same [`DensitySource`], with the
/// renderer's caches beside it (a sparse grid's dense copy, or its bricks when no dense copy
/// fits), made on first use.
pub struct TrackedSource {
    source: Arc<dyn DensitySource>,
    /// A sparse grid's dense copy for the trackers' [`Density::dense_view`], made on
    /// first use (a pins-only render never asks); `None` inside when the source has no copy
    /// (analytic, rotated, or over the memory cap).
    copy: OnceLock<Option<source::DenseGrid>>,
    /// The map of the raw grid or of `copy`, made once.
    map: OnceLock<Option<DenseMap>>,
    /// A voxel source too large for `copy` bricked instead ([`BrickGrid`]: only the bricks
    /// the source does not bound by zero), made on first use; `None` inside when there is a
    /// dense view, no voxels, or the bricks would not fit either.
    bricks: OnceLock<Option<Arc<BrickGrid>>>,
    /// The render's memory budget: the bricks may take half of it, the dense copy a quarter
    /// (the source and the rest of the render keep the other half).
    budget: u64,
}

impl TrackedSource {
    /// Under the default memory budget ([`pin_volume::files::default_memory_limit`]).
    pub fn new(source: Arc<dyn DensitySource>) -> Self {
        Self::with_budget(source, pin_volume::files::default_memory_limit())
    }

    /// Under a render's memory budget (`--max-memory`), which bounds its caches before they
    /// are built.
    pub fn with_budget(source: Arc<dyn DensitySource>, budget: u64) -> Self {
        TrackedSource {
            source,
            copy: OnceLock::new(),
            map: OnceLock::new(),
            bricks: OnceLock::new(),
            budget,
        }
    }

    /// The most bytes its bricks may take ([`bricks_of`]).
    pub fn bricks_budget(&self) -> u64 {
        self.budget / 2
    }

    /// The bricked copy of a voxel source whose dense copy does not fit: the trackers read
    /// it instead of the tree. Its voxels are the source's values at its voxel centres (the
    /// index grid of an axis-aligned VDB, one zero voxel beyond its bounds on every side), so
    /// its trilinear field is the tree's up to the rounding of the world-to-index map.
    pub fn bricked(&self) -> Option<&BrickGrid> {
        self.bricked_shared_ref().map(|g| &**g)
    }

    /// [`TrackedSource::bricked`] as a shared grid (the GPU's copy reads it too).
    pub fn bricked_shared(&self) -> Option<Arc<BrickGrid>> {
        self.bricked_shared_ref().cloned()
    }

    fn bricked_shared_ref(&self) -> Option<&Arc<BrickGrid>> {
        self.bricks
            .get_or_init(|| {
                if self.dense_view().is_some() {
                    return None;
                }
                bricks_of(&*self.source, self.bricks_budget()).map(Arc::new)
            })
            .as_ref()
    }

    /// The source.
    pub fn source(&self) -> &Arc<dyn DensitySource> {
        &self.source
    }
}

/// A voxel source bricked ([`TrackedSource::bricked`]): its values at the centres of voxels of
/// its own size over its bounds widened by half a voxel (for an axis-aligned VDB: its index
/// grid with one zero voxel beyond its bounds on every side), in the bricks that the source
/// does not bound by zero; `None` for a source without voxels, or bricks over `max_bytes`
/// (counted before they are listed: [`pinbake::sparse_density::sparse_f32_bricks`]).
pub fn bricks_of(source: &dyn DensitySource, max_bytes: u64) -> Option<BrickGrid> {
    let voxel = source.voxel_size()?;
    let b = source.bounds();
    let (lo, hi) = (b.min - voxel * 0.5, b.max + voxel * 0.5);
    let n = (hi - lo) / voxel;
    if !(n.is_finite() && n.max_element() < f64::from(1u32 << 20)) {
        return None;
    }
    let dims = n.round().max(DVec3::ONE).to_array().map(|v| v as u32);
    let bbox = source::Aabb::new(lo, hi);
    let (index, values) =
        pinbake::sparse_density::sparse_f32_bricks(source, &bbox, dims, max_bytes)?;
    let spacing = [0, 1, 2].map(|a| (hi[a] - lo[a]) / f64::from(dims[a]));
    BrickGrid::new(
        dims,
        lo.to_array(),
        spacing,
        pinbake::sparse_density::SPARSE_BRICK,
        index,
        values,
    )
    .ok()
}

/// The dense grid's convention is `DenseView`'s: voxel `i`'s centre at `origin + (i + 0.5)
/// spacing`, trilinear, clamped to the edge voxels inside the box.
fn map_of(g: &source::DenseGrid) -> Option<DenseMap> {
    DenseMap::new(
        g.data().len(),
        g.dims(),
        g.origin().to_array(),
        g.spacing().to_array(),
    )
}

impl Density for TrackedSource {
    fn bounds(&self) -> source::Aabb {
        self.source.bounds()
    }
    fn extinction(&self, p: DVec3) -> f32 {
        if let Some(g) = self.bricked() {
            return g.extinction(p);
        }
        self.source.extinction(p)
    }
    fn max_extinction_in(&self, region: source::Aabb) -> f32 {
        if let Some(g) = self.bricked() {
            return g.max_extinction_in(region);
        }
        self.source.max_extinction_in(region)
    }
    fn min_extinction_in(&self, region: source::Aabb) -> Option<f32> {
        if let Some(g) = self.bricked() {
            return g.min_extinction_in(region);
        }
        source::min_extinction_by_view(self, region)
    }
    /// A raw grid as it is; a VDB through its dense copy, whose one-voxel zero border makes
    /// the clamped array zero wherever the tree is (the copy's trilinear field is the tree's:
    /// `pinbake`'s `dense_copy`), at most the size the VDB's own cache may take.
    fn dense_view(&self) -> Option<DenseView<'_>> {
        let grid = match self.source.as_dense_grid() {
            Some(g) => g,
            None => self
                .copy
                .get_or_init(|| {
                    self.source
                        .dense_copy(pinbake::bake::DEFAULT_DENSE_COPY_BYTES.min(self.budget / 4))
                })
                .as_ref()?,
        };
        DenseView::new(grid.data(), (*self.map.get_or_init(|| map_of(grid)))?)
    }
}

impl DensitySource for TrackedSource {
    fn describe(&self) -> String {
        self.source.describe()
    }

    fn voxel_size(&self) -> Option<DVec3> {
        self.source.voxel_size()
    }
}

/// Majorant grid of `bricks^3` over the field's box, from the source's conservative bounds.
pub fn majorants(field: &TrackedSource, bricks: u32) -> Result<Arc<MajorantGrid>> {
    Ok(Arc::new(
        MajorantGrid::from_field(field, [bricks; 3]).map_err(|e| anyhow!("{e}"))?,
    ))
}

/// Opens `--pins FILE` as a whole grid: a tile of a farm bake is refused (it covers only its
/// slab of cells: rendering with it would treat the rest of the volume as empty).
pub fn load_pins(p: &Path) -> Result<PinGrid> {
    // A FIFO would block the open, a device or directory map as nonsense.
    pin_volume::files::check_input(p)?;
    // pinrt's errors name the file already.
    let grid = PinGrid::open(p).map_err(|e| anyhow!("{e}"))?;
    if let Some(t) = grid.file().map_err(|e| anyhow!("{e}"))?.tile() {
        anyhow::bail!(
            "{}: tile {}/{} of a farm bake, not a whole grid; join the tiles with \
             `pinbake merge` first",
            p.display(),
            t.tile_index,
            t.tile_count
        );
    }
    Ok(grid)
}

/// Checks that `grid` (from `pins`) was baked from `source` (read from `volume` with
/// `density_scale`): the identity the bake recorded against the volume's. A mismatch is an
/// error naming both files and what differs, unless `allow`; a file without an identity
/// (baked before it was recorded) passes with a warning.
pub fn check_pins_match(
    pins: &Path,
    grid: &PinGrid,
    volume: &Path,
    source: &dyn DensitySource,
    density_scale: DensityScale,
    allow: bool,
) -> Result<()> {
    let recorded = grid
        .file()
        .map_err(|e| anyhow!("{}: {e}", pins.display()))?
        .metadata()
        .transpose()
        .map_err(|e| anyhow!("{}: {e}", pins.display()))?
        .and_then(|m| source::SourceIdentity::from_extra(&m.extra));
    let Some(recorded) = recorded else {
        pin_cli::errln!(
            "pinrender: warning: {} records no source identity (an older bake); not checked \
             against {}",
            pins.display(),
            volume.display()
        );
        return Ok(());
    };
    let recorded = recorded.map_err(|e| anyhow!("{}: {e}", pins.display()))?;
    let differences =
        recorded.differences(&source::SourceIdentity::of(source, density_scale.get()));
    if differences.is_empty() {
        return Ok(());
    }
    let what = format!(
        "{} was not baked from {} ({}; pins vs volume)",
        pins.display(),
        volume.display(),
        differences.join("; ")
    );
    if allow {
        pin_cli::errln!("pinrender: warning: {what}; rendering anyway (--allow-mismatched-pins)");
        return Ok(());
    }
    anyhow::bail!("{what}; rebake the pins, or pass --allow-mismatched-pins")
}

/// The medium of a pin file rendered alone (no `--volume`): the world box of its placed
/// grid, and, when the file embeds density, that density as a world-space field with
/// majorants from the file's majorant section: the sparse section (format 1.1) as a
/// [`BrickGrid`], the dense section as a [`VoxelGrid`].
pub struct PinFileMedium {
    pub bounds: ([f64; 3], [f64; 3]),
    /// The dense section's grid, when the file has no sparse one (also the GPU's copy).
    pub density: Option<Arc<VoxelGrid>>,
    /// The sparse section's grid: what the CPU trackers and the GPU read when the file has
    /// one, whether or not it also has a dense one.
    pub bricks: Option<Arc<BrickGrid>>,
    pub majorants: Option<Arc<MajorantGrid>>,
}

impl PinFileMedium {
    /// The field the CPU estimators read: the bricked one if the file has it.
    pub fn field(&self) -> Option<Arc<dyn Density>> {
        match (&self.bricks, &self.density) {
            (Some(b), _) => Some(b.clone()),
            (None, Some(d)) => Some(d.clone()),
            (None, None) => None,
        }
    }
}

/// Reads the medium sections of `grid` (from `path`). The embedded density and the majorants
/// live in the grid's local box; the renderer's fields are axis-aligned in the world, so a
/// placement other than a positive scale and a translation is refused (render such a grid
/// with `--volume`).
/// A pin file's f16 sparse values, read in place from the grid's bytes (its mapping).
#[derive(Debug)]
struct MappedHalves {
    grid: Arc<PinGrid>,
    /// Byte range of the values in the grid's bytes.
    range: std::ops::Range<usize>,
}

impl MappedHalves {
    /// `values`, a view into `grid`'s bytes, as their byte range there; `None` where they
    /// are not such a view.
    fn new(grid: &Arc<PinGrid>, values: &[half::f16]) -> Option<Self> {
        let bytes = grid.bytes();
        let start = (values.as_ptr() as usize).checked_sub(bytes.as_ptr() as usize)?;
        let range = start..start.checked_add(std::mem::size_of_val(values))?;
        let back: &[half::f16] = bytemuck::try_cast_slice(bytes.get(range.clone())?).ok()?;
        (back.as_ptr() == values.as_ptr()).then(|| Self {
            grid: grid.clone(),
            range,
        })
    }
}

impl SharedHalves for MappedHalves {
    fn halves(&self) -> &[half::f16] {
        // Checked in `new`: in range and aligned, and the grid's bytes do not move.
        bytemuck::cast_slice(&self.grid.bytes()[self.range.clone()])
    }
}

/// The embedded density of `grid` (opened from `path`) for the trackers: a sparse section as
/// bricks, whose f16 values are read in place from the grid's mapping (no copy; f32 values
/// are copied); a dense one as f32 voxels.
///
/// A file that carries both density sections renders its sparse one, on the CPU and on the
/// GPU alike (`docs/format.md` section 5.6a): its f16 values are read in place, where the
/// dense one would be widened to f32, so the sparse section keeps the memory bounded by the
/// mapping. The dense section is then not read (`pinbake verify` checks it).
///
/// Each section read is checked against its checksum in the pass that validates its values
/// (`pinrt::PinGrid::sparse_density` and the others): a damaged section is one error line
/// naming the file and the section.
pub fn pin_file_medium(path: &Path, grid: &Arc<PinGrid>) -> Result<PinFileMedium> {
    let named = |e: pinrt::Error| anyhow!("{e}");
    let sparse = grid.sparse_density().map_err(named)?;
    let density = match sparse {
        Some(_) => None,
        None => grid.density().map_err(named)?,
    };
    let majorants = grid.majorants().map_err(named)?;
    let d = grid.desc();
    let m = d.local_to_world;
    let scale = [m[0], m[5], m[10]];
    let off_diagonal = [m[1], m[2], m[4], m[6], m[8], m[9]];
    let axis_aligned =
        off_diagonal.iter().all(|&v| v == 0.0) && scale.iter().all(|&v| v > 0.0 && v.is_finite());
    let to_world = |p: [f64; 3]| [0, 1, 2].map(|a| scale[a] * p[a] + m[4 * a + 3]);
    let bounds = (to_world(d.box_min), to_world(d.box_max));
    if (density.is_some() || sparse.is_some()) && !axis_aligned {
        anyhow::bail!(
            "{}: the grid is rotated or sheared in the world; its embedded density can only be \
             rendered with --volume",
            path.display()
        );
    }
    let spacing_of =
        |dims: [u32; 3]| [0, 1, 2].map(|a| (bounds.1[a] - bounds.0[a]) / f64::from(dims[a]));
    let dense = density
        .map(|density| {
            VoxelGrid::new(
                density.dims(),
                bounds.0,
                spacing_of(density.dims()),
                density.to_f32(),
            )
            .map(Arc::new)
            .map_err(|e| anyhow!("{}: embedded density: {e}", path.display()))
        })
        .transpose()?;
    let bricks = sparse
        .map(|s| {
            let (origin, spacing) = (bounds.0, spacing_of(s.dims()));
            let mapped = match s.values() {
                pin_format::SparseValues::F16(v) => MappedHalves::new(grid, v),
                pin_format::SparseValues::F32(_) => None,
            };
            match mapped {
                Some(m) => {
                    let index = s.index().to_vec();
                    BrickGrid::from_shared_f16(
                        s.dims(),
                        origin,
                        spacing,
                        s.brick(),
                        index,
                        Arc::new(m),
                    )
                }
                None => BrickGrid::from_sparse(&s, origin, spacing),
            }
            .map(Arc::new)
            .map_err(|e| anyhow!("{}: embedded sparse density: {e}", path.display()))
        })
        .transpose()?;
    let mut medium = PinFileMedium {
        bounds,
        density: dense,
        bricks,
        majorants: None,
    };
    let Some(field) = medium.field() else {
        return Ok(medium);
    };
    // The file's majorants bound the source's extinction; its f16 copy can round above them,
    // so each brick is raised to the copy's exact maximum there (delta tracking needs a
    // bound of the field it tracks).
    let (dims, values) = match majorants {
        Some(mj) => (mj.dims(), mj.values().to_vec()),
        None => ([1; 3], vec![0.0]),
    };
    let size = [0, 1, 2].map(|a| (bounds.1[a] - bounds.0[a]) / f64::from(dims[a]));
    let mut raised = values;
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let i = [x, y, z];
                let lo = [0, 1, 2].map(|a| bounds.0[a] + size[a] * f64::from(i[a]));
                let hi = [0, 1, 2].map(|a| bounds.0[a] + size[a] * f64::from(i[a] + 1));
                let exact = field
                    .max_extinction_in(source::Aabb::from_arrays(lo, hi))
                    .min(f32::MAX);
                let k = (x + dims[0] * (y + dims[1] * z)) as usize;
                raised[k] = raised[k].max(exact);
            }
        }
    }
    let majorants = MajorantGrid::from_parts(bounds.0, bounds.1, dims, raised)
        .map_err(|e| anyhow!("{}: majorants: {e}", path.display()))?;
    medium.majorants = Some(Arc::new(majorants));
    Ok(medium)
}

/// Loads `--pins FILE`, or bakes the volume in memory as `pinbake bake` would by default: the
/// cells (unless given), directions and pins per entry chosen from the volume by the same
/// `pinbake::plan` calls as `pinbake bake`, so a render without `--pins` sees the same bake as
/// a render of `pinbake bake`'s file. With `control`, the in-memory bake also stores the
/// control section (`pinbake bake --embed-control`, for `pinres`).
pub fn pins_for(
    pins: Option<&Path>,
    source: &dyn DensitySource,
    cells: Option<u32>,
    seed: u64,
    control: bool,
    budget: &pin_volume::files::MemoryBudget,
) -> Result<PinGrid> {
    if let Some(p) = pins {
        return load_pins(p);
    }
    let opts = in_memory_bake_options(source, cells, seed, control, budget)?;
    let (grid, _) = pinbake::bake(source, &opts, &|_| {})?;
    PinGrid::from_bytes(grid.to_bytes()?).map_err(|e| anyhow!("{e}"))
}

/// The options of a volume's bake in memory (what [`pins_for`] and the viewer bake):
/// `pinbake bake`'s choice for `source`, with `cells` per axis where given, `seed`, and the
/// control section where `control`; refused with one line when the bake, its serialised
/// bytes and the loaded copy exceed `budget`.
pub fn in_memory_bake_options(
    source: &dyn DensitySource,
    cells: Option<u32>,
    seed: u64,
    control: bool,
    budget: &pin_volume::files::MemoryBudget,
) -> Result<pinbake::BakeOptions> {
    let req = pinbake::BakeRequest {
        cells: cells.map(|c| [c; 3]),
        seed,
        embed_control: control.then(pinbake::control::ControlOptions::default),
        ..pinbake::BakeRequest::default()
    };
    let choice = pinbake::plan::choose(source, &req)?;
    let opts = pinbake::plan::options(&req, &choice, pin_format::Metadata::default());
    budget.check(
        &format!(
            "baking {:?} pin cells x {:?} in memory",
            opts.cells, opts.directions
        ),
        pinbake::bake::estimate_output_bytes(&opts).saturating_mul(2),
    )?;
    Ok(opts)
}

/// One medium as `pinrender render` opens it from its flags and the viewer from the same
/// file: its world box, the field the CPU estimators read, a pin file's majorants, the pins,
/// and what the GPU's copy of the density is made from. Both build their
/// [`crate::medium::MediumDesc`] here, so a batch render and the viewer pack the same media.
#[derive(Clone)]
pub struct OpenedMedium {
    pub bounds: ([f64; 3], [f64; 3]),
    pub field: Option<Arc<dyn Density>>,
    /// A pin file's majorants; `None`: built from the field when an estimator tracks.
    pub majorants: Option<Arc<MajorantGrid>>,
    pub pins: Option<Arc<PinGrid>>,
    /// The source volume and its tracked field, for its GPU copy.
    pub opened: Option<(Opened, Arc<TrackedSource>)>,
    /// A pin file's embedded dense density, for its GPU copy when there is no sparse one.
    pub voxels: Option<Arc<VoxelGrid>>,
    /// A pin file's embedded sparse density, for its GPU copy (preferred to a dense one).
    pub bricks: Option<Arc<BrickGrid>>,
}

impl OpenedMedium {
    /// A pin file alone (`grid`, mapped from `path`): its embedded density and majorants as
    /// [`pin_file_medium`] reads them, framed by the placed grid's world box (rotations
    /// included).
    pub fn pin_file(path: &Path, grid: Arc<PinGrid>) -> Result<Self> {
        let m = pin_file_medium(path, &grid)?;
        let bounds = grid
            .sampler()
            .map_err(|e| anyhow!("{}: {e}", path.display()))?
            .world_bounds()
            .unwrap_or(m.bounds);
        Ok(Self {
            bounds,
            field: m.field(),
            majorants: m.majorants,
            pins: Some(grid),
            opened: None,
            // The GPU reads the section the CPU reads: the sparse one if there is one (as its
            // dense expansion where that fits one binding, else as the bricks), else the dense.
            voxels: m.density,
            bricks: m.bricks,
        })
    }

    /// A volume: `opened`'s source tracked with caches of at most `cache_limit` bytes
    /// ([`TrackedSource::with_budget`]), with `pins` where the caller has them.
    pub fn volume(opened: Opened, pins: Option<Arc<PinGrid>>, cache_limit: u64) -> Self {
        let source = opened.source();
        let b = source.bounds();
        let field = Arc::new(TrackedSource::with_budget(source, cache_limit));
        Self {
            bounds: (b.min.to_array(), b.max.to_array()),
            field: Some(field.clone()),
            majorants: None,
            pins,
            opened: Some((opened, field)),
            voxels: None,
            bricks: None,
        }
    }

    /// The GPU's copy of the density for a device with `limits`: dense when it has at most
    /// [`GPU_DENSE_VOXELS`] voxels and fits one storage binding, else bricked.
    pub fn gpu_density(&self, limits: &wgpu::Limits) -> Result<GpuDensity> {
        let max_dense = GPU_DENSE_VOXELS.min(pinrt::gpu::binding_limit(limits) / 4);
        let dense = |v: VoxelGrid| GpuDensity::from_voxel_grid(v).map_err(|e| anyhow!("{e}"));
        match (&self.opened, &self.voxels, &self.bricks) {
            // A VDB's dense copy is charged as its bricks are: half the budget at most.
            (Some((o, field)), _, _) => {
                o.gpu_density_or_bricks(field, max_dense.min(field.bricks_budget() / 4))
            }
            (None, _, Some(b)) => match b.to_voxels(max_dense) {
                Some(v) => dense(v),
                None => GpuDensity::from_bricks(b.clone()).map_err(|e| anyhow!("{e}")),
            },
            (None, Some(v), None) => dense((**v).clone()),
            (None, None, None) => anyhow::bail!("no density to upload"),
        }
    }

    /// The render's description of this medium, unplaced (the file's own placement), with
    /// `gpu_density` where a GPU render reads the density.
    pub fn desc(
        &self,
        majorant_bricks: u32,
        gpu_density: Option<Arc<GpuDensity>>,
    ) -> crate::medium::MediumDesc {
        crate::medium::MediumDesc {
            field: self.field.clone(),
            majorants: self.majorants.clone(),
            majorant_bricks,
            pins: self.pins.clone().map(|grid| crate::medium::PlacedPins {
                grid,
                local_to_world: None,
            }),
            gpu_density,
            translation: [0.0; 3],
            placement: None,
        }
    }
}
