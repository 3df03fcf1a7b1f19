//! `pin-volume`: density volumes as the baker and the renderer read them.
//!
//! Every source answers one question, "what is the extinction coefficient at this world-space
//! point", and knows a world-space box outside of which it is zero. The density scale has already
//! been applied by the time a value leaves a source.
//!
//! What lives here:
//! * [`Density`]: the narrow interface a renderer reads (a point lookup, the box, bounds over
//!   a box, a voxel view); [`DensitySource`]: what a bake and a farm part ask besides;
//! * [`grid`]: a dense f32 grid with the shared world placement (docs/background.md section 2);
//! * [`raw`]: the headerless raw reader that produces such a grid;
//! * [`procedural`]: analytic fields (box, sphere, cosine noise) with closed-form optical depth;
//! * `vdb` (feature `vdb`): OpenVDB float/half grids, read in an isolated child process.
//! * `nanovdb` (feature `vdb`): NanoVDB float, half and quantised grids, read in place into
//!   the same sparse table as `vdb`.
//! * [`files`]: the input and output file rules and the [`files::MemoryBudget`] every
//!   allocation sized by input is checked against.
//!
//! What does not: ray marching, majorant grids and pin baking (the baker `pinbake` consumes
//! [`DensitySource`], and the renderer's trackers [`Density`]); file formats for pins (crate
//! `pin-format`).
//!
//! [`open_source`] turns a [`SourceSpec`] into a boxed source; every failure is a
//! [`SourceError`] whose message is one line and names the file where there is one.

/// The vector library of the public API ([`Aabb`], positions), so users name the same version
/// of its types without a direct dependency.
pub use glam;

use std::fmt;
use std::path::{Path, PathBuf};

use glam::DVec3;

pub mod dense_view;
pub mod files;
pub mod grid;
pub mod identity;
#[cfg(feature = "vdb")]
pub mod nanovdb;
pub mod part_facts;
pub mod procedural;
pub mod raw;
#[cfg(feature = "vdb")]
pub mod vdb;

/// The hidden subcommand that runs an executable as the isolated OpenVDB reader
/// (`vdb::serve_vdb_worker_if_asked`); named here so builds without `vdb` can refuse it.
pub const VDB_WORKER_SUBCOMMAND: &str = "__vdb-worker";

pub use dense_view::{DenseMap, DenseView};
pub use grid::{DenseGrid, DenseLattice};
pub use identity::SourceIdentity;
pub use procedural::{CosineNoise, HomogeneousBox, ProceduralSpec, Sphere};
pub use raw::{Endian, RawOptions, RawType};
#[cfg(feature = "vdb")]
pub use vdb::{GridStats, VdbOptions, VdbPart, VdbSource};

/// An axis-aligned world-space box, `min <= max` componentwise.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    pub min: DVec3,
    pub max: DVec3,
}

impl Aabb {
    pub fn new(min: DVec3, max: DVec3) -> Self {
        Self { min, max }
    }
    /// `(min, max)` as arrays, as the renderer's DDA and majorant grids take boxes.
    pub fn to_arrays(&self) -> ([f64; 3], [f64; 3]) {
        (self.min.to_array(), self.max.to_array())
    }
    /// The box `[lo, hi]` given as arrays.
    pub fn from_arrays(lo: [f64; 3], hi: [f64; 3]) -> Self {
        Self::new(DVec3::from(lo), DVec3::from(hi))
    }
    pub fn extent(&self) -> DVec3 {
        self.max - self.min
    }
    /// True when the box has positive, finite volume.
    pub fn is_valid(&self) -> bool {
        self.min.is_finite() && self.max.is_finite() && self.min.cmplt(self.max).all()
    }
}

/// A scalar extinction field in world space, as a renderer reads it (pbrt-v4's medium
/// density, five methods): a point lookup, the box, an upper and a lower bound over a box
/// (what majorant grids and controls are built from) and, where the field is a voxel array, a
/// view of it for trackers that step in index space. The renderer's estimators (`pinrender`)
/// take nothing wider; the baker's further questions (a description for provenance, batched
/// lookups along a line, cropping, farm parts, dense copies, memory) are [`DensitySource`]'s.
///
/// Implementations must be cheap to call from many threads at once and must never return NaN
/// or a negative value (sources reject or sanitise such input when they are built; the
/// renderer's estimators also read NaN and negatives as 0 and `+inf` as opaque, for the
/// fields its stability tests build).
///
/// Points are f64. The renderer's rays, the pin runtime's queries and the WGSL path work in
/// f32, and the renderer asks at those f32 points widened exactly, so its reference sees the
/// sample points the others would.
pub trait Density: Send + Sync {
    /// World-space box that contains every point with non-zero extinction.
    fn bounds(&self) -> Aabb;

    /// Extinction at a world-space point (zero outside `bounds`).
    fn extinction(&self, p: DVec3) -> f32;

    /// Maximum extinction inside `region` (a conservative upper bound is fine). Used for
    /// majorant grids and empty-space detection. A field that cannot bound itself cheaply
    /// returns `f32::INFINITY`: the renderer's majorant grid then samples a lattice instead.
    fn max_extinction_in(&self, region: Aabb) -> f32;

    /// An exact lower bound of the extinction over `region`, if the field can give one
    /// cheaply (residual ratio tracking's control in the renderer). The default: 0 where the
    /// region reaches outside [`Self::bounds`] (the extinction is 0 there), else through the
    /// [`Self::dense_view`] if there is one ([`DenseView::min_over`]), else `None`.
    fn min_extinction_in(&self, region: Aabb) -> Option<f32> {
        min_extinction_by_view(self, region)
    }

    /// The field as a dense voxel array, when it is one: inside [`Self::bounds`],
    /// `extinction(p)` must equal [`DenseView::at`] of [`DenseView::index`]`(p)` up to the
    /// rounding of the index to f32. The renderer's trackers then step through the array in
    /// f32 index space (one world-to-index transform per majorant brick, not per lookup)
    /// instead of calling `extinction` per tentative collision. `None` (the default): no
    /// such array.
    fn dense_view(&self) -> Option<DenseView<'_>> {
        None
    }
}

/// A [`Density`] the baker reads: what a bake asks beyond a renderer (its description for
/// provenance, batched lookups along a line, cropping, the voxel size that bounds the default
/// cells, the frame a rotated grid is baked in, a farm part's slab and facts, the dense copy a
/// bake marches, the memory a source holds). Every source the baker opens ([`open_source`])
/// is one; a renderer's own fields need not be. It lives here, beside the sources, rather
/// than in the baker because its methods read the sources' internals (a VDB's leaf table,
/// its part slab and reader facts), which the baker cannot see.
pub trait DensitySource: Density {
    /// A short human-readable description for provenance ("raw u8 128x128x128", ...). The
    /// default says only what it is: every source the baker opens names itself.
    fn describe(&self) -> String {
        String::from("density field")
    }

    /// Batched sampling along a line: `out[i] = extinction(origin + i * step)` for
    /// `i < min(n, out.len())`.
    ///
    /// A ray marcher should prefer this over a loop of [`extinction`](Self::extinction): sources
    /// override it to hoist per-call work (box tests, virtual dispatch, index transforms) out of
    /// the loop or to use recurrences along the line. Overrides must agree with `extinction`
    /// at `origin + step * i as f64` (computed in f64, as written) to within one f32 ulp;
    /// the dense grid and the VDB source give identical bits.
    fn extinction_along(&self, origin: DVec3, step: DVec3, n: usize, out: &mut [f32]) {
        for (i, o) in out.iter_mut().take(n).enumerate() {
            *o = self.extinction(origin + step * i as f64);
        }
    }

    /// Tight box around the non-zero extinction, if the source can tell cheaply (used for
    /// cropping). `None` means "use `bounds`".
    fn occupied_bounds(&self) -> Option<Aabb> {
        None
    }

    /// World size of one voxel per axis for a voxel grid, `None` for an analytic field. Bakes
    /// use it to keep the default spatial cells no finer than the voxels.
    fn voxel_size(&self) -> Option<DVec3> {
        None
    }

    /// World boxes inside each of which the extinction is at least `floor` at every point (a
    /// VDB's constant tiles, shrunk by the reach of its interpolation): what a sparse copy of
    /// the source must store, known from its tree's counts before any brick is tested (the
    /// memory and disk checks of `pinbake::sparse_density`). Empty (the default) where the
    /// source cannot tell cheaply; a lower bound, never more than is there.
    fn solid_boxes(&self, _floor: f32) -> Vec<Aabb> {
        Vec::new()
    }

    /// The frame the baker should work in when it is not world space: a view of this source
    /// in its own local coordinates and the row-major 3x4 `local_to_world` that places it.
    /// A rotated or sheared VDB returns its index space here, so that the pin grid's box is
    /// the grid's own box and the pin file records the placement; `None` (the default) bakes
    /// in world space with an identity placement.
    fn bake_frame(&self) -> Option<(Box<dyn DensitySource + '_>, [f64; 12])> {
        None
    }

    /// For a source read for one part of a farm bake (`pinbake bake --part I/N`; a VDB's
    /// `VdbOptions::part`): the z-interval `[lo, hi)` of the frame it is baked in (its own
    /// [`Self::bake_frame`] view answers for a rotated grid) inside which it holds the whole
    /// field, and a margin around it; elsewhere it may read zero where the field is not.
    /// `None` (the default): the source holds the whole field.
    fn part_slab(&self) -> Option<[f64; 2]> {
        None
    }

    /// For a voxel grid read for one part of a farm bake: the grid's leaf facts it baked
    /// with and those of its own slab's leaves ([`part_facts::PartFacts`]), for the merge's
    /// checks. `None` (the default): the source holds the whole field.
    fn part_facts(&self) -> Option<part_facts::PartFacts> {
        None
    }

    /// The source as a dense grid, when it is one: the baker then marches its voxels directly
    /// ([`DenseGrid::march_runs`]) instead of going through `extinction_along`.
    fn as_dense_grid(&self) -> Option<&DenseGrid> {
        None
    }

    /// A dense copy of a sparse grid with the same values and trilinear field, at most
    /// `max_bytes` bytes, for a bake that marches it ([`DenseGrid::march_runs`]) instead of
    /// looking every sample up in the sparse structure. `None` (the default): no copy; dense
    /// grids answer [`Self::as_dense_grid`] instead, analytic fields have no voxels.
    fn dense_copy(&self, max_bytes: u64) -> Option<DenseGrid> {
        let _ = max_bytes;
        None
    }

    /// The lattice of the dense grid [`Self::dense_copy`] makes, whatever the budget and
    /// however many of its voxels are zeros, for a bake that reads that grid a few planes at a
    /// time ([`Self::dense_planes`]: the GPU bake of a source too large to copy whole).
    /// `None` (the default): no such grid.
    fn dense_lattice(&self) -> Option<DenseLattice> {
        None
    }

    /// The values of z-planes `[z_begin, z_end)` of the grid [`Self::dense_lattice`] places,
    /// x fastest, then y: the values [`Self::dense_copy`] holds there, bit for bit, so that the
    /// same trilinear field comes out. `None` without a lattice, for a range outside it or an
    /// empty one, or when the memory cannot be had.
    fn dense_planes(&self, z_begin: u32, z_end: u32) -> Option<Vec<f32>> {
        let _ = (z_begin, z_end);
        None
    }

    /// What the source holds in memory, when it can say exactly (a VDB's leaf table):
    /// `held` now, and `while_opening` at most while it was opened (with its reader process).
    /// `None` (the default): the caller estimates from the input's size.
    fn footprint(&self) -> Option<Footprint> {
        None
    }

    /// The bytes [`Self::dense_copy`] would allocate when it makes a copy at all (given
    /// enough budget), or `None` when it never does; for memory estimates.
    fn dense_copy_size(&self) -> Option<u64> {
        None
    }
}

/// [`Density::min_extinction_in`]'s default, for overrides that fall back to it: 0
/// where `region` reaches outside the source's bounds, else [`DenseView::min_over`] of its
/// [`Density::dense_view`], else `None`.
pub fn min_extinction_by_view<S: Density + ?Sized>(source: &S, region: Aabb) -> Option<f32> {
    let b = source.bounds();
    if !(region.min.cmpge(b.min).all() && region.max.cmple(b.max).all()) {
        return Some(0.0);
    }
    let (lo, hi) = region.to_arrays();
    source.dense_view().map(|v| v.min_over(lo, hi))
}

/// The memory a source holds: [`DensitySource::footprint`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Footprint {
    /// Bytes held once open.
    pub held: u64,
    /// Bytes held at most while opening, its reader process included.
    pub while_opening: u64,
}

/// Everything that can go wrong while opening a source. Every message is a single line and
/// names the file where there is one, so a CLI can print it as is.
#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    /// The file could not be opened or read at all.
    #[error("{}: {}", .path.display(), one_line(&.source.to_string()))]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The path names a directory, device, FIFO or socket, not a regular file.
    #[error("{}: {what}", .path.display())]
    NotAFile { path: PathBuf, what: &'static str },
    /// A NanoVDB file was rejected.
    #[error("{}: {}", .path.display(), one_line(.message))]
    NanoVdb { path: PathBuf, message: String },
    /// A raw volume is malformed or does not match its options.
    #[error("{}: {}", .path.display(), one_line(.message))]
    Raw { path: PathBuf, message: String },
    /// An OpenVDB file was rejected (by our checks, or because the isolated reader failed).
    #[error("{}: {}", .path.display(), one_line(.message))]
    Vdb { path: PathBuf, message: String },
    /// A procedural source description could not be parsed or is out of range.
    #[error("procedural source '{}': {}", one_line(.spec), one_line(.message))]
    Procedural { spec: String, message: String },
    /// An option is out of range (density scale, spacing, ...), independent of any file.
    #[error("invalid option: {}", one_line(.0))]
    InvalidOption(String),
    /// The source would need more memory than the caller's budget allows.
    #[error("{}: {}", .path.display(), one_line(.message))]
    Memory { path: PathBuf, message: String },
    /// The source was built in without the cargo feature it needs.
    #[error("{}: {}", .path.display(), one_line(.message))]
    Unsupported { path: PathBuf, message: String },
}

impl SourceError {
    pub(crate) fn raw(path: &Path, message: impl Into<String>) -> Self {
        Self::Raw {
            path: path.to_path_buf(),
            message: message.into(),
        }
    }
    /// A refused input path ([`crate::files`]): an I/O error keeps its kind, the rest
    /// (not a regular file, a directory) is a message about the file.
    pub(crate) fn from_file(e: crate::files::FileError) -> Self {
        match e {
            crate::files::FileError::Io { path, err } => Self::Io { path, source: err },
            crate::files::FileError::IsDirectory(path) => Self::NotAFile {
                path,
                what: "is a directory",
            },
            crate::files::FileError::NotRegular(path) => Self::NotAFile {
                path,
                what: "not a regular file",
            },
            other => Self::InvalidOption(other.to_string()),
        }
    }
}

/// Replaces line breaks and other control characters so that an error stays on one line even
/// when it quotes hostile input (grid names come straight from files).
pub fn one_line(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '\n' | '\r' | '\t' => out.push(' '),
            '\u{1e}' => out.push('#'),
            c if c.is_control() => out.push_str(&format!("\\u{{{:x}}}", c as u32)),
            c => out.push(c),
        }
    }
    out
}

/// A validated density multiplier: finite and `>= 0`.
///
/// Sources apply it while they are built, so the hot path never multiplies. The product of a
/// finite value and a finite scale can still overflow f32 (`1e30 * 1e9`); [`DensityScale::apply`]
/// reports that instead of letting an infinity through.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DensityScale(f64);

impl DensityScale {
    pub const ONE: DensityScale = DensityScale(1.0);

    /// Accepts any finite, non-negative scale (0 gives an all-zero field, which is legal).
    pub fn new(scale: f64) -> Result<Self, SourceError> {
        if scale.is_finite() && scale >= 0.0 {
            Ok(Self(scale))
        } else {
            Err(SourceError::InvalidOption(format!(
                "density scale must be finite and >= 0, got {scale}"
            )))
        }
    }

    pub fn get(self) -> f64 {
        self.0
    }

    /// `value * scale` as f32, or `None` when the product is not a finite f32. `value` must be
    /// finite; the product is formed in f64 so that only the final narrowing can overflow.
    #[inline]
    pub fn apply(self, value: f64) -> Option<f32> {
        let v = (value * self.0) as f32;
        v.is_finite().then_some(v)
    }
}

impl Default for DensityScale {
    fn default() -> Self {
        Self::ONE
    }
}

impl fmt::Display for DensityScale {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// The kinds of input a bake reads, for the rule of which source options apply to which.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InputKind {
    Procedural,
    Vdb,
    /// A NanoVDB file: opened with the OpenVDB options (`SourceSpec::Vdb`).
    NanoVdb,
    Raw,
    /// Voxels in memory (Python's NumPy arrays): placed by spacing and origin only.
    Array,
}

impl InputKind {
    /// The kind a path or `procedural:SPEC` names, by content where the format has a
    /// magic: a file that starts with NanoVDB's magic is NanoVDB and one that starts with
    /// OpenVDB's is OpenVDB, whatever its name (an OpenVDB file named `.nvdb` and a NanoVDB
    /// file named `.vdb` open as what they are, in every tool). A file without either (raw
    /// voxels have no header), or that cannot be read here (missing, not a regular file:
    /// refused later with its own message), goes by its extension: `.vdb` OpenVDB, `.nvdb`
    /// NanoVDB, anything else raw.
    pub fn of(input: &std::path::Path) -> Self {
        let ext = |x: &str| input.extension().is_some_and(|e| e.eq_ignore_ascii_case(x));
        if input.to_str().is_some_and(|s| s.starts_with("procedural:")) {
            return InputKind::Procedural;
        }
        match magic_kind(input) {
            Some(kind) => kind,
            None if ext("nvdb") => InputKind::NanoVdb,
            None if ext("vdb") => InputKind::Vdb,
            None => InputKind::Raw,
        }
    }

    /// Whether the input is read with the OpenVDB options (OpenVDB or NanoVDB).
    pub fn is_vdb_like(self) -> bool {
        matches!(self, InputKind::Vdb | InputKind::NanoVdb)
    }

    /// Its name in messages ("a raw input").
    pub fn article_name(self) -> &'static str {
        match self {
            InputKind::Procedural => "a procedural",
            InputKind::Vdb => "an OpenVDB",
            InputKind::NanoVdb => "a NanoVDB",
            InputKind::Raw => "a raw",
            InputKind::Array => "an array",
        }
    }

    /// Whether the source option `name` (snake case: `dims`, `voxel_type`, `endian`,
    /// `spacing`, `origin`, `clamp_negative`, `nan_as_zero`, `grid`, `levelset_to_fog`)
    /// means anything for this kind. A given option that does not is refused by every entry
    /// point (exit 2, `ValueError`): ignoring it would bake something other than what the
    /// user asked for.
    pub fn accepts(self, name: &str) -> bool {
        const RAW: [&str; 7] = [
            "dims",
            "voxel_type",
            "endian",
            "spacing",
            "origin",
            "clamp_negative",
            "nan_as_zero",
        ];
        const VDB: [&str; 2] = ["grid", "levelset_to_fog"];
        match self {
            InputKind::Procedural => false,
            InputKind::Vdb | InputKind::NanoVdb => VDB.contains(&name),
            InputKind::Raw => RAW.contains(&name),
            InputKind::Array => matches!(name, "spacing" | "origin"),
        }
    }

    /// The first option `given` that does not apply to this kind (its name, see
    /// [`InputKind::accepts`]).
    pub fn first_inapplicable(self, given: &GivenSourceOptions) -> Option<&'static str> {
        given.names().find(|n| !self.accepts(n))
    }
}

/// Which source options a caller gave (differ from their defaults): what
/// [`InputKind::first_inapplicable`] checks, for the command line and Python alike.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct GivenSourceOptions {
    pub dims: bool,
    pub voxel_type: bool,
    pub endian: bool,
    pub spacing: bool,
    pub origin: bool,
    pub clamp_negative: bool,
    pub nan_as_zero: bool,
    pub grid: bool,
    pub levelset_to_fog: bool,
}

impl GivenSourceOptions {
    /// The names of the options given, raw ones first, then the VDB ones.
    pub fn names(self) -> impl Iterator<Item = &'static str> {
        [
            ("dims", self.dims),
            ("voxel_type", self.voxel_type),
            ("endian", self.endian),
            ("spacing", self.spacing),
            ("origin", self.origin),
            ("clamp_negative", self.clamp_negative),
            ("nan_as_zero", self.nan_as_zero),
            ("grid", self.grid),
            ("levelset_to_fog", self.levelset_to_fog),
        ]
        .into_iter()
        .filter(|f| f.1)
        .map(|f| f.0)
    }
}

/// NanoVDB's magic: the first 8 bytes of a file (and of each grid).
const NANOVDB_MAGIC: [u8; 8] = *b"NanoVDB0";
/// OpenVDB's magic: the file's first int32, 0x56444220 (" BDV"), little-endian.
const OPENVDB_MAGIC: [u8; 4] = [0x20, 0x42, 0x44, 0x56];

/// The format `input`'s first bytes name, if it is a regular file that starts with one of
/// the magics. Only a regular file is opened (non-blocking, `pin_format::input`): opening a
/// FIFO would block, and a device or directory is refused later with its own message.
fn magic_kind(input: &Path) -> Option<InputKind> {
    use std::io::Read;
    let (f, len) = pin_format::input::open_regular(input).ok()?;
    let mut head = Vec::with_capacity(8);
    f.take(8.min(len)).read_to_end(&mut head).ok()?;
    if head.starts_with(&NANOVDB_MAGIC) {
        Some(InputKind::NanoVdb)
    } else if head.starts_with(&OPENVDB_MAGIC) {
        Some(InputKind::Vdb)
    } else {
        None
    }
}

/// Whether the file at `input` starts with NanoVDB's magic (false when it cannot be read).
#[cfg(feature = "vdb")]
pub(crate) fn has_nanovdb_magic(input: &Path) -> bool {
    magic_kind(input) == Some(InputKind::NanoVdb)
}

/// What to open: the input half of a bake command line.
#[derive(Clone, Debug)]
pub enum SourceSpec {
    Raw(PathBuf, RawOptions),
    #[cfg(feature = "vdb")]
    Vdb(PathBuf, VdbOptions),
    /// A VDB requested from a build without the `vdb` feature; opening it is an error.
    #[cfg(not(feature = "vdb"))]
    Vdb(PathBuf),
    Procedural(ProceduralSpec),
}

/// A source as [`open_source`] opens it, its concrete type kept: what a reader that makes
/// its own copies (the renderer's GPU density) needs. The one place an input's format is
/// dispatched: [`open_source`] boxes what this returns.
pub enum OpenedSource {
    /// A raw grid.
    Raw(Box<DenseGrid>),
    /// An OpenVDB or a NanoVDB file (both read into the same sparse source).
    #[cfg(feature = "vdb")]
    Vdb(Box<VdbSource>),
    /// A procedural field, built.
    Procedural(Box<dyn DensitySource>),
}

impl OpenedSource {
    /// The source behind the density interface.
    pub fn into_source(self) -> Box<dyn DensitySource> {
        match self {
            OpenedSource::Raw(g) => g,
            #[cfg(feature = "vdb")]
            OpenedSource::Vdb(v) => v,
            OpenedSource::Procedural(p) => p,
        }
    }
}

/// [`open_source`] with the concrete type kept ([`OpenedSource`]).
pub fn open_source_typed(
    spec: &SourceSpec,
    scale: DensityScale,
) -> Result<OpenedSource, SourceError> {
    match spec {
        SourceSpec::Raw(path, options) => Ok(OpenedSource::Raw(Box::new(raw::read_raw(
            path, options, scale,
        )?))),
        // What the content names (`InputKind::of`: the magic first, the name only where
        // there is none): NanoVDB in process, the rest through the OpenVDB worker.
        #[cfg(feature = "vdb")]
        SourceSpec::Vdb(path, options) if InputKind::of(path) == InputKind::NanoVdb => Ok(
            OpenedSource::Vdb(Box::new(nanovdb::open(path, options, scale)?)),
        ),
        #[cfg(feature = "vdb")]
        SourceSpec::Vdb(path, options) => Ok(OpenedSource::Vdb(Box::new(VdbSource::open(
            path, options, scale,
        )?))),
        #[cfg(not(feature = "vdb"))]
        SourceSpec::Vdb(path) => Err(SourceError::Unsupported {
            path: path.clone(),
            message: "this build has no OpenVDB support (cargo feature `vdb`)".into(),
        }),
        SourceSpec::Procedural(p) => Ok(OpenedSource::Procedural(p.build(scale)?)),
    }
}

/// Opens any source with every density multiplied by `scale` (the one place a scale enters a
/// source: the readers apply it as they build, so the hot path never multiplies). The result
/// is ready to sample: validated, density-scaled, bounds computed.
pub fn open_source(
    spec: &SourceSpec,
    scale: DensityScale,
) -> Result<Box<dyn DensitySource>, SourceError> {
    Ok(open_source_typed(spec, scale)?.into_source())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_line_escapes_controls() {
        assert_eq!(one_line("a\nb\u{1e}1\u{7}"), "a b#1\\u{7}");
    }

    #[test]
    fn density_scale_validation() {
        assert!(DensityScale::new(0.0).is_ok());
        assert!(DensityScale::new(1e30).is_ok());
        assert!(DensityScale::new(-1.0).is_err());
        assert!(DensityScale::new(f64::NAN).is_err());
        assert!(DensityScale::new(f64::INFINITY).is_err());
        let s = DensityScale::new(1e30).unwrap();
        assert_eq!(s.apply(1e-30), Some(1.0));
        assert_eq!(s.apply(1e9), None);
        assert_eq!(DensityScale::new(0.0).unwrap().apply(1e38), Some(0.0));
    }

    #[test]
    fn open_procedural_from_string() {
        let spec: ProceduralSpec = "cosine:seed=7,freq=16".parse().unwrap();
        let s = open_source(&SourceSpec::Procedural(spec), crate::DensityScale::ONE).unwrap();
        assert!(s.bounds().is_valid());
        let mut out = [0.0f32; 4];
        s.extinction_along(DVec3::splat(0.1), DVec3::splat(0.1), 4, &mut out);
        for (i, v) in out.iter().enumerate() {
            let e = s.extinction(DVec3::splat(0.1) + DVec3::splat(0.1) * i as f64);
            assert!((v - e).abs() <= f32::EPSILON * e, "{v} vs {e}");
        }
    }
}
